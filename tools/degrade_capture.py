#!/usr/bin/env python3
"""Turn a rendered kdmap example into the capture a real camera gives: per-photo exposure and
white balance, camera poses a pixel or two off, 8-bit sRGB PNG/JPEG, a COLMAP model with lens
distortion. Writes a complete scene copy whose training photos are degraded, plus `capture.json`
recording exactly what was done per view (the truth for tests and for the nightly harness).

    .venv/bin/python tools/degrade_capture.py <scene dir> --out <new scene dir> [options]
    .venv/bin/python tools/degrade_capture.py tests/fixtures/cbox-tex --preset all       # one variant
    .venv/bin/python tools/degrade_capture.py tests/fixtures/{cbox,cbox-tex,envmap} \\
        --preset exposure,pose,jpeg,all,control --out-root cache/capture              # all variants

Presets (`--preset a,b,...`; options given on the command line win): `exposure` (gain 0.5-1.9,
white balance 6%), `pose` (0.3 degrees, 0.5% of the distance), `jpeg` (8-bit sRGB JPEG, quality
90), `all` (the three + COLMAP OPENCV with k1 = -0.05, k2 = 0.01), `control` (re-rendered from
the nominal cameras at the same spp, nothing else: the noise-matched baseline of `pose` and
`all`, whose photos are re-rendered at 256 spp while the fixtures' are 256-1024 spp).

The output scene holds `input.xml` (NOMINAL cameras, unchanged), `truth.xml`, `relit.xml`,
`meshes/`, `textures/`, `truth/` (held-out views: copied unchanged, the judge stays the truth)
and every other file of the source, except `images/` (the degraded photos) and `albedo/` (kept
only when the photos still come from the nominal, undistorted cameras). Options combine; the
order of the operations is: (re-)render -> exposure x white balance (linear) -> 8-bit encoding.

Exposure and white balance (`--exposure LO,HI`, `--white-balance W`): per photo a gain g drawn
log-uniformly in [LO, HI] and multipliers (1 + dR, 1, 1 + dB) with dR, dB uniform in [-W, W]
(R and B relative to G), applied to the linear radiance. Without `--ldr` the photos stay EXR,
written as float32 (the sources are half float), so degraded / original = g * wb exactly up to
float32 rounding.

Poses (`--pose-deg A --pose-dist F`): each training camera is turned by a rotation of exactly A
degrees about a uniformly random axis through its centre, and moved by F x its distance to its
look-at target (the scene's bounding-box centre when its transform is not a single <lookat>)
along a uniformly random direction. The photo is RE-RENDERED with Mitsuba from the moved camera
using truth.xml (the true scene) with its integrator and the sensor's film and filter, `--spp`
samples per pixel (default 256; `--spp source` takes the sensor's sample_count); input.xml
keeps the nominal camera, as structure-from-motion poses would be off. `--rerender` re-renders
even without pose change or distortion (a noise-matched control). capture.json records per
view the true to_world (and an equivalent lookat), the rotation axis and angle, the
translation, and the offset in pixels: for each pixel centre of the nominal camera, the point
its ray first hits in truth.xml (a point at infinity for rays that miss) projected through the
true camera, its distance to the pixel centre; mean, median, 95th percentile and max.

8-bit encoding (`--ldr png|jpg`, `--jpeg-quality 90`, `--jpeg-subsampling 4:2:0`): value =
clip(ldr_scale x g x wb x radiance, 0, 1), IEC 61966-2-1 sRGB transfer function, rounded to
0..255, written as images/<id>.png or .jpg instead of .exr. ldr_scale (one for all photos) maps
the 99th percentile of all channel values of the (re-rendered, pre-gain) training photos to 0.9,
unless `--ldr-scale S` is given. The per-channel linear factor scene radiance -> encoded value,
ldr_scale x g x wb, is `views.<id>.factor` in capture.json (without --ldr, ldr_scale = 1).

COLMAP (`--colmap`, `--distortion k1,k2`, `--colmap-model opencv|radial`): writes a text sparse
model `sparse/cameras.txt`, `sparse/images.txt`, an empty `sparse/points3D.txt`, one camera per
training view (CAMERA_ID = IMAGE_ID = 1 + index in input.xml, NAME = the image file name
relative to images/), in a frame that differs from the scene's by a random similarity:
X_scene = s R X_colmap + t (R uniform, s log-uniform in [0.25, 4], |t| up to twice the mean
camera-target distance; `--colmap-identity` for none). That 4x4 matrix, COLMAP -> scene, is
`colmap.to_world` in capture.json and `sparse/to_world.txt` (4 rows). Poses are the NOMINAL
ones of input.xml (`--colmap-pose true` writes the true ones). Conventions, from COLMAP's
doc/format.rst and src/colmap/sensor/models/{pinhole,opencv,radial}.h: images.txt holds
world-to-camera QW QX QY QZ (Hamilton, w first) and TX TY TZ, camera centre = -R^T t; the camera
looks along +Z with X right and Y down; the centre of the top-left pixel is (0.5, 0.5);
PINHOLE fx fy cx cy; OPENCV fx fy cx cy k1 k2 p1 p2 (p1 = p2 = 0 here); RADIAL f cx cy k1 k2;
x = fx (u (1 + k1 r^2 + k2 r^4) + tangential) + cx with (u, v) = (X/Z, Y/Z). Mitsuba's
perspective camera looks along +z with +x LEFT and +y up (lookat's to_world columns are left,
up, forward) and its film puts pixel centres at (i + 0.5) / W with fx = (W / 2) / tan(x_fov / 2),
cx = W / 2, cy = H / 2: so COLMAP camera = diag(-1, -1, 1) x Mitsuba camera (a rotation of 180
degrees about z, hence still a proper rotation), R_cw = F R_tw^T R, t_cw = F R_tw^T (t - o) / s.
tools/test_degrade_capture.py projects scene points both ways (and through Mitsuba's own
sensor.sample_ray) and checks agreement to 1e-3 px.

Distortion: with `--distortion=k1,k2` (the `=` lets k1 be negative), the photos are rendered
EXACTLY through the distortion (not resampled from an undistorted render): every sample position
(x, y) of a pixel of the distorted image (box filter: uniform over the pixel, as a sensor pixel
integrates; tent: tent-distributed around its centre, which converges to what Mitsuba's
weighted splatting gives; other filters refused) is lifted to normalised coordinates ((x - cx) / fx,
(y - cy) / fy), undistorted by Newton's method (to 1e-12), and turned into the Mitsuba ray
(-u, -v, 1) of the (true) camera, started at the near clip plane like Mitsuba's perspective
sensor; Mitsuba's path integrator (`integrator.sample`, llvm_ad_rgb) traces it, and each
pixel is the mean of its samples. So the only approximation is Monte Carlo noise; with k1 = k2 =
0 this is the same estimator as mi.render (checked by the tests to within noise). The
distortion must be invertible over the image (checked; refused otherwise).

Random draws come from separate streams of `--seed` (exposure/WB, poses, COLMAP frame, render
seeds), so a variant with more options keeps the same gains and poses as one with fewer, and
the same command gives the same capture.json (but for timings and date) and, without
rendering, the same bytes.
Mitsuba 3.9 with libLLVM (DRJIT_LIBLLVM_PATH is set when unset and a libLLVM is found) renders;
without it, undistorted renders fall back to scalar_rgb and distortion is refused.
"""

import argparse
import json
import math
import os
import shutil
import sys
import time
import xml.etree.ElementTree as ET

import numpy as np

TOOLS = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, TOOLS)
from exrio import mitsuba, read_exr_rgb  # noqa: E402

TOOL_VERSION = 1
REPO = os.path.dirname(TOOLS)
DEFAULT_OUT_ROOT = os.path.join(REPO, "cache", "capture")
LLVM = "llvm_ad_rgb"
LDR_TARGET = 0.9  # linear value the 99th percentile maps to
LDR_PERCENTILE = 99.0
FLIP = np.diag([-1.0, -1.0, 1.0])  # Mitsuba camera (x left, y up, z fwd) <-> COLMAP (x right, y down)
COLMAP_SCALE_RANGE = (0.25, 4.0)

PRESETS = {
    "exposure": dict(exposure="0.5,1.9", white_balance=0.06),
    "pose": dict(pose_deg=0.3, pose_dist=0.005),
    "jpeg": dict(ldr="jpg", jpeg_quality=90),
    # noise-matched control for "pose" and "all": re-rendered from the nominal cameras at the
    # same spp, nothing else changed
    "control": dict(rerender=True),
    "all": dict(exposure="0.5,1.9", white_balance=0.06, pose_deg=0.3, pose_dist=0.005, ldr="jpg",
                jpeg_quality=90, colmap=True, distortion="-0.05,0.01"),
}

# ------------------------------------------------------------------------------------------
# sRGB (IEC 61966-2-1)


def srgb_encode(lin):
    """Linear [0, 1] -> sRGB-encoded [0, 1] (piecewise: 12.92 x below 0.0031308)."""
    x = np.clip(np.asarray(lin, np.float64), 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1.0 / 2.4) - 0.055)


def srgb_decode(enc):
    """sRGB-encoded [0, 1] -> linear [0, 1]."""
    v = np.asarray(enc, np.float64)
    return np.where(v <= 0.04045, v / 12.92, np.power((v + 0.055) / 1.055, 2.4))


def to_srgb8(lin):
    """Linear values -> 8-bit sRGB codes (clipped at 0 and 1, rounded to nearest)."""
    return np.round(srgb_encode(lin) * 255.0).astype(np.uint8)


def from_srgb8(codes):
    return srgb_decode(np.asarray(codes, np.float64) / 255.0)


# ------------------------------------------------------------------------------------------
# Rotations and quaternions


def unit(v):
    v = np.asarray(v, np.float64)
    return v / np.linalg.norm(v)


def random_unit(rng):
    while True:
        v = rng.standard_normal(3)
        n = np.linalg.norm(v)
        if n > 1e-9:
            return v / n


def axis_angle(axis, angle_rad):
    """Rotation matrix of `angle_rad` about unit `axis` (right-handed, Rodrigues)."""
    k = unit(axis)
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(angle_rad) * kx + (1 - math.cos(angle_rad)) * (kx @ kx)


def quat_to_matrix(q):
    """Hamilton quaternion (w, x, y, z) -> rotation matrix (as Eigen's toRotationMatrix)."""
    w, x, y, z = np.asarray(q, np.float64) / np.linalg.norm(q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


def matrix_to_quat(r):
    """Rotation matrix -> Hamilton quaternion (w, x, y, z) with w >= 0 (Shepperd's method)."""
    r = np.asarray(r, np.float64)
    tr = np.trace(r)
    if tr > 0:
        s = 2.0 * math.sqrt(tr + 1.0)
        q = [0.25 * s, (r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, (r[1, 0] - r[0, 1]) / s]
    elif r[0, 0] > r[1, 1] and r[0, 0] > r[2, 2]:
        s = 2.0 * math.sqrt(1.0 + r[0, 0] - r[1, 1] - r[2, 2])
        q = [(r[2, 1] - r[1, 2]) / s, 0.25 * s, (r[0, 1] + r[1, 0]) / s, (r[0, 2] + r[2, 0]) / s]
    elif r[1, 1] > r[2, 2]:
        s = 2.0 * math.sqrt(1.0 + r[1, 1] - r[0, 0] - r[2, 2])
        q = [(r[0, 2] - r[2, 0]) / s, (r[0, 1] + r[1, 0]) / s, 0.25 * s, (r[1, 2] + r[2, 1]) / s]
    else:
        s = 2.0 * math.sqrt(1.0 + r[2, 2] - r[0, 0] - r[1, 1])
        q = [(r[1, 0] - r[0, 1]) / s, (r[0, 2] + r[2, 0]) / s, (r[1, 2] + r[2, 1]) / s, 0.25 * s]
    q = np.array(q) / np.linalg.norm(q)
    return q if q[0] >= 0 else -q


def random_rotation(rng):
    """A uniformly distributed rotation (normalised Gaussian quaternion)."""
    return quat_to_matrix(random_unit_4(rng))


def random_unit_4(rng):
    v = rng.standard_normal(4)
    return v / np.linalg.norm(v)


def lookat_matrix(origin, target, up):
    """Mitsuba's Transform4f.look_at in float64: columns left, up', forward, origin."""
    o = np.asarray(origin, np.float64)
    d = unit(np.asarray(target, np.float64) - o)
    left = unit(np.cross(unit(up), d))
    new_up = np.cross(d, left)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = left, new_up, d, o
    return m


# ------------------------------------------------------------------------------------------
# Cameras: Mitsuba perspective sensors as numbers, and their COLMAP form


class Camera:
    """A training camera: id, film size, x field of view, to_world (4x4, float64, rigid), near
    and far clip, look-at target, pixel filter, sample count."""

    def __init__(self, sid, w, h, x_fov, to_world, near, far, target, rfilter, spp):
        self.id, self.w, self.h, self.x_fov = sid, int(w), int(h), float(x_fov)
        self.to_world = np.asarray(to_world, np.float64)
        self.near, self.far = float(near), float(far)
        self.target = np.asarray(target, np.float64)
        self.rfilter, self.spp = rfilter, spp

    @property
    def origin(self):
        return self.to_world[:3, 3]

    def intrinsics(self):
        """COLMAP (fx, fy, cx, cy) of this Mitsuba sensor: square pixels, centred principal
        point, fx = (W / 2) / tan(x_fov / 2)."""
        f = 0.5 * self.w / math.tan(math.radians(self.x_fov) / 2.0)
        return f, f, 0.5 * self.w, 0.5 * self.h

    def moved(self, to_world):
        return Camera(self.id, self.w, self.h, self.x_fov, to_world, self.near, self.far,
                      self.target, self.rfilter, self.spp)


def _floats(s):
    return [float(x) for x in s.replace(",", " ").split()]


def _sensor_xml_info(sensor):
    """(lookat (origin, target, up) or None, rfilter dict, sample_count or None) of an ET sensor."""
    lookat = None
    for tr in sensor.findall("transform"):
        if tr.get("name") == "to_world":
            kids = list(tr)
            if len(kids) == 1 and kids[0].tag == "lookat":
                la = kids[0]
                lookat = (_floats(la.get("origin")), _floats(la.get("target")),
                          _floats(la.get("up", "0, 1, 0")))
    rf = {"type": "gaussian"}  # Mitsuba's default film filter
    spp = None
    for film in sensor.iter("film"):
        for r in film.findall("rfilter"):
            rf = {"type": r.get("type")}
            for p in r:
                if p.get("name"):
                    rf[p.get("name")] = float(p.get("value"))
    for smp in sensor.iter("sampler"):
        for i in smp.iter("integer"):
            if i.get("name") == "sample_count":
                spp = int(i.get("value"))
    return lookat, rf, spp


def load_cameras(xml_path):
    """The sensors of `xml_path` as Camera objects, in file order (Mitsuba scalar_rgb: x_fov,
    film size, clip planes; to_world recomputed in float64 from a <lookat>, checked against
    Mitsuba's to 1e-5)."""
    mi = mitsuba()
    base = os.path.dirname(os.path.abspath(xml_path))
    root = ET.parse(xml_path).getroot()
    sensors_xml = {s.get("id"): s for s in root.findall("sensor")}
    # only the sensors are needed: load them without the shapes
    only = ET.Element("scene", root.attrib)
    for s in root:
        if s.tag in ("default", "sensor"):
            if s.tag == "sensor" and s.get("type") != "perspective":
                raise SystemExit(f"{xml_path}: sensor {s.get('id')} is a {s.get('type')}, not a perspective camera")
            only.append(s)
    scene = _load_string(ET.tostring(only, encoding="unicode"), base)
    bbox_centre = None
    cams = []
    for sensor in scene.sensors():
        sid = sensor.id()
        p = mi.traverse(sensor)
        size = np.array(p["film.size"]).reshape(-1)[:2]
        crop = np.array(p["film.crop_size"]).reshape(-1)[:2]
        off = np.array(p["film.crop_offset"]).reshape(-1)[:2]
        ppx = float(np.array(p["principal_point_offset_x"]).reshape(-1)[0])
        ppy = float(np.array(p["principal_point_offset_y"]).reshape(-1)[0])
        if tuple(crop) != tuple(size) or off.any() or ppx or ppy:
            raise SystemExit(f"{xml_path}: sensor {sid}: crop windows and principal point offsets "
                             "are not supported")
        m_mi = np.array(p["to_world"].matrix, np.float64).reshape(4, 4)
        lookat, rf, spp = _sensor_xml_info(sensors_xml[sid])
        if lookat is not None:
            m = lookat_matrix(*lookat)
            if np.abs(m - m_mi).max() > 1e-5 * max(1.0, np.abs(m_mi[:3, 3]).max()):
                raise SystemExit(f"{xml_path}: sensor {sid}: float64 lookat differs from Mitsuba's")
            target = np.array(lookat[1])
        else:
            m = m_mi
            if np.abs(m[:3, :3].T @ m[:3, :3] - np.eye(3)).max() > 1e-5:
                raise SystemExit(f"{xml_path}: sensor {sid}: to_world is not rigid")
            if bbox_centre is None:
                bbox_centre = _scene_centre(xml_path)
            target = bbox_centre
        cams.append(Camera(sid, size[0], size[1], float(np.array(p["x_fov"]).reshape(-1)[0]), m,
                           float(np.array(p["near_clip"]).reshape(-1)[0]),
                           float(np.array(p["far_clip"]).reshape(-1)[0]), target, rf, spp))
    return cams


def _scene_centre(xml_path):
    mi = mitsuba()
    with open(xml_path) as fh:
        text = fh.read()
    scene = _load_string(text, os.path.dirname(os.path.abspath(xml_path)))
    bb = scene.bbox()
    return 0.5 * (np.array(bb.min, np.float64) + np.array(bb.max, np.float64))


def _load_string(text, base_dir, optimize=True):
    """mi.load_string with `base_dir` first on the file resolver (relative meshes, textures)."""
    mi = mitsuba()
    fr = mi.file_resolver()
    saved = [fr[i] for i in range(len(fr))]
    fr.prepend(os.path.abspath(base_dir))
    try:
        return mi.load_string(text, optimize=optimize)
    finally:
        fr.clear()
        for p in saved:
            fr.append(p)


# --- distortion (COLMAP OPENCV / RADIAL: radial k1, k2 and tangential p1, p2) ---------------


def distort(dist, u, v):
    """COLMAP's OpenCV distortion: normalised undistorted (u, v) -> distorted. `dist` =
    (k1, k2, p1, p2) (RADIAL is p1 = p2 = 0)."""
    k1, k2, p1, p2 = dist
    u2, v2, uv = u * u, v * v, u * v
    r2 = u2 + v2
    radial = k1 * r2 + k2 * r2 * r2
    return (u + u * radial + 2 * p1 * uv + p2 * (r2 + 2 * u2),
            v + v * radial + 2 * p2 * uv + p1 * (r2 + 2 * v2))


def undistort(dist, xd, yd, iterations=50, tol=1e-12):
    """Inverse of `distort` by Newton's method with the analytic Jacobian; returns (u, v) and
    the largest residual."""
    k1, k2, p1, p2 = dist
    xd = np.asarray(xd, np.float64)
    yd = np.asarray(yd, np.float64)
    u, v = xd.copy(), yd.copy()
    res = np.inf
    for _ in range(iterations):
        fu, fv = distort(dist, u, v)
        ru, rv = fu - xd, fv - yd
        res = float(max(np.abs(ru).max(initial=0.0), np.abs(rv).max(initial=0.0)))
        if res < tol:
            break
        r2 = u * u + v * v
        radial = k1 * r2 + k2 * r2 * r2
        g = 2.0 * (k1 + 2.0 * k2 * r2)  # d radial / d(u or v) = g * (u or v)
        juu = 1 + radial + u * u * g + 2 * p1 * v + 6 * p2 * u
        juv = u * v * g + 2 * p1 * u + 2 * p2 * v
        jvu = u * v * g + 2 * p2 * v + 2 * p1 * u
        jvv = 1 + radial + v * v * g + 2 * p2 * u + 6 * p1 * v
        det = juu * jvv - juv * jvu
        u = u - (jvv * ru - juv * rv) / det
        v = v - (-jvu * ru + juu * rv) / det
    return u, v, res


def check_distortion_invertible(cam, dist):
    """Refuse a distortion that is not one-to-one over the image: the radial profile
    r_d(r) = r (1 + k1 r^2 + k2 r^4) must increase up to the corners' undistorted radius and
    Newton must converge at every border pixel."""
    fx, fy, cx, cy = cam.intrinsics()
    xs = np.concatenate([np.linspace(0, cam.w, 65), np.linspace(0, cam.w, 65), np.zeros(65),
                         np.full(65, float(cam.w))])
    ys = np.concatenate([np.zeros(65), np.full(65, float(cam.h)), np.linspace(0, cam.h, 65),
                         np.linspace(0, cam.h, 65)])
    u, v, res = undistort(dist, (xs - cx) / fx, (ys - cy) / fy)
    r_max = float(np.sqrt(u * u + v * v).max())
    r = np.linspace(0, r_max * 1.05, 2001)
    rd = r * (1 + dist[0] * r * r + dist[1] * r ** 4)
    if res > 1e-9 or not np.all(np.diff(rd) > 0):
        raise SystemExit(f"distortion {list(dist)} is not invertible over {cam.id}'s image "
                         f"(undistorted corner radius {r_max:.3f}, Newton residual {res:.1e})")
    return r_max


# --- projections ------------------------------------------------------------------------------


def camera_points(to_world, pts, at_infinity=False):
    """World points (n, 3) (or directions, `at_infinity`) in the COLMAP camera frame of a
    Mitsuba to_world: F R^T (p - o)."""
    r, o = to_world[:3, :3], to_world[:3, 3]
    q = np.asarray(pts, np.float64) - (0.0 if at_infinity else o)
    return q @ (FLIP @ r.T).T


def project(to_world, intr, dist, pts, at_infinity=False):
    """Pixel coordinates (n, 2) (top-left corner 0, pixel centres at +0.5) of world points
    through a camera given by its Mitsuba to_world, COLMAP intrinsics and distortion (None for
    a pinhole); nan behind the camera."""
    fx, fy, cx, cy = intr
    q = camera_points(to_world, pts, at_infinity)
    z = np.where(q[:, 2] > 1e-12, q[:, 2], np.nan)
    u, v = q[:, 0] / z, q[:, 1] / z
    if dist is not None:
        u, v = distort(dist, u, v)
    return np.stack([fx * u + cx, fy * v + cy], axis=1)


def pixel_rays(to_world, intr, dist, x, y):
    """World ray directions (n, 3, unit) through film positions (x, y) in pixels (top-left
    corner 0): lifted through the intrinsics, undistorted, turned into Mitsuba's camera frame
    (x left, y up) and to world. Also returns the local z of the unit direction (for the near
    clip)."""
    fx, fy, cx, cy = intr
    u, v = (np.asarray(x, np.float64) - cx) / fx, (np.asarray(y, np.float64) - cy) / fy
    if dist is not None:
        u, v, res = undistort(dist, u, v)
        if res > 1e-9:
            raise RuntimeError(f"undistortion did not converge (residual {res:.1e})")
    local = np.stack([-u, -v, np.ones_like(u)], axis=1)
    local /= np.linalg.norm(local, axis=1, keepdims=True)
    return local @ to_world[:3, :3].T, local[:, 2]


# --- COLMAP frame and files -------------------------------------------------------------------


def colmap_pose(to_world, sim):
    """World-to-camera (R_cw, t_cw) in the COLMAP frame of a Mitsuba to_world, where
    sim = (s, R, t) maps COLMAP points to scene points X = s R Xc + t."""
    s, rs, ts = sim
    r, o = to_world[:3, :3], to_world[:3, 3]
    r_cw = FLIP @ r.T @ rs
    t_cw = FLIP @ r.T @ (ts - o) / s
    return r_cw, t_cw


def similarity_matrix(sim):
    s, r, t = sim
    m = np.eye(4)
    m[:3, :3] = s * r
    m[:3, 3] = t
    return m


def _g(x):
    """Shortest text that reads back as the same double."""
    return repr(float(x))


def camera_params(model, intr, dist):
    fx, fy, cx, cy = intr
    if model == "PINHOLE":
        return [fx, fy, cx, cy]
    if model == "OPENCV":
        return [fx, fy, cx, cy, dist[0], dist[1], dist[2], dist[3]]
    if model == "RADIAL":
        if abs(fx - fy) > 1e-9 * fx or dist[2] or dist[3]:
            raise SystemExit("RADIAL needs fx = fy and no tangential distortion")
        return [fx, cx, cy, dist[0], dist[1]]
    raise SystemExit(f"unknown COLMAP model {model}")


def write_colmap(out_dir, entries, sim):
    """entries: [(image_id, camera_id, model, w, h, params, qvec, tvec, name)]. Writes the text
    model (single spaces, no trailing space: COLMAP's reader splits on ' ') and to_world.txt."""
    os.makedirs(out_dir, exist_ok=True)
    with open(os.path.join(out_dir, "cameras.txt"), "w") as fh:
        fh.write("# Camera list with one line of data per camera:\n")
        fh.write("#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n")
        fh.write(f"# Number of cameras: {len(entries)}\n")
        for e in entries:
            fh.write(" ".join([str(e[1]), e[2], str(e[3]), str(e[4])] + [_g(p) for p in e[5]]) + "\n")
    with open(os.path.join(out_dir, "images.txt"), "w") as fh:
        fh.write("# Image list with two lines of data per image:\n")
        fh.write("#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME\n")
        fh.write("#   POINTS2D[] as (X, Y, POINT3D_ID)\n")
        fh.write(f"# Number of images: {len(entries)}, mean observations per image: 0\n")
        for e in entries:
            fh.write(" ".join([str(e[0])] + [_g(q) for q in e[6]] + [_g(t) for t in e[7]]
                              + [str(e[1]), e[8]]) + "\n")
            fh.write("\n")  # no 2D points
    with open(os.path.join(out_dir, "points3D.txt"), "w") as fh:
        fh.write("# 3D point list with one line of data per point:\n")
        fh.write("#   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)\n")
        fh.write("# Number of points: 0, mean track length: 0\n")
    with open(os.path.join(out_dir, "to_world.txt"), "w") as fh:
        fh.write("# kdmap: 4x4 similarity COLMAP -> scene, row-major: X_scene = M[:3,:3] X_colmap + M[:3,3]\n")
        for row in similarity_matrix(sim):
            fh.write(" ".join(_g(x) for x in row) + "\n")


# ------------------------------------------------------------------------------------------
# Rendering


def _set_to_world_matrix(sensor, m):
    for tr in list(sensor.findall("transform")):
        if tr.get("name") == "to_world":
            sensor.remove(tr)
    tr = ET.Element("transform", {"name": "to_world"})
    ET.SubElement(tr, "matrix", {"value": " ".join(_g(x) for x in np.asarray(m).reshape(-1))})
    sensor.insert(0, tr)


def truth_with_cameras(truth_xml, cams):
    """truth.xml's text with only the sensors `cams` (their ids), each with its to_world as a
    matrix (the true pose). Sensors missing from truth.xml are taken from nowhere: refused."""
    root = ET.parse(truth_xml).getroot()
    by_id = {s.get("id"): s for s in root.findall("sensor")}
    for s in root.findall("sensor"):
        root.remove(s)
    at = 0
    for i, child in enumerate(list(root)):
        if child.tag == "integrator":
            at = i + 1
    for k, c in enumerate(cams):
        if c.id not in by_id:
            raise SystemExit(f"{truth_xml} has no sensor {c.id}")
        s = by_id[c.id]
        _set_to_world_matrix(s, c.to_world)
        root.insert(at + k, s)
    return ET.tostring(root, encoding="unicode")


class Renderer:
    """truth.xml loaded once (with the true cameras) in llvm_ad_rgb (scalar_rgb without libLLVM):
    mi.render for pinhole photos, the exact distorted render, and first hits of rays."""

    def __init__(self, truth_xml, cams, variant="auto", max_samples=4_000_000, log=print):
        mi = mitsuba()
        self.mi, self.log, self.max_samples = mi, log, max_samples
        if variant == "auto":
            import heldout

            heldout.ensure_libllvm()
            variant = LLVM if heldout._llvm_available() else "scalar_rgb"
        self.variant = variant
        self.cams = cams
        text = truth_with_cameras(truth_xml, cams)
        t0 = time.time()
        with mi.variant_context(variant):
            self.scene = _load_string(text, os.path.dirname(os.path.abspath(truth_xml)), optimize=False)
            self.index = {s.id(): i for i, s in enumerate(self.scene.sensors())}
        self.load_seconds = time.time() - t0

    def render_pinhole(self, cam, spp, seed):
        """mi.render of the sensor `cam.id` in passes of at most max_samples samples, averaged
        (exact for the box filter). Linear RGB float64 (h, w, 3)."""
        mi = self.mi
        per = max(1, min(spp, self.max_samples // (cam.w * cam.h)))
        acc, done, k = None, 0, 0
        with mi.variant_context(self.variant):
            while done < spp:
                n = min(per, spp - done)
                s = (seed * 1000003 + k * 7919) % (2 ** 31)
                img = np.array(mi.render(self.scene, sensor=self.index[cam.id], spp=n, seed=s),
                               dtype=np.float64)[:, :, -3:]
                acc = img * n if acc is None else acc + img * n
                done += n
                k += 1
        return acc / spp

    def render_distorted(self, cam, intr, dist, spp, seed):
        """The photo of `cam` through the distortion, exactly (see the module docstring): per
        pixel the mean of `spp` path-traced samples whose film positions follow the pixel
        filter (box: uniform over the pixel; tent: separable tent of its radius) and whose rays
        come from pixel_rays. Linear RGB float64 (h, w, 3)."""
        mi = self.mi
        if self.variant != LLVM:
            raise SystemExit("distorted renders need the llvm_ad_rgb variant (libLLVM)")
        import drjit as dr

        rf = cam.rfilter
        if rf["type"] == "box":
            def offsets(rng, n):
                return rng.random(n)
        elif rf["type"] == "tent":
            radius = rf.get("radius", 1.0)

            def offsets(rng, n):  # tent on [-radius, radius], as (u1 + u2 - 1) * radius
                return 0.5 + radius * (rng.random(n) + rng.random(n) - 1.0)
        else:
            raise SystemExit(f"{cam.id}: the distorted render supports box and tent filters, not {rf['type']}")
        npix = cam.w * cam.h
        per = max(1, min(spp, self.max_samples // npix))
        acc = np.zeros((npix, 3))
        done, k = 0, 0
        with mi.variant_context(self.variant):
            sensor = self.scene.sensors()[self.index[cam.id]]
            integrator = self.scene.integrator()
            while done < spp:
                n = min(per, spp - done)
                rng = np.random.default_rng([seed, k])
                idx = np.repeat(np.arange(npix), n)
                x = (idx % cam.w) + offsets(rng, idx.size)
                y = (idx // cam.w) + offsets(rng, idx.size)
                d, dz = pixel_rays(cam.to_world, intr, dist, x, y)
                near_t = cam.near / dz
                far_t = cam.far / dz
                o = cam.origin[None, :] + d * near_t[:, None]

                def f3(a):
                    a = np.ascontiguousarray(a.astype(np.float32))
                    return mi.Float(a[:, 0]), mi.Float(a[:, 1]), mi.Float(a[:, 2])

                ray = mi.Ray3f(mi.Point3f(*f3(o)), mi.Vector3f(*f3(d)))
                ray.maxt = mi.Float((far_t - near_t).astype(np.float32))
                sampler = sensor.sampler().clone()
                # an opaque seed, not a literal baked into the kernel (each pass still compiles
                # its kernel, ~0.25 s, as Dr.Jit's hash differs between passes here)
                sampler.seed(dr.opaque(mi.UInt32, (seed * 1000003 + k * 7919) % (2 ** 31)), idx.size)
                spec = integrator.sample(self.scene, sampler, ray)[0]
                val = np.array(spec, dtype=np.float64)
                val = val.T if val.shape[0] == 3 else val
                val = np.where(np.isfinite(val), val, 0.0)
                for c in range(3):
                    acc[:, c] += np.bincount(idx, weights=val[:, c], minlength=npix)
                del ray, sampler, spec
                dr.flush_malloc_cache()
                done += n
                k += 1
        return (acc / spp).reshape(cam.h, cam.w, 3)

    def first_hits(self, o, d):
        """Distance to the first hit of rays from `o` (3,) along unit `d` (n, 3); inf on a miss."""
        mi = self.mi
        n = len(d)
        with mi.variant_context(self.variant):
            if self.variant == LLVM:
                a = np.ascontiguousarray(d.astype(np.float32))
                ray = mi.Ray3f(mi.Point3f(*(mi.Float(np.full(n, float(x), np.float32)) for x in o)),
                               mi.Vector3f(mi.Float(a[:, 0]), mi.Float(a[:, 1]), mi.Float(a[:, 2])))
                si = self.scene.ray_intersect(ray)
                valid = np.array(si.is_valid())
                return np.where(valid, np.array(si.t, dtype=np.float64), np.inf)
            t = np.full(n, np.inf)
            for i in range(n):
                si = self.scene.ray_intersect(mi.Ray3f(mi.Point3f(*o), mi.Vector3f(*d[i])))
                if si.is_valid():
                    t[i] = si.t
            return t


def pixel_shift(renderer, nominal, true, intr, dist, step=1):
    """For each pixel centre (every `step`-th) of the nominal camera: the point its ray first
    hits in the true scene (a point at infinity for a miss), projected through the true camera;
    the distance from that projection to the pixel centre, in pixels. Returns the statistics."""
    ys, xs = np.mgrid[0:nominal.h:step, 0:nominal.w:step]
    x, y = xs.reshape(-1) + 0.5, ys.reshape(-1) + 0.5
    d, _ = pixel_rays(nominal.to_world, intr, dist, x, y)
    t = renderer.first_hits(nominal.origin, d)
    hit = np.isfinite(t)
    p = np.empty((len(d), 2))
    if hit.any():
        pts = nominal.origin + d[hit] * t[hit, None]
        p[hit] = project(true.to_world, intr, dist, pts)
    if (~hit).any():
        p[~hit] = project(true.to_world, intr, dist, d[~hit], at_infinity=True)
    s = np.linalg.norm(p - np.stack([x, y], axis=1), axis=1)
    s = s[np.isfinite(s)]
    return {"mean": float(s.mean()), "median": float(np.median(s)), "p95": float(np.percentile(s, 95)),
            "max": float(s.max()), "pixels": int(s.size), "missed_pixels": int((~hit).sum()),
            "pixel_step": step}


# ------------------------------------------------------------------------------------------
# Plan: every random choice, drawn before anything is rendered


def _range(s, name):
    v = _floats(s) if isinstance(s, str) else list(s)
    if len(v) != 2 or not (0 < v[0] <= v[1]):
        raise SystemExit(f"--{name} takes LO,HI with 0 < LO <= HI")
    return v


def make_plan(cams, a):
    """Per view: gain, white balance, pose perturbation; the COLMAP similarity; render seeds.
    Independent streams of the seed per purpose (so options do not shift each other's draws)."""
    rng_exp = np.random.default_rng([a.seed, 1])
    rng_pose = np.random.default_rng([a.seed, 2])
    rng_sim = np.random.default_rng([a.seed, 3])
    lo, hi = _range(a.exposure, "exposure") if a.exposure else (1.0, 1.0)
    views = []
    for i, c in enumerate(cams):
        g = float(math.exp(rng_exp.uniform(math.log(lo), math.log(hi))))
        dr_, db_ = rng_exp.uniform(-1.0, 1.0, 2) * (a.white_balance or 0.0)
        axis = random_unit(rng_pose)
        tdir = random_unit(rng_pose)
        dist_t = float(np.linalg.norm(c.target - c.origin))
        rot = axis_angle(axis, math.radians(a.pose_deg or 0.0))
        shift = tdir * (a.pose_dist or 0.0) * dist_t
        m = np.eye(4)
        m[:3, :3] = rot @ c.to_world[:3, :3]
        m[:3, 3] = c.origin + shift
        views.append(dict(
            gain=g if a.exposure else 1.0,
            white_balance=[1.0 + float(dr_), 1.0, 1.0 + float(db_)] if a.white_balance else [1.0, 1.0, 1.0],
            pose_axis=axis, pose_rot=rot, pose_shift=shift, target_distance=dist_t,
            true_to_world=m if (a.pose_deg or a.pose_dist) else c.to_world.copy(),
            render_seed=int((a.seed * 7727 + 104729 * (i + 1)) % (2 ** 31)),
        ))
    # COLMAP frame: X_scene = s R X_colmap + t
    extent = float(np.mean([v["target_distance"] for v in views])) if views else 1.0
    r = random_rotation(rng_sim)
    s = float(math.exp(rng_sim.uniform(*np.log(COLMAP_SCALE_RANGE))))
    t = random_unit(rng_sim) * extent * float(rng_sim.uniform(0.0, 2.0))
    sim = (1.0, np.eye(3), np.zeros(3)) if a.colmap_identity else (s, r, t)
    return views, sim


# ------------------------------------------------------------------------------------------
# Output


def write_exr32(path, img):
    mi = mitsuba()
    mi.Bitmap(np.ascontiguousarray(img.astype(np.float32)), mi.Bitmap.PixelFormat.RGB).write(path)


def write_ldr(path, codes, fmt, quality, subsampling):
    from PIL import Image

    im = Image.fromarray(np.ascontiguousarray(codes), "RGB")
    if fmt == "png":
        im.save(path, format="PNG")
    else:
        im.save(path, format="JPEG", quality=int(quality), subsampling=subsampling, optimize=False)


def read_ldr(path):
    from PIL import Image

    with Image.open(path) as im:
        return np.array(im.convert("RGB"))


def _copy_scene(src, out, keep_albedo):
    skip = {"images", "capture.json", "sparse"} | (set() if keep_albedo else {"albedo"})
    for name in sorted(os.listdir(src)):
        if name in skip:
            continue
        s, d = os.path.join(src, name), os.path.join(out, name)
        if os.path.isdir(s):
            shutil.copytree(s, d)
        else:
            shutil.copy2(s, d)


def _prepare_out(out, src):
    if os.path.abspath(out) == os.path.abspath(src):
        raise SystemExit("--out must differ from the source scene")
    if os.path.isdir(out) and os.listdir(out):
        if not os.path.exists(os.path.join(out, "capture.json")):
            raise SystemExit(f"{out} exists and is not a degraded capture (no capture.json); not touching it")
        shutil.rmtree(out)
    os.makedirs(out, exist_ok=True)


def _mat(m):
    return [[float(x) for x in row] for row in np.asarray(m)]


def degrade(src, out, a, log=print):
    """Write the degraded copy of scene `src` into `out` per the options `a`; returns the
    capture.json dict."""
    t_all = time.time()
    src = os.path.abspath(src)
    out = os.path.abspath(out)
    for f in ("input.xml", "truth.xml"):
        if not os.path.exists(os.path.join(src, f)):
            raise SystemExit(f"{src} is not a kdmap scene directory (no {f})")
    dist = None
    model = "PINHOLE"
    if a.distortion is not None:
        k = _floats(a.distortion)
        if len(k) != 2:
            raise SystemExit("--distortion takes k1,k2")
        dist = (k[0], k[1], 0.0, 0.0)
        model = a.colmap_model.upper()
        if not a.colmap:
            log("  note: --distortion implies --colmap (the only place the distortion is stated)")
            a.colmap = True
    if a.ldr and a.ldr not in ("png", "jpg"):
        raise SystemExit("--ldr takes png or jpg")
    if a.jpeg_quality is None:
        a.jpeg_quality = 90
    if a.jpeg_subsampling is None:
        a.jpeg_subsampling = "4:2:0"
    cams = load_cameras(os.path.join(src, "input.xml"))
    if not cams:
        raise SystemExit(f"{src}/input.xml has no sensors")
    truth_cams = {c.id: c for c in load_cameras(os.path.join(src, "truth.xml"))}
    for c in cams:
        t = truth_cams.get(c.id)
        if t is None or (t.w, t.h) != (c.w, c.h) or abs(t.x_fov - c.x_fov) > 1e-9 \
                or np.abs(t.to_world - c.to_world).max() > 1e-9:
            raise SystemExit(f"{src}: sensor {c.id} of input.xml is not the same camera in truth.xml")
    for c in cams:
        if dist is not None:
            check_distortion_invertible(c, dist)
    views, sim = make_plan(cams, a)
    moved = bool(a.pose_deg or a.pose_dist)
    rerender = moved or dist is not None or a.rerender
    _prepare_out(out, src)
    _copy_scene(src, out, keep_albedo=not (moved or dist is not None))
    os.makedirs(os.path.join(out, "images"), exist_ok=True)
    t_copy = time.time() - t_all

    timings = {"copy_seconds": round(t_copy, 2)}
    linear = {}
    renderer = None
    render_info = None
    if rerender:
        if a.nice:
            try:
                os.nice(a.nice)
            except OSError:
                pass
        true_cams = [c.moved(v["true_to_world"]) for c, v in zip(cams, views)]
        renderer = Renderer(os.path.join(src, "truth.xml"), true_cams, a.variant, a.max_samples, log)
        log(f"  loaded truth.xml ({renderer.variant}) in {renderer.load_seconds:.1f} s")
        render_info = {"variant": renderer.variant, "mitsuba": mitsuba().__version__, "views": {},
                       "method": ("exact through the distortion (integrator.sample on rays of the "
                                  "distorted pixels)" if dist is not None else "mi.render"),
                       "load_seconds": round(renderer.load_seconds, 2)}
        for c, tc, v in zip(cams, true_cams, views):
            spp = (c.spp or 256) if str(a.spp) == "source" else int(a.spp)
            t0 = time.time()
            if dist is not None:
                img = renderer.render_distorted(tc, c.intrinsics(), dist, spp, v["render_seed"])
            else:
                img = renderer.render_pinhole(tc, spp, v["render_seed"])
            dt = time.time() - t0
            linear[c.id] = img
            render_info["views"][c.id] = {"spp": spp, "source_spp": c.spp, "seed": v["render_seed"],
                                          "seconds": round(dt, 2), "filter": c.rfilter}
            log(f"    rendered {c.id}: {c.w}x{c.h}, {spp} spp, {dt:.1f} s")
        timings["render_seconds"] = round(sum(r["seconds"] for r in render_info["views"].values()), 2)
    else:
        for c in cams:
            p = os.path.join(src, "images", f"{c.id}.exr")
            if not os.path.exists(p):
                raise SystemExit(f"missing photo {p}")
            linear[c.id] = read_exr_rgb(p).astype(np.float64)

    # 8-bit scale
    ldr_scale = 1.0
    p99 = None
    if a.ldr:
        allv = np.concatenate([img.reshape(-1) for img in linear.values()])
        p99 = float(np.percentile(allv, LDR_PERCENTILE))
        ldr_scale = float(a.ldr_scale) if a.ldr_scale else LDR_TARGET / p99

    rec_views = {}
    entries = []
    for i, (c, v) in enumerate(zip(cams, views)):
        factor = ldr_scale * v["gain"] * np.array(v["white_balance"])
        img = linear[c.id] * factor
        rv = {"index": i, "gain": v["gain"], "white_balance": v["white_balance"],
              "factor": [float(x) for x in factor]}
        if a.ldr:
            ext = "png" if a.ldr == "png" else "jpg"
            name = f"{c.id}.{ext}"
            codes = to_srgb8(img)
            write_ldr(os.path.join(out, "images", name), codes, a.ldr, a.jpeg_quality, a.jpeg_subsampling)
            rv["clipped_fraction"] = float((img >= 1.0).any(axis=2).mean())
            rv["clipped_channel_fraction"] = float((img >= 1.0).mean())
        else:
            name = f"{c.id}.exr"
            write_exr32(os.path.join(out, "images", name), img)
        rv["image"] = f"images/{name}"
        tw = v["true_to_world"]
        rv["nominal_to_world"] = _mat(c.to_world)
        rv["true_to_world"] = _mat(tw)
        fwd, up = tw[:3, 2], tw[:3, 1]
        rv["true_lookat"] = {"origin": tw[:3, 3].tolist(),
                             "target": (tw[:3, 3] + fwd * v["target_distance"]).tolist(),
                             "up": up.tolist()}
        rv["intrinsics"] = dict(zip(("fx", "fy", "cx", "cy"), c.intrinsics()), width=c.w, height=c.h,
                                x_fov=c.x_fov)
        if moved:
            rv["pose_offset"] = {"rotation_deg": float(a.pose_deg or 0.0),
                                 "rotation_axis": v["pose_axis"].tolist(),
                                 "translation": v["pose_shift"].tolist(),
                                 "translation_length": float(np.linalg.norm(v["pose_shift"])),
                                 "target_distance": v["target_distance"]}
            t0 = time.time()
            rv["pixel_shift"] = pixel_shift(renderer, c, c.moved(tw), c.intrinsics(), dist)
            rv["pixel_shift"]["seconds"] = round(time.time() - t0, 2)
        if a.colmap:
            pose_tw = tw if a.colmap_pose == "true" else c.to_world
            r_cw, t_cw = colmap_pose(pose_tw, sim)
            q = matrix_to_quat(r_cw)
            params = camera_params(model, c.intrinsics(), dist)
            entries.append((i + 1, i + 1, model, c.w, c.h, params, q, t_cw, name))
            rv["colmap"] = {"image_id": i + 1, "camera_id": i + 1, "qvec": q.tolist(), "tvec": t_cw.tolist(),
                            "name": name, "model": model, "params": [float(p) for p in params]}
        rec_views[c.id] = rv
        msg = f"    {c.id}: gain {v['gain']:.4f}, wb {[round(x, 4) for x in v['white_balance']]}"
        if moved:
            msg += f", pose shift mean {rv['pixel_shift']['mean']:.2f} px (max {rv['pixel_shift']['max']:.2f})"
        if a.ldr:
            msg += f", clipped {100 * rv['clipped_fraction']:.2f}% of pixels"
        log(msg)
    if a.colmap:
        write_colmap(os.path.join(out, "sparse"), entries, sim)

    rec = {
        "tool": "tools/degrade_capture.py", "tool_version": TOOL_VERSION,
        "source": src, "seed": a.seed, "preset": getattr(a, "preset_name", None),
        "options": {"exposure": _range(a.exposure, "exposure") if a.exposure else None,
                    "white_balance": a.white_balance or 0.0,
                    "pose_deg": a.pose_deg or 0.0, "pose_dist": a.pose_dist or 0.0,
                    "ldr": a.ldr, "jpeg_quality": a.jpeg_quality if a.ldr == "jpg" else None,
                    "jpeg_subsampling": a.jpeg_subsampling if a.ldr == "jpg" else None,
                    "ldr_scale": a.ldr_scale, "colmap": bool(a.colmap),
                    "distortion": list(dist[:2]) if dist is not None else None,
                    "colmap_model": model if a.colmap else None, "colmap_pose": a.colmap_pose,
                    "colmap_identity": bool(a.colmap_identity), "spp": str(a.spp), "rerender": bool(a.rerender)},
        "pipeline": ["re-render from the true camera" if rerender else "source photo (EXR)",
                     "x gain x white balance (linear)"] + (
                         [f"x ldr_scale, clip [0, 1], sRGB, 8 bit, {a.ldr}"] if a.ldr else ["float32 EXR"]),
        "ldr": ({"format": a.ldr, "scale": ldr_scale, "percentile": LDR_PERCENTILE, "percentile_value": p99,
                 "target": LDR_TARGET if not a.ldr_scale else None, "transfer": "sRGB IEC 61966-2-1",
                 "clip": 1.0, "quality": a.jpeg_quality if a.ldr == "jpg" else None,
                 "subsampling": a.jpeg_subsampling if a.ldr == "jpg" else None} if a.ldr else None),
        "albedo_copied": not (moved or dist is not None),
        "render": render_info,
        "views": rec_views,
    }
    if a.colmap:
        s, r, t = sim
        rec["colmap"] = {"dir": "sparse", "model": model, "poses": a.colmap_pose,
                         "to_world": _mat(similarity_matrix(sim)), "scale": s, "rotation": _mat(r),
                         "translation": t.tolist(),
                         "convention": ("X_scene = to_world[:3,:3] X_colmap + to_world[:3,3]; images.txt "
                                        "world-to-camera, camera x right, y down, z forward; pixel "
                                        "centres at +0.5")}
    timings["total_seconds"] = round(time.time() - t_all, 2)
    rec["timings"] = timings
    rec["date"] = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
    with open(os.path.join(out, "capture.json"), "w") as fh:
        json.dump(rec, fh, indent=1)
    return rec


# ------------------------------------------------------------------------------------------


def parse_args(argv):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter,
                                 epilog="presets: " + "; ".join(
                                     f"{k}: {v}" for k, v in PRESETS.items()))
    ap.add_argument("scenes", nargs="+", help="source scene directories (kdmap layout)")
    ap.add_argument("--out", help="output scene directory (one scene, one preset or none)")
    ap.add_argument("--out-root", default=DEFAULT_OUT_ROOT,
                    help="with --preset and no --out: outputs go to <out-root>/<scene>-<preset>")
    ap.add_argument("--preset", help="comma-separated presets: " + ", ".join(PRESETS))
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--exposure", help="LO,HI: per-photo gain, log-uniform")
    ap.add_argument("--white-balance", type=float, help="W: R and B multipliers 1 + U(-W, W)")
    ap.add_argument("--pose-deg", type=float, help="rotation of each training camera, degrees")
    ap.add_argument("--pose-dist", type=float, help="translation, fraction of the camera-target distance")
    ap.add_argument("--spp", default="256", help="samples per pixel of re-rendered photos, or 'source'")
    ap.add_argument("--rerender", action="store_true", help="re-render the photos even without pose change")
    ap.add_argument("--ldr", choices=("png", "jpg"), help="8-bit sRGB output instead of EXR")
    ap.add_argument("--ldr-scale", type=float, help="linear scale before clipping (default: p99 -> 0.9)")
    ap.add_argument("--jpeg-quality", type=int, help="JPEG quality (default 90)")
    ap.add_argument("--jpeg-subsampling", choices=("4:4:4", "4:2:2", "4:2:0"),
                    help="JPEG chroma subsampling (default 4:2:0, what cameras write)")
    ap.add_argument("--colmap", action="store_true", help="write a COLMAP text model in sparse/")
    ap.add_argument("--distortion", help="k1,k2: distort the photos (implies --colmap); write "
                    "--distortion=-0.05,0.01 when k1 is negative")
    ap.add_argument("--colmap-model", default="opencv", choices=("opencv", "radial"),
                    help="model with --distortion (PINHOLE without)")
    ap.add_argument("--colmap-pose", default="nominal", choices=("nominal", "true"))
    ap.add_argument("--colmap-identity", action="store_true", help="COLMAP frame = scene frame")
    ap.add_argument("--variant", default="auto", help="Mitsuba variant for rendering (auto: llvm_ad_rgb)")
    ap.add_argument("--max-samples", type=int, default=4_000_000, help="samples per render pass")
    ap.add_argument("--nice", type=int, default=10, help="lower the priority by N while rendering")
    return ap.parse_args(argv)


def _with_preset(a, name):
    """`a` with the preset's options, except those given on the command line."""
    b = argparse.Namespace(**vars(a))
    for k, v in PRESETS[name].items():
        if getattr(a, k) in (None, False):
            setattr(b, k, v)
    b.preset_name = name
    return b


def main(argv=None):
    a = parse_args(sys.argv[1:] if argv is None else argv)
    presets = [p for p in (a.preset or "").split(",") if p]
    for p in presets:
        if p not in PRESETS:
            raise SystemExit(f"unknown preset {p} (known: {', '.join(PRESETS)})")
    jobs = []
    if a.out:
        if len(a.scenes) > 1 or len(presets) > 1:
            raise SystemExit("--out takes one scene and at most one preset; use --out-root for more")
        jobs.append((a.scenes[0], a.out, _with_preset(a, presets[0]) if presets else a))
    else:
        if not presets:
            raise SystemExit("give --out, or --preset (outputs to <out-root>/<scene>-<preset>)")
        for s in a.scenes:
            for p in presets:
                name = os.path.basename(os.path.normpath(s))
                jobs.append((s, os.path.join(a.out_root, f"{name}-{p}"), _with_preset(a, p)))
    summary = []
    for src, out, opts in jobs:
        print(f"{src} -> {out}", flush=True)
        t0 = time.time()
        degrade(src, out, opts, log=lambda m: print(m, flush=True))
        dt = time.time() - t0
        summary.append((out, dt))
        print(f"  done in {dt:.1f} s", flush=True)
    if len(summary) > 1:
        for out, dt in summary:
            print(f"{dt:8.1f} s  {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
