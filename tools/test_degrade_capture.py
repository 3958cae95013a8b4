#!/usr/bin/env python3
"""Tests of tools/degrade_capture.py (5-10 s here; the only renders are 32x32 ones).

    .venv/bin/python tools/test_degrade_capture.py [-v]

- exposure and white balance: degraded / original EXR per view and channel is exactly the
  factor capture.json records; 8-bit PNG codes are exactly those of the recorded factor; JPEG
  within a few codes of them; held-out views, XML, meshes byte-identical to the source;
- sRGB: the transfer function against colour-science, the 8-bit round trip within half a code;
- COLMAP: the files parsed here (as COLMAP's text reader does) and projected with COLMAP's
  formulas, after the recorded similarity, against Mitsuba's own sensor (sample_ray) and
  Mitsuba's projection of the scene's mesh vertices, to 1e-3 px; with distortion against the
  rays the distorted render traces; quaternion conventions; camera centres;
- the pose offsets (pixel shift) of a known rotation; the exact distorted render at zero
  distortion against mi.render (within noise); a whole `--preset all` run on a 32x32 cbox;
- determinism under the seed, and independent draws per option.
"""

import filecmp
import json
import math
import os
import re
import shutil
import subprocess
import sys
import tempfile
import unittest

import numpy as np

TOOLS = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(TOOLS)
sys.path.insert(0, TOOLS)
import degrade_capture as dc  # noqa: E402
from exrio import mitsuba, quiet_colour, read_exr_rgb  # noqa: E402

FIX = os.path.join(REPO, "tests", "fixtures")
PY = sys.executable


def read_text(path):
    with open(path) as fh:
        return fh.read()


def write_text(path, text):
    with open(path, "w") as fh:
        fh.write(text)


def opts(**kw):
    """The tool's options namespace with `kw` set (command-line defaults otherwise)."""
    a = dc.parse_args(["x"])
    for k, v in kw.items():
        setattr(a, k, v)
    return a


def run_degrade(src, out, **kw):
    return dc.degrade(src, out, opts(**kw), log=lambda m: None)


# --- an independent COLMAP text reader and projection (COLMAP's reconstruction_io_text.cc and
#     sensor/models: OpenCV / Radial / Pinhole)


def read_cameras_txt(path):
    cams = {}
    for line in read_text(path).split("\n"):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        items = line.split(" ")  # COLMAP splits on single spaces: no empty items allowed
        assert all(items), f"empty field in {line!r}"
        cid, model, w, h = int(items[0]), items[1], int(items[2]), int(items[3])
        cams[cid] = (model, w, h, [float(x) for x in items[4:]])
    return cams


def read_images_txt(path):
    imgs = {}
    lines = read_text(path).split("\n")
    i = 0
    while i < len(lines):
        line = lines[i].strip()
        i += 1
        if not line or line.startswith("#"):
            continue
        items = line.split(" ")
        assert all(items), f"empty field in {line!r}"
        q = np.array([float(x) for x in items[1:5]])
        t = np.array([float(x) for x in items[5:8]])
        imgs[int(items[0])] = dict(q=q, t=t, camera_id=int(items[8]), name=items[9])
        i += 1  # the POINTS2D line (empty here) always follows
    return imgs


def qvec2rotmat(q):
    """COLMAP's (w, x, y, z) Hamilton quaternion -> matrix, written out as in its scripts."""
    w, x, y, z = q
    return np.array([
        [1 - 2 * y * y - 2 * z * z, 2 * x * y - 2 * w * z, 2 * z * x + 2 * w * y],
        [2 * x * y + 2 * w * z, 1 - 2 * x * x - 2 * z * z, 2 * y * z - 2 * w * x],
        [2 * z * x - 2 * w * y, 2 * y * z + 2 * w * x, 1 - 2 * x * x - 2 * y * y],
    ])


def colmap_project(cam, img, xw):
    """Pixel coordinates (n, 2) of COLMAP-frame points (n, 3)."""
    model, _, _, p = cam
    xc = xw @ qvec2rotmat(img["q"]).T + img["t"]
    z = np.where(xc[:, 2] > 1e-12, xc[:, 2], np.nan)  # behind the camera: not projectable (COLMAP's cheirality)
    u, v = xc[:, 0] / z, xc[:, 1] / z
    if model == "PINHOLE":
        fx, fy, cx, cy = p
        k1 = k2 = p1 = p2 = 0.0
    elif model == "OPENCV":
        fx, fy, cx, cy, k1, k2, p1, p2 = p
    elif model == "RADIAL":
        fx, cx, cy, k1, k2 = p
        fy, p1, p2 = fx, 0.0, 0.0
    else:
        raise AssertionError(model)
    r2 = u * u + v * v
    radial = k1 * r2 + k2 * r2 * r2
    du = u * radial + 2 * p1 * u * v + p2 * (r2 + 2 * u * u)
    dv = v * radial + 2 * p2 * u * v + p1 * (r2 + 2 * v * v)
    return np.stack([fx * (u + du) + cx, fy * (v + dv) + cy], axis=1)


def read_to_world(path):
    rows = [r for r in read_text(path).split("\n") if r.strip() and not r.startswith("#")]
    return np.array([[float(x) for x in r.split(" ")] for r in rows])


def to_colmap_frame(m, pts):
    """Scene points -> COLMAP frame, inverting X_scene = M[:3,:3] X + M[:3,3] (a similarity)."""
    return np.linalg.solve(m[:3, :3], (pts - m[:3, 3]).T).T


def mitsuba_sensors(xml_path):
    """{id: sensor} of xml_path's sensors loaded by Mitsuba (scalar_rgb), without the shapes."""
    mi = mitsuba()
    text = read_text(xml_path)
    text = re.sub(r"<shape.*?</shape>", "", text, flags=re.S)
    text = re.sub(r"<emitter.*?</emitter>", "", text, flags=re.S)
    scene = mi.load_string(text)
    return {s.id(): s for s in scene.sensors()}


def mesh_vertices(scene_dir):
    pts = []
    for f in sorted(os.listdir(os.path.join(scene_dir, "meshes"))):
        if f.endswith(".obj"):
            for line in read_text(os.path.join(scene_dir, "meshes", f)).split("\n"):
                if line.startswith("v "):
                    pts.append([float(x) for x in line.split()[1:4]])
    return np.array(pts)


def tiny_scene(dst, src=os.path.join(FIX, "cbox"), size=32):
    """A copy of `src` whose films are size x size (photos not resized: only re-rendered
    variants use it)."""
    shutil.copytree(src, dst)
    for f in ("input.xml", "truth.xml", "relit.xml"):
        p = os.path.join(dst, f)
        t = re.sub(r'(name="(width|height)" value=")\d+', rf"\g<1>{size}", read_text(p))
        write_text(p, t)
    return dst


class TmpDir(unittest.TestCase):
    def setUp(self):
        self.tmp = tempfile.mkdtemp(prefix="degrade-test-")

    def tearDown(self):
        shutil.rmtree(self.tmp, ignore_errors=True)


# ---------------------------------------------------------------------------------------------


class SRGB(unittest.TestCase):
    def test_transfer_function_matches_colour_science(self):
        colour = quiet_colour()
        x = np.concatenate([np.linspace(0, 1, 20001), [0.0031308, 0.04045 / 12.92]])
        np.testing.assert_allclose(dc.srgb_encode(x), colour.cctf_encoding(x, function="sRGB"), atol=1e-12)
        e = np.linspace(0, 1, 20001)
        # at the break 0.04045 the standard's two pieces differ by 2.3e-9 (colour-science takes
        # the power piece there, IEC 61966-2-1 the linear one)
        np.testing.assert_allclose(dc.srgb_decode(e), colour.cctf_decoding(e, function="sRGB"), rtol=0, atol=3e-9)
        self.assertLess(np.abs(dc.srgb_decode(e) - colour.cctf_decoding(e, function="sRGB"))[e != 0.04045].max(), 1e-15)

    def test_8bit_round_trip_within_half_a_code(self):
        x = np.linspace(0, 1, 200001)
        codes = dc.to_srgb8(x)
        # the code is the nearest one in the encoded domain ...
        self.assertLessEqual(np.abs(dc.srgb_encode(x) * 255 - codes).max(), 0.5 + 1e-9)
        # ... so decoding is within half a code of the value, in linear terms too
        back = dc.from_srgb8(codes)
        lo = dc.srgb_decode(np.clip((codes - 0.5) / 255, 0, 1))
        hi = dc.srgb_decode(np.clip((codes + 0.5) / 255, 0, 1))
        self.assertTrue(np.all((x >= lo - 1e-12) & (x <= hi + 1e-12)))
        self.assertLess(np.abs(back - x).max(), 0.5 / 255 * 2.4 * 1.0 + 1e-9)  # slope of decode <= 2.4 at 1
        # every code decodes and re-encodes to itself; clipping at 0 and 1
        c = np.arange(256)
        np.testing.assert_array_equal(dc.to_srgb8(dc.from_srgb8(c)), c)
        np.testing.assert_array_equal(dc.to_srgb8(np.array([-1.0, 1.0, 7.0])), [0, 255, 255])


class Quaternions(unittest.TestCase):
    def test_matrix_quaternion_round_trip_and_hamilton_convention(self):
        rng = np.random.default_rng(5)
        for _ in range(200):
            r = dc.random_rotation(rng)
            self.assertAlmostEqual(np.linalg.det(r), 1.0, places=12)
            q = dc.matrix_to_quat(r)
            self.assertGreaterEqual(q[0], 0.0)
            np.testing.assert_allclose(qvec2rotmat(q), r, atol=1e-12)
        # Hamilton: (cos 45, 0, 0, sin 45) turns +x into +y (90 degrees about +z)
        q = np.array([math.cos(math.pi / 4), 0, 0, math.sin(math.pi / 4)])
        np.testing.assert_allclose(dc.quat_to_matrix(q) @ [1, 0, 0], [0, 1, 0], atol=1e-15)
        np.testing.assert_allclose(dc.axis_angle([0, 0, 1], math.pi / 2) @ [1, 0, 0], [0, 1, 0], atol=1e-15)

    def test_lookat_is_mitsubas(self):
        mi = mitsuba()
        o, t, u = [-0.8, 1.0, 3.6], [0.1, 0.9, 0.0], [0, 1, 0]
        m = np.array(mi.ScalarTransform4f().look_at(origin=o, target=t, up=u).matrix, np.float64)
        np.testing.assert_allclose(dc.lookat_matrix(o, t, u), m, atol=1e-6)


class Exposure(TmpDir):
    def test_gain_and_white_balance_applied_exactly_per_capture_json(self):
        src = os.path.join(FIX, "cbox-tex")
        out = os.path.join(self.tmp, "exp")
        rec = run_degrade(src, out, exposure="0.5,1.9", white_balance=0.06)
        self.assertEqual(json.loads(read_text(os.path.join(out, "capture.json")))["views"], json.loads(json.dumps(rec["views"])))
        gains = []
        for vid, v in rec["views"].items():
            a = read_exr_rgb(os.path.join(src, "images", f"{vid}.exr")).astype(np.float64)
            b = read_exr_rgb(os.path.join(out, v["image"])).astype(np.float64)
            self.assertEqual(a.shape, b.shape)
            g, wb = v["gain"], v["white_balance"]
            self.assertTrue(0.5 <= g <= 1.9)
            self.assertEqual(wb[1], 1.0)
            self.assertTrue(all(abs(w - 1) <= 0.06 for w in wb))
            np.testing.assert_allclose(v["factor"], g * np.array(wb), rtol=1e-15)
            for c in range(3):
                m = a[..., c] > 1e-4
                ratio = b[..., c][m] / a[..., c][m]
                np.testing.assert_allclose(ratio, v["factor"][c], rtol=2e-7)
            gains.append(g)
        self.assertGreater(max(gains) / min(gains), 1.01)  # they differ per view
        # everything else is the source's, byte for byte; nothing moved so albedo/ is kept
        for rel in ("input.xml", "truth.xml", "relit.xml", "truth/cam_test_0.exr", "truth/cam_test_1_relit.exr",
                    "meshes/left.obj", "textures/brick.png", "albedo/cam_train_0.exr"):
            self.assertTrue(filecmp.cmp(os.path.join(src, rel), os.path.join(out, rel), shallow=False), rel)
        self.assertFalse(os.path.exists(os.path.join(out, "sparse")))

    def test_png_codes_are_those_of_the_recorded_factor_and_jpeg_close(self):
        src = os.path.join(FIX, "cbox")
        out_png, out_jpg = os.path.join(self.tmp, "png"), os.path.join(self.tmp, "jpg")
        rp = run_degrade(src, out_png, exposure="0.5,1.9", white_balance=0.06, ldr="png")
        rj = run_degrade(src, out_jpg, exposure="0.5,1.9", white_balance=0.06, ldr="jpg")
        self.assertEqual(rp["ldr"]["scale"], rj["ldr"]["scale"])
        # the scale maps the 99th percentile of the photos' channel values to 0.9
        allv = np.concatenate([read_exr_rgb(os.path.join(src, "images", f"{v}.exr")).reshape(-1)
                               for v in rp["views"]]).astype(np.float64)
        self.assertAlmostEqual(rp["ldr"]["scale"] * np.percentile(allv, 99), 0.9, places=9)
        for vid, v in rp["views"].items():
            a = read_exr_rgb(os.path.join(src, "images", f"{vid}.exr")).astype(np.float64)
            expect = dc.to_srgb8(a * np.array(v["factor"]))
            self.assertTrue(v["image"].endswith(".png"))
            np.testing.assert_array_equal(dc.read_ldr(os.path.join(out_png, v["image"])), expect)
            np.testing.assert_allclose(v["factor"], rp["ldr"]["scale"] * v["gain"] * np.array(v["white_balance"]),
                                       rtol=1e-15)
            self.assertAlmostEqual(v["clipped_fraction"], float((a * v["factor"] >= 1).any(axis=2).mean()))
            j = dc.read_ldr(os.path.join(out_jpg, rj["views"][vid]["image"])).astype(np.float64)
            self.assertEqual(j.shape, expect.shape)
            self.assertLess(np.abs(j - expect).mean(), 2.5)  # JPEG q90, 4:2:0
            # decoded / factor recovers the radiance where nothing clipped, within quantisation
            lin = dc.from_srgb8(expect) / np.array(v["factor"])
            ok = (a * v["factor"] < 0.99) & (a * v["factor"] > 0.05)
            self.assertLess(np.abs(lin[ok] - a[ok]).max() / a[ok].min(), 0.5)
            self.assertLess(np.median(np.abs(lin[ok] / a[ok] - 1)), 0.01)

    def test_refuses_to_overwrite_what_it_did_not_write(self):
        out = os.path.join(self.tmp, "other")
        os.makedirs(out)
        write_text(os.path.join(out, "precious.txt"), "x")
        with self.assertRaises(SystemExit):
            run_degrade(os.path.join(FIX, "cbox"), out, exposure="0.5,1.9")
        self.assertTrue(os.path.exists(os.path.join(out, "precious.txt")))


class Colmap(TmpDir):
    def check_against_mitsuba(self, src, out, rec, pixels=4000):
        cams = read_cameras_txt(os.path.join(out, "sparse", "cameras.txt"))
        imgs = read_images_txt(os.path.join(out, "sparse", "images.txt"))
        self.assertEqual(read_text(os.path.join(out, "sparse", "points3D.txt")).count("\n"), 3)
        m = read_to_world(os.path.join(out, "sparse", "to_world.txt"))
        np.testing.assert_allclose(m, rec["colmap"]["to_world"], rtol=0, atol=0)
        sensors = mitsuba_sensors(os.path.join(src, "input.xml"))
        mi = mitsuba()
        verts = mesh_vertices(src)
        rng = np.random.default_rng(11)
        worst = 0.0
        for iid, img in imgs.items():
            vid = img["name"].rsplit(".", 1)[0]
            self.assertEqual(rec["views"][vid]["image"], "images/" + img["name"])
            cam = cams[img["camera_id"]]
            sensor = sensors[vid]
            w, h = cam[1], cam[2]
            # (1) points along Mitsuba's own rays through random film positions
            fx_, fy_ = rng.random(pixels) * w, rng.random(pixels) * h
            pts = []
            for x, y in zip(fx_, fy_):
                ray, _ = sensor.sample_ray(0.0, 0.5, mi.Point2f(x / w, y / h), mi.Point2f(0.5, 0.5))
                t = rng.uniform(0.5, 10.0)
                pts.append(np.array(ray.o, np.float64) + t * np.array(ray.d, np.float64))
            got = colmap_project(cam, img, to_colmap_frame(m, np.array(pts)))
            expect = np.stack([fx_, fy_], 1)
            if cam[0] != "PINHOLE":
                expect = self.distorted(cam, expect)
            err = np.abs(got - expect).max()
            worst = max(worst, err)
            self.assertLess(err, 1e-3, f"{vid}: COLMAP vs Mitsuba sample_ray, {err:.2e} px")
            # (2) the scene's mesh vertices, projected by Mitsuba's perspective formulas
            #     (heldout._Camera, checked there against sample_ray)
            import heldout

            hc = heldout._Camera(sensor)
            pm, inside = hc.project(verts)
            if cam[0] != "PINHOLE":
                pm = self.distorted(cam, pm)
            got = colmap_project(cam, img, to_colmap_frame(m, verts))
            self.assertGreater(inside.sum(), 10)
            err = np.abs(got[inside] - pm[inside]).max()
            worst = max(worst, err)
            self.assertLess(err, 1e-3, f"{vid}: COLMAP vs Mitsuba projection of vertices, {err:.2e} px")
            # (3) camera centre -R^T t, mapped to the scene, is the sensor's position
            c = -qvec2rotmat(img["q"]).T @ img["t"]
            np.testing.assert_allclose(m[:3, :3] @ c + m[:3, 3], hc.origin, atol=1e-5)
            # (4) looking along +z: the optical axis hits the image centre
            fwd = hc.to_world[:3, 2]
            p = colmap_project(cam, img, to_colmap_frame(m, (hc.origin + 3 * fwd)[None]))
            np.testing.assert_allclose(p[0], [w / 2, h / 2], atol=1e-4)
        return worst

    @staticmethod
    def distorted(cam, px):
        """Undistorted pixel positions of a camera -> distorted ones (COLMAP's formula)."""
        model, _, _, p = cam
        if model == "OPENCV":
            fx, fy, cx, cy, k1, k2, p1, p2 = p
        else:
            fx, cx, cy, k1, k2 = p
            fy, p1, p2 = fx, 0.0, 0.0
        u, v = (px[:, 0] - cx) / fx, (px[:, 1] - cy) / fy
        r2 = u * u + v * v
        rad = k1 * r2 + k2 * r2 * r2
        du = u * rad + 2 * p1 * u * v + p2 * (r2 + 2 * u * u)
        dv = v * rad + 2 * p2 * u * v + p1 * (r2 + 2 * v * v)
        return np.stack([fx * (u + du) + cx, fy * (v + dv) + cy], 1)

    def test_pinhole_round_trip_through_a_random_similarity(self):
        for scene in ("cbox", "envmap"):
            src = os.path.join(FIX, scene)
            out = os.path.join(self.tmp, scene)
            rec = run_degrade(src, out, colmap=True, seed=3)
            s = rec["colmap"]["scale"]
            self.assertNotAlmostEqual(s, 1.0, places=3)  # a real similarity, not the identity
            self.assertEqual(read_text(os.path.join(out, "sparse", "cameras.txt")).count(" PINHOLE "), 3)
            self.check_against_mitsuba(src, out, rec, pixels=1500)

    def test_known_points_land_on_what_the_photo_shows(self):
        """The flip, on content: the red wall's and the green wall's centres, projected through
        the COLMAP files, land on red and green pixels of cbox's photos, left and right."""
        src = os.path.join(FIX, "cbox")
        out = os.path.join(self.tmp, "known")
        run_degrade(src, out, colmap=True, seed=2)
        m = read_to_world(os.path.join(out, "sparse", "to_world.txt"))
        cams = read_cameras_txt(os.path.join(out, "sparse", "cameras.txt"))
        imgs = read_images_txt(os.path.join(out, "sparse", "images.txt"))
        walls = {}
        for wall in ("left", "right"):
            v = np.array([[float(x) for x in line.split()[1:4]] for line in
                          read_text(os.path.join(src, "meshes", f"{wall}.obj")).split("\n") if line.startswith("v ")])
            walls[wall] = v.mean(0)
        for img in imgs.values():
            photo = read_exr_rgb(os.path.join(src, "images", img["name"]))
            w = cams[img["camera_id"]][1]
            for wall, (channel, side) in (("left", (0, -1)), ("right", (1, 1))):
                x, y = colmap_project(cams[img["camera_id"]], img, to_colmap_frame(m, walls[wall][None]))[0]
                self.assertEqual(np.sign(x - w / 2), side, f"{img['name']}: the {wall} wall's side")
                rgb = photo[int(y) - 2:int(y) + 3, int(x) - 2:int(x) + 3].reshape(-1, 3).mean(0)
                self.assertGreater(rgb[channel], 2 * rgb[1 - channel], f"{img['name']}: {wall} wall colour {rgb}")

    def test_distorted_models_round_trip_and_match_the_rendered_rays(self):
        src = os.path.join(FIX, "cbox-tex")
        cams = dc.load_cameras(os.path.join(src, "input.xml"))
        a = opts(colmap=True, seed=9)
        _, sim = dc.make_plan(cams, a)
        for model, dist in (("OPENCV", (-0.05, 0.01, 0.0, 0.0)), ("RADIAL", (0.08, -0.02, 0.0, 0.0))):
            out = os.path.join(self.tmp, model)
            entries = []
            for i, c in enumerate(cams):
                r_cw, t_cw = dc.colmap_pose(c.to_world, sim)
                entries.append((i + 1, i + 1, model, c.w, c.h, dc.camera_params(model, c.intrinsics(), dist),
                                dc.matrix_to_quat(r_cw), t_cw, f"{c.id}.jpg"))
            dc.write_colmap(os.path.join(out, "sparse"), entries, sim)
            rec = {"colmap": {"to_world": dc.similarity_matrix(sim).tolist()},
                   "views": {c.id: {"image": f"images/{c.id}.jpg"} for c in cams}}
            self.check_against_mitsuba(src, out, rec, pixels=500)
            # the rays the distorted render traces (pixel_rays), read back through the files
            m = read_to_world(os.path.join(out, "sparse", "to_world.txt"))
            ccams = read_cameras_txt(os.path.join(out, "sparse", "cameras.txt"))
            imgs = read_images_txt(os.path.join(out, "sparse", "images.txt"))
            rng = np.random.default_rng(2)
            for c, (iid, img) in zip(cams, sorted(imgs.items())):
                x, y = rng.random(5000) * c.w, rng.random(5000) * c.h
                x[:4], y[:4] = [0, c.w, 0, c.w], [0, 0, c.h, c.h]  # the corners too
                d, _ = dc.pixel_rays(c.to_world, c.intrinsics(), dist, x, y)
                pts = c.origin + d * rng.uniform(0.3, 8.0, (len(d), 1))
                got = colmap_project(ccams[img["camera_id"]], img, to_colmap_frame(m, pts))
                err = np.abs(got - np.stack([x, y], 1)).max()
                self.assertLess(err, 1e-3, f"{model} {c.id}: rendered rays vs COLMAP, {err:.2e} px")

    def test_undistort_inverts_distort_and_bad_distortion_is_refused(self):
        rng = np.random.default_rng(4)
        u, v = rng.uniform(-0.6, 0.6, (2, 10000))
        for dist in ((-0.05, 0.01, 0, 0), (0.1, 0.05, 0.001, -0.002), (-0.2, 0.05, 0, 0)):
            xd, yd = dc.distort(dist, u, v)
            u2, v2, res = dc.undistort(dist, xd, yd)
            self.assertLess(res, 1e-12)
            np.testing.assert_allclose(np.stack([u2, v2]), np.stack([u, v]), atol=1e-11)
        cam = dc.load_cameras(os.path.join(FIX, "cbox", "input.xml"))[0]
        dc.check_distortion_invertible(cam, (-0.05, 0.01, 0, 0))
        with self.assertRaises(SystemExit):  # folds over before the corners
            dc.check_distortion_invertible(cam, (-2.0, 0.0, 0, 0))

    def test_identity_frame_and_true_poses_option(self):
        src = os.path.join(FIX, "cbox")
        out = os.path.join(self.tmp, "id")
        rec = run_degrade(src, out, colmap=True, colmap_identity=True)
        np.testing.assert_array_equal(rec["colmap"]["to_world"], np.eye(4))
        self.check_against_mitsuba(src, out, rec, pixels=300)


class Renders(TmpDir):
    """Tiny Mitsuba renders (32x32): the exact distorted render at k = 0 against mi.render,
    pixel shifts of a known rotation, and one whole `--preset all` run."""

    @classmethod
    def setUpClass(cls):
        cls.tmp_cls = tempfile.mkdtemp(prefix="degrade-tiny-")
        cls.src = tiny_scene(os.path.join(cls.tmp_cls, "cbox-tiny"))

    @classmethod
    def tearDownClass(cls):
        shutil.rmtree(cls.tmp_cls, ignore_errors=True)

    def test_distorted_render_at_zero_distortion_is_mi_render(self):
        cams = dc.load_cameras(os.path.join(self.src, "input.xml"))
        r = dc.Renderer(os.path.join(self.src, "truth.xml"), cams)
        if r.variant != dc.LLVM:
            self.skipTest("needs llvm_ad_rgb")
        c = cams[0]
        a = r.render_distorted(c, c.intrinsics(), (0.0, 0.0, 0.0, 0.0), 512, 1)
        b = r.render_pinhole(c, 512, 2)
        self.assertEqual(a.shape, (32, 32, 3))
        # the same image up to Monte Carlo noise: image means within 1%, 4x4 blocks within 5%
        np.testing.assert_allclose(a.mean((0, 1)), b.mean((0, 1)), rtol=0.01)
        ba = a.reshape(8, 4, 8, 4, 3).mean((1, 3)).sum(-1)
        bb = b.reshape(8, 4, 8, 4, 3).mean((1, 3)).sum(-1)
        lit = bb > 0.05 * bb.max()
        self.assertLess(np.median(np.abs(ba[lit] / bb[lit] - 1)), 0.05)
        # a one-pixel misregistration would show: shifting b by one pixel is much worse
        shifted = np.roll(b, 1, axis=1).reshape(8, 4, 8, 4, 3).mean((1, 3)).sum(-1)
        self.assertGreater(np.abs(shifted - bb)[lit].mean(), 2 * np.abs(ba - bb)[lit].mean())

    def test_the_render_uses_the_true_pose(self):
        cams = dc.load_cameras(os.path.join(self.src, "input.xml"))
        plan, _ = dc.make_plan(cams, opts(pose_deg=2.0, pose_dist=0.05, seed=3))
        true = [c.moved(v["true_to_world"]) for c, v in zip(cams, plan)]
        r = dc.Renderer(os.path.join(self.src, "truth.xml"), true)
        mi = mitsuba()
        with mi.variant_context(r.variant):
            for c, nominal in zip(true, cams):
                sensor = r.scene.sensors()[r.index[c.id]]
                m = np.array(mi.traverse(sensor)["to_world"].matrix, np.float64).reshape(4, 4)
                np.testing.assert_allclose(m, c.to_world, atol=2e-6)
                self.assertGreater(np.abs(m - nominal.to_world).max(), 1e-3)

    def test_pixel_shift_of_a_roll_about_the_optical_axis(self):
        cams = dc.load_cameras(os.path.join(self.src, "input.xml"))
        r = dc.Renderer(os.path.join(self.src, "truth.xml"), cams)
        c = cams[1]
        theta = math.radians(0.5)
        m = c.to_world.copy()
        m[:3, :3] = dc.axis_angle(c.to_world[:3, 2], theta) @ c.to_world[:3, :3]
        s = dc.pixel_shift(r, c, c.moved(m), c.intrinsics(), None)
        ys, xs = np.mgrid[0:32, 0:32] + 0.5
        radius = np.hypot(xs - 16, ys - 16)
        self.assertAlmostEqual(s["mean"], float((2 * radius * math.sin(theta / 2)).mean()), places=4)
        self.assertAlmostEqual(dc.pixel_shift(r, c, c, c.intrinsics(), None)["max"], 0.0, places=6)

    def test_preset_all_end_to_end(self):
        out = os.path.join(self.tmp, "all")
        p = subprocess.run([PY, os.path.join(TOOLS, "degrade_capture.py"), self.src, "--out", out,
                            "--preset", "all", "--spp", "8", "--nice", "0"], capture_output=True, text=True)
        self.assertEqual(p.returncode, 0, p.stderr[-2000:])
        rec = json.loads(read_text(os.path.join(out, "capture.json")))
        self.assertEqual(rec["preset"], "all")
        self.assertEqual(rec["colmap"]["model"], "OPENCV")
        self.assertEqual(rec["options"]["distortion"], [-0.05, 0.01])
        self.assertFalse(os.path.exists(os.path.join(out, "albedo")))
        for f in ("input.xml", "truth.xml", "relit.xml", "truth/cam_test_0.exr"):
            self.assertTrue(filecmp.cmp(os.path.join(self.src, f), os.path.join(out, f), shallow=False), f)
        cams = read_cameras_txt(os.path.join(out, "sparse", "cameras.txt"))
        imgs = read_images_txt(os.path.join(out, "sparse", "images.txt"))
        self.assertEqual(len(cams), 3)
        for iid, img in imgs.items():
            vid = img["name"][:-4]
            v = rec["views"][vid]
            self.assertEqual(dc.read_ldr(os.path.join(out, "images", img["name"])).shape, (32, 32, 3))
            self.assertEqual(v["pose_offset"]["rotation_deg"], 0.3)
            # the true pose is the nominal one turned by 0.3 degrees and moved by 0.5%
            nom, tru = np.array(v["nominal_to_world"]), np.array(v["true_to_world"])
            ang = math.degrees(math.acos(np.clip((np.trace(tru[:3, :3] @ nom[:3, :3].T) - 1) / 2, -1, 1)))
            self.assertAlmostEqual(ang, 0.3, places=6)
            np.testing.assert_allclose(tru[:3, :3] @ nom[:3, :3].T,  # turned about the recorded world axis
                                       dc.axis_angle(v["pose_offset"]["rotation_axis"], math.radians(0.3)), atol=1e-12)
            np.testing.assert_allclose(tru[:3, 3] - nom[:3, 3], v["pose_offset"]["translation"], atol=1e-15)
            self.assertAlmostEqual(np.linalg.norm(tru[:3, 3] - nom[:3, 3]) / v["pose_offset"]["target_distance"],
                                   0.005, places=9)
            self.assertGreater(v["pixel_shift"]["mean"], 0.01)
            # COLMAP holds the nominal pose (what SfM would give), images.txt = capture.json
            np.testing.assert_allclose(img["q"], v["colmap"]["qvec"], rtol=1e-15)
            r_cw, t_cw = dc.colmap_pose(nom, (rec["colmap"]["scale"], np.array(rec["colmap"]["rotation"]),
                                              np.array(rec["colmap"]["translation"])))
            np.testing.assert_allclose(qvec2rotmat(img["q"]), r_cw, atol=1e-12)
            np.testing.assert_allclose(img["t"], t_cw, atol=1e-12)


class Determinism(TmpDir):
    def test_same_seed_same_bytes_other_seed_other_draws(self):
        src = os.path.join(FIX, "cbox")
        kw = dict(exposure="0.5,1.9", white_balance=0.06, ldr="jpg", colmap=True)
        r1 = run_degrade(src, os.path.join(self.tmp, "a"), seed=4, **kw)
        r2 = run_degrade(src, os.path.join(self.tmp, "b"), seed=4, **kw)
        r3 = run_degrade(src, os.path.join(self.tmp, "c"), seed=5, **kw)
        strip = lambda r: {k: v for k, v in r.items() if k not in ("timings", "date")}  # noqa: E731
        self.assertEqual(strip(r1), strip(r2))
        for rel in ["sparse/cameras.txt", "sparse/images.txt", "sparse/to_world.txt"] + \
                [v["image"] for v in r1["views"].values()]:
            self.assertTrue(filecmp.cmp(os.path.join(self.tmp, "a", rel), os.path.join(self.tmp, "b", rel),
                                        shallow=False), rel)
        self.assertNotEqual([v["gain"] for v in r1["views"].values()], [v["gain"] for v in r3["views"].values()])
        self.assertNotEqual(r1["colmap"]["to_world"], r3["colmap"]["to_world"])

    def test_options_draw_from_their_own_streams(self):
        cams = dc.load_cameras(os.path.join(FIX, "cbox-tex", "input.xml"))
        exp, _ = dc.make_plan(cams, opts(exposure="0.5,1.9", white_balance=0.06, seed=1))
        every, _ = dc.make_plan(cams, opts(exposure="0.5,1.9", white_balance=0.06, pose_deg=0.3, pose_dist=0.005,
                                           colmap=True, seed=1))
        pose, _ = dc.make_plan(cams, opts(pose_deg=0.3, pose_dist=0.005, seed=1))
        for e, a, p in zip(exp, every, pose):
            self.assertEqual((e["gain"], e["white_balance"]), (a["gain"], a["white_balance"]))
            np.testing.assert_array_equal(a["true_to_world"], p["true_to_world"])


if __name__ == "__main__":
    unittest.main()
