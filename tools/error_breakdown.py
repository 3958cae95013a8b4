#!/usr/bin/env python3
"""Why: a held-out albedo error says how far a run is off, not where; before fixing an interior
one needs to know whether the error sits in filled texels, thin edges and seams, a colour
bias, known materials and the light that passes them, or texture detail. This tool splits the
held-out albedo judge's error (tools/heldout.py, the nightly's figure) along those lines for any
kdmap run whose scene has a truth.

    .venv/bin/python tools/error_breakdown.py <out dir> <scene dir> [--spp 64] [--json out.json]
        [--save DIR] [--floor] [--cache FILE] [--edge-px 1] [--border-texels 2] [--sigma 2]
        [--shapes 15] [--scalar]

`<out dir>` is a finished kdmap run (scene.xml, textures/, maps/<id>_coverage.exr, meshes/,
report.json); `<scene dir>` holds truth.xml with `cam_train_*` and `cam_test_*` sensors (no
held-out renders are needed: the judge renders the albedo AOV of truth.xml itself).

The pixels and the error are exactly the judge's (`heldout.albedo_score`): the albedo AOV of the
recovered and of the true scene from every `cam_test_*` view, the pixels whose pixel-centre ray
first hits a non-emitter shape that a training camera sees, with true albedo sum > 1e-6; per
pixel the relative error e = sum_c |a_c - t_c| / sum_c t_c. Squared error E = sum e^2 over those
pixels, pooled over the views. A class of pixels is reported by its share of the pixels, its
share of the summed e (of the judge's mean), its share of E, its rms and mean of e. Classes,
per pixel (pixel centre):

- `observed` / `partly observed` / `filled`: the share of the bilinear footprint of the hit's
  texel (the recovered texture's lookup, on the atlas mesh `meshes/<id>.obj`) that is observed,
  `maps/<id>_coverage.exr` > 0: 1, between, 0; filled ones also by the hit texel's distance to
  the nearest observed texel inside the charts (chessboard, in texels: <= 2, 3-8, > 8);
- `shape boundary`: within `--edge-px` pixels of a pixel whose first hit is another shape (or
  nothing, or an emitter); `crease/step`: within `--edge-px` of a depth step (the neighbour's
  hit off this pixel's tangent plane by more than 2% of the distance) or of a normal turning by
  more than 30 degrees; `chart border`: the hit's texel within `--border-texels` texels of a
  texel outside the charts (the atlas rasterised at texel centres); `edge/seam`: any of the three;
- `known material`: the first hit's shape in truth.xml has a glossy or specular BSDF (conductor,
  dielectric, plastic, ...; the judge keeps such a pixel only when its albedo AOV is not black,
  in practice its rim, where the box filter mixes in the surface behind); `no recovered
  texture`: the hit shape has no coverage map (known or emitter shapes);
- `lit through known`: a diffuse pixel from whose point one of 8 rays to random points of an
  area emitter (8 per emitter shape) first meets a known-material shape (its direct light passes
  glass or a mirror's shadow); `sees known >= 10%`: one from which at least 10% of 32
  cosine-weighted hemisphere rays first meet one (its indirect light comes much through them).
  Only when truth.xml has a known material; point, spot and environment emitters are covered by
  the hemisphere rays only;
- `exclusive`: every pixel in the first of known material, light via known (either of the two
  above), filled (observed share < 0.5), edge/seam, observed interior: the shares add up to
  100%.

Besides e, the judge's rel. L1 (sum |a - t| / sum t) weighs pixels by their true albedo, not
their inverse: where dark truths dominate the mean (a black brick filled grey is off by 50x), the
share of the summed |a - t| (`L1%`) and each class's own rel. L1 say where the L1 error sits.

And two decompositions of the error:
- colour bias: the error left after one global per-channel scale of the recovered albedo, and
  after one per shape and channel, each the scale that minimises the judge's mean error on the
  judged pixels themselves (a weighted median of t/a: the most a colour correction of that kind
  could remove); as the mean and as E; the global scale is printed (0.9 = the recovered albedo
  is ~11% high in that channel) beside mean(recovered) / mean(true) per channel; the same for
  the rel. L1 (its own best scales, a median of t/a weighted by a);
- texture detail: e of the two albedo images low-passed by a Gaussian of `--sigma` pixels
  (normalised within each shape's judged pixels, so shapes do not bleed into each other);
  `high-frequency share` = 1 - e_lowpass / e (and of E), the part of the error finer than the
  filter; the rel. L1 after the low-pass.

Shapes grouped by their judged pixels (1-99, 100-999, 1000-9999, >= 10000): how much of the
error sits on small shapes. Per shape: its pixels, share of e and E, mean, the share of its
covered texels observed (coverage > 0 among the texels inside its charts), the share of its e on
filled and on edge/seam pixels, its mean after its own colour scale, its BSDF kind.

Prints a table; `--json` writes everything (also per view); `--save DIR` per view the error
image and the exclusive class of every judged pixel; `--floor` the AOV's own Monte Carlo noise
per class (the true scene rendered again with seed 1), the part of the error no reconstruction
can remove. Its pooled mean and rel. L1 are the judge's (same renders, same pixels).
"""

import argparse
import json
import math
import os
import pickle
import sys
import time
import xml.etree.ElementTree as ET

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import heldout  # noqa: E402
from exrio import mitsuba, read_exr_rgb  # noqa: E402

BLACK = heldout.BLACK
STEP_REL = 0.02  # a neighbour's hit off the tangent plane by > 2% of the distance: a depth step
CREASE_DEG = 30.0
HEMI_RAYS = 32
EMITTER_RAYS = 8
VIA_KNOWN_SHARE = 0.10
SIZE_BINS = [(1, 100), (100, 1000), (1000, 10000), (10000, 1 << 62)]  # judged pixels per shape
FILL_NEAR = 2  # a filled texel within 2 texels of an observed one
FILL_FAR = 8  # ... more than 8 texels from any


# ---------------------------------------------------------------------------------------------
# Pure numpy parts (unit-tested in tools/test_error_breakdown.py).


def rel_error(a, t):
    """Per pixel e = sum_c |a_c - t_c| / sum_c t_c (h, w), and where it is defined
    (sum_c t_c > BLACK)."""
    st = t.sum(axis=-1)
    ok = st > BLACK
    e = np.where(ok, np.abs(a - t).sum(axis=-1) / np.where(ok, st, 1.0), 0.0)
    return e, ok


def class_stats(e, m, total_e2, total_e, l1=None, ts=None):
    """Figures of the pixels `m` (bool, same shape as e) of errors `e`; with l1 (sum_c |a - t|
    per pixel) and ts (sum_c t), also the class's share of the summed l1 and its own rel. L1."""
    n = int(m.sum())
    s2 = float((e[m] ** 2).sum()) if n else 0.0
    s1 = float(e[m].sum()) if n else 0.0
    return {
        "pixels": n,
        "share_of_pixels": None,  # filled by the caller
        "share_of_e": s1 / total_e if total_e > 0 else float("nan"),
        "share_of_e2": s2 / total_e2 if total_e2 > 0 else float("nan"),
        "rms": math.sqrt(s2 / n) if n else float("nan"),
        "mean": float(e[m].mean()) if n else float("nan"),
    } | ({} if l1 is None else {
        "share_of_l1": float(l1[m].sum() / l1.sum()) if l1.sum() > 0 else float("nan"),
        "rel_l1": float(l1[m].sum() / ts[m].sum()) if n else float("nan"),
    })


def breakdown(e, classes, l1=None, ts=None):
    """{name: class_stats} of the error e (1-D, the judged pixels) over `classes` {name: bool
    array like e}; shares are of all the pixels, of sum e and of sum e^2 (and with l1, ts: of
    the summed l1, and the class's rel. L1)."""
    tot = float((e ** 2).sum())
    tot1 = float(e.sum())
    out = {}
    for name, m in classes.items():
        s = class_stats(e, m, tot, tot1, l1, ts)
        s["share_of_pixels"] = s["pixels"] / e.size if e.size else float("nan")
        out[name] = s
    return out


def exclusive(order, classes, n):
    """Label array (n,) assigning each pixel to the first class of `order` it belongs to
    (len(order) - 1 = the last, the rest)."""
    lab = np.full(n, len(order) - 1, dtype=np.int64)
    for i in range(len(order) - 2, -1, -1):
        lab[classes[order[i]]] = i
    return lab


def bilinear_observed(observed, uv):
    """Share of the bilinear footprint of Mitsuba's bitmap lookup at `uv` (n, 2; u right, v
    down: row = v * H) on texels where `observed` (H, W) is true; wraps like the bitmap's
    default `repeat`."""
    h, w = observed.shape
    x = uv[:, 0] * w - 0.5
    y = uv[:, 1] * h - 0.5
    x0, y0 = np.floor(x), np.floor(y)
    fx, fy = x - x0, y - y0
    x0 = x0.astype(np.int64)
    y0 = y0.astype(np.int64)
    o = observed.astype(np.float64)
    out = np.zeros(len(uv))
    for dx, dy, wgt in ((0, 0, (1 - fx) * (1 - fy)), (1, 0, fx * (1 - fy)),
                        (0, 1, (1 - fx) * fy), (1, 1, fx * fy)):
        out += wgt * o[(y0 + dy) % h, (x0 + dx) % w]
    return out


def texel_at(mask, uv):
    """`mask` (H, W) at the texel containing uv (n, 2) (u right, v down), wrapping."""
    h, w = mask.shape
    x = np.floor(uv[:, 0] * w).astype(np.int64) % w
    y = np.floor(uv[:, 1] * h).astype(np.int64) % h
    return mask[y, x]


def dilate(m, r):
    """Binary dilation of the 2-D bool `m` by a (2r+1) square (no wrap)."""
    out = m.copy()
    h, w = m.shape
    for dy in range(-r, r + 1):
        for dx in range(-r, r + 1):
            if dx == 0 and dy == 0:
                continue
            src = m[max(0, -dy): h - max(0, dy), max(0, -dx): w - max(0, dx)]
            out[max(0, dy): h - max(0, -dy), max(0, dx): w - max(0, -dx)] |= src
    return out


def fill_distance(observed, cap=FILL_FAR):
    """Per texel the chessboard distance in texels to the nearest observed texel, up to `cap`
    (cap + 1 beyond; 0 on observed texels)."""
    d = np.full(observed.shape, cap + 1, dtype=np.int32)
    d[observed] = 0
    cur = observed.copy()
    for k in range(1, cap + 1):
        nxt = dilate(cur, 1)
        d[nxt & ~cur] = k
        cur = nxt
    return d


def border_texels(covered, r):
    """Covered texels within r texels (square) of a texel outside the charts or of the
    texture's edge."""
    pad = np.pad(~covered, 1, constant_values=True)
    return covered & dilate(pad, r)[1:-1, 1:-1]


def boundary_pixels(shape, r):
    """Pixels within r pixels of a pixel whose first-hit shape index differs (h, w)."""
    h, w = shape.shape
    diff = np.zeros((h, w), bool)
    diff[:, 1:] |= shape[:, 1:] != shape[:, :-1]
    diff[:, :-1] |= shape[:, 1:] != shape[:, :-1]
    diff[1:, :] |= shape[1:, :] != shape[:-1, :]
    diff[:-1, :] |= shape[1:, :] != shape[:-1, :]
    return dilate(diff, r - 1) if r > 1 else diff


def crease_pixels(p, n, t, valid, r, step_rel=STEP_REL, crease_deg=CREASE_DEG):
    """Pixels within r of a depth step or a crease between 4-neighbours that both hit something:
    the neighbour's point off this pixel's tangent plane by > step_rel * distance, or the
    normals (n, unit, (h, w, 3)) more than crease_deg apart. p: hit points (h, w, 3), t: hit
    distances (h, w)."""
    h, w = t.shape
    out = np.zeros((h, w), bool)
    cosmax = math.cos(math.radians(crease_deg))
    for ax in (0, 1):
        sl_a = (slice(None), slice(None, -1)) if ax == 1 else (slice(None, -1), slice(None))
        sl_b = (slice(None), slice(1, None)) if ax == 1 else (slice(1, None), slice(None))
        both = valid[sl_a] & valid[sl_b]
        d = p[sl_b] - p[sl_a]
        off_a = np.abs((d * n[sl_a]).sum(-1)) > step_rel * t[sl_a]
        off_b = np.abs((d * n[sl_b]).sum(-1)) > step_rel * t[sl_b]
        turn = np.abs((n[sl_a] * n[sl_b]).sum(-1)) < cosmax
        hit = both & (off_a | off_b | turn)
        out[sl_a] |= hit
        out[sl_b] |= hit
    return dilate(out, r - 1) if r > 1 else out


def weighted_median(x, w):
    """The weighted median of x (n,) with weights w >= 0: a minimiser of sum w |s - x|."""
    if len(x) == 0 or w.sum() <= 0:
        return 1.0
    o = np.argsort(x)
    c = np.cumsum(w[o])
    return float(x[o][np.searchsorted(c, 0.5 * c[-1])])


def channel_scale(a, t, figure="mean"):
    """Per-channel scale s (3,) of the recovered albedo a (n, 3) that minimises the judge's mean
    relative error against t (n, 3), sum_p sum_c |s_c a_pc - t_pc| / sum_c t_pc: the error is
    separable in the channels, and per channel sum_p (a_pc / T_p) |s_c - t_pc / a_pc| is least
    at the median of t/a weighted by a/T. figure="l1": the judge's rel. L1 instead (weights a)."""
    st = np.maximum(t.sum(-1), BLACK) if figure == "mean" else np.ones(len(t))
    s = np.ones(3)
    for c in range(3):
        ok = a[:, c] > 0
        if ok.any():
            s[c] = weighted_median(t[ok, c] / a[ok, c], a[ok, c] / st[ok])
    return s


def scaled_error(a, t, groups=None, figure="mean"):
    """Per pixel e after the best per-channel scale (channel_scale(figure)) of a, one for all
    rows or one per value of `groups` (n,); returns (e, {group: scale}, the scaled a)."""
    a2 = a.copy()
    scales = {}
    if groups is None:
        s = channel_scale(a, t, figure)
        a2 = a * s
        scales[None] = s
    else:
        for g in np.unique(groups):
            m = groups == g
            s = channel_scale(a[m], t[m], figure)
            a2[m] = a[m] * s
            scales[int(g)] = s
    return np.abs(a2 - t).sum(-1) / np.maximum(t.sum(-1), BLACK), scales, a2


def gaussian_kernel(sigma):
    r = max(1, int(math.ceil(3 * sigma)))
    x = np.arange(-r, r + 1, dtype=np.float64)
    k = np.exp(-0.5 * (x / sigma) ** 2)
    return k / k.sum()


def blur(img, k):
    """Separable convolution of (h, w[, c]) with kernel k, zero outside."""
    r = len(k) // 2

    def along(x, axis):
        pad = [(0, 0)] * x.ndim
        pad[axis] = (r, r)
        xp = np.pad(x, pad)
        out = np.zeros_like(x)
        n = x.shape[axis]
        for i, kv in enumerate(k):
            sl = [slice(None)] * x.ndim
            sl[axis] = slice(i, i + n)
            out += kv * xp[tuple(sl)]
        return out

    return along(along(img, 0), 1)


def lowpass_within(img, labels, mask, sigma):
    """Gaussian low-pass (sigma pixels) of img (h, w, 3) normalised within each label's pixels
    of `mask`: a pixel's value mixes only pixels of its own label. Pixels outside the mask keep
    img."""
    k = gaussian_kernel(sigma)
    out = img.astype(np.float64).copy()
    for lab in np.unique(labels[mask]):
        m = mask & (labels == lab)
        ys, xs = np.nonzero(m)
        r = len(k) // 2
        y0, y1 = max(0, ys.min() - r), min(m.shape[0], ys.max() + r + 1)
        x0, x1 = max(0, xs.min() - r), min(m.shape[1], xs.max() + r + 1)
        mw = m[y0:y1, x0:x1].astype(np.float64)
        num = blur(img[y0:y1, x0:x1] * mw[..., None], k)
        den = blur(mw, k)
        sub = out[y0:y1, x0:x1]
        sub[m[y0:y1, x0:x1]] = (num / np.maximum(den, 1e-12)[..., None])[m[y0:y1, x0:x1]]
    return out


# ---------------------------------------------------------------------------------------------
# Mitsuba parts: renders (heldout's), ray casts with normals and UVs, the atlas.


class _Caster(heldout._RayCaster):
    """heldout's ray caster with the scene's BSDF kinds and emitter points as well."""

    def bsdf_kinds(self):
        """Per shape: 'emitter', 'diffuse', or the BSDF's class name when it has a glossy or
        specular lobe (a known material for kdmap)."""
        mi = mitsuba()
        kinds = []
        with mi.variant_context(self.variant):
            glossy = int(mi.BSDFFlags.Glossy) | int(mi.BSDFFlags.Delta)
            for s in self.shapes:
                if s.is_emitter():
                    kinds.append("emitter")
                    continue
                b = s.bsdf()
                fl = int(np.array(b.flags()).reshape(-1)[0]) if b is not None else 0
                kinds.append(str(b).split("[")[0].strip() if fl & glossy else "diffuse")
        return kinds

    def emitter_points(self, per_shape, rng):
        """Up to `per_shape` uniform random points on each area-emitter shape (m, 3)."""
        mi = mitsuba()
        pts = []
        with mi.variant_context(self.variant):
            for s in self.shapes:
                if not s.is_emitter():
                    continue
                try:
                    prm = mi.traverse(s)
                    v = np.array(prm["vertex_positions"], dtype=np.float64).reshape(-1, 3)
                    f = np.array(prm["faces"], dtype=np.int64).reshape(-1, 3)
                except Exception:
                    continue
                a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
                area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
                if area.sum() <= 0:
                    continue
                k = rng.choice(len(f), size=per_shape, p=area / area.sum())
                r1, r2 = rng.random(per_shape), rng.random(per_shape)
                s1 = np.sqrt(r1)
                pts.append((1 - s1)[:, None] * a[k] + (s1 * (1 - r2))[:, None] * b[k]
                           + (s1 * r2)[:, None] * c[k])
        return np.concatenate(pts) if pts else np.zeros((0, 3))


def _obj_uv_triangles(path):
    """Per triangle corner UVs (m, 3, 2) of an OBJ's faces (fan-triangulated), v as in the file
    (up)."""
    vts, tris = [], []
    with open(path) as f:
        for line in f:
            if line.startswith("vt "):
                parts = line.split()
                vts.append((float(parts[1]), float(parts[2])))
            elif line.startswith("f "):
                idx = []
                for tok in line.split()[1:]:
                    s = tok.split("/")
                    if len(s) < 2 or not s[1]:
                        return None
                    k = int(s[1])
                    idx.append(k - 1 if k > 0 else len(vts) + k)
                for j in range(1, len(idx) - 1):
                    tris.append((idx[0], idx[j], idx[j + 1]))
    if not tris:
        return None
    vt = np.array(vts, dtype=np.float64)
    return vt[np.array(tris)]


def covered_masks(atlases, vectorized):
    """{shape id: covered (H, W) bool}: texels whose centre lies in one of the mesh's UV
    triangles, for atlases {id: (obj path, W, H)}. One Mitsuba scene holds every shape's UV
    layout (in texels, row down) at its own depth z = k; a ray from z = k + 0.5 down meets it
    first."""
    mi = mitsuba()
    import drjit as dr

    variant = heldout.LLVM_VARIANT if vectorized else mi.variant()
    out = {}
    verts, faces, nv = [], [], 0
    order = []
    for k, (sid, (path, w, h)) in enumerate(atlases.items()):
        tri = _obj_uv_triangles(path)
        if tri is None:
            continue
        p = np.empty((len(tri), 3, 3))
        p[..., 0] = tri[..., 0] * w
        p[..., 1] = (1.0 - tri[..., 1]) * h
        p[..., 2] = float(len(order))
        verts.append(p.reshape(-1, 3))
        faces.append(np.arange(nv, nv + 3 * len(tri)).reshape(-1, 3))
        nv += 3 * len(tri)
        order.append((sid, w, h))
    if not order:
        return out
    v = np.concatenate(verts).astype(np.float32)
    f = np.concatenate(faces).astype(np.uint32)
    with mi.variant_context(variant):
        mesh = mi.Mesh("uv_layout", len(v), len(f))
        prm = mi.traverse(mesh)
        prm["vertex_positions"] = dr.ravel(mi.Point3f(v[:, 0], v[:, 1], v[:, 2])) \
            if vectorized else v.reshape(-1).tolist()
        prm["faces"] = dr.ravel(mi.Vector3u(f[:, 0], f[:, 1], f[:, 2])) \
            if vectorized else f.reshape(-1).tolist()
        prm.update()
        scene = mi.load_dict({"type": "scene", "m": mesh})
        for k, (sid, w, h) in enumerate(order):
            y, x = np.mgrid[0:h, 0:w]
            ox = (x.reshape(-1) + 0.5).astype(np.float32)
            oy = (y.reshape(-1) + 0.5).astype(np.float32)
            z = np.float32(k + 0.5)
            if vectorized:
                n = len(ox)
                ray = mi.Ray3f(mi.Point3f(mi.Float(ox), mi.Float(oy), mi.Float(np.full(n, z))),
                               mi.Vector3f(0, 0, -1))
                t = np.array(scene.ray_intersect(ray).t, dtype=np.float64)
            else:
                t = np.array([scene.ray_intersect(mi.Ray3f(mi.Point3f(a, b, z),
                                                           mi.Vector3f(0, 0, -1))).t
                              for a, b in zip(ox, oy)], dtype=np.float64)
            out[sid] = (t < 1.0).reshape(h, w)
    return out


def _atlas_scene(orig_xml, out):
    """The recovered scene (held-out sensors) with every folded shape's mesh swapped back to
    its atlas mesh meshes/<id>.obj, so a hit's UV is its atlas texel."""
    root = ET.fromstring(orig_xml)
    for sh in root.findall("shape"):
        sid = sh.get("id", "")
        for s in sh.findall("string"):
            v = s.get("value", "")
            if s.get("name") == "filename" and v.endswith(f"meshes/{sid}_uv.obj"):
                if os.path.exists(os.path.join(out, "meshes", f"{sid}.obj")):
                    s.set("value", v[: -len("_uv.obj")] + ".obj")
    return ET.tostring(root, encoding="unicode")


def _hemisphere(n, k, rng):
    """k cosine-weighted unit directions around each unit normal of n (m, 3): (m, k, 3)."""
    m = len(n)
    r1, r2 = rng.random((m, k)), rng.random((m, k))
    phi = 2 * np.pi * r1
    sr = np.sqrt(r2)
    local = np.stack([sr * np.cos(phi), sr * np.sin(phi), np.sqrt(np.maximum(0, 1 - r2))], -1)
    a = np.where(np.abs(n[:, :1]) > 0.9, np.array([[0.0, 1.0, 0.0]]), np.array([[1.0, 0, 0]]))
    tx = np.cross(n, a)
    tx /= np.linalg.norm(tx, axis=1, keepdims=True)
    ty = np.cross(n, tx)
    return (local[..., :1] * tx[:, None] + local[..., 1:2] * ty[:, None]
            + local[..., 2:] * n[:, None])


def via_known(caster, p, n, known, emitter_pts, rng):
    """Per point (m, 3) with unit normal n facing the viewer: share of HEMI_RAYS cosine-weighted
    rays, and of rays to `emitter_pts`, whose first hit is a shape with known[idx]."""
    m = len(p)
    eps = 1e-4 * np.maximum(1.0, np.abs(p).max(axis=1, keepdims=True))
    o = p + eps * n
    hemi = np.zeros(m)
    emit = np.zeros(m)
    kn = np.append(known, False)  # index -1: a miss
    chunk = max(1, 200000 // HEMI_RAYS)
    for s in range(0, m, chunk):
        e = slice(s, s + chunk)
        d = _hemisphere(n[e], HEMI_RAYS, rng)
        oo = np.repeat(o[e], HEMI_RAYS, axis=0)
        _, sh, _ = caster.cast(oo, d.reshape(-1, 3))
        hemi[e] = kn[sh].reshape(-1, HEMI_RAYS).mean(axis=1)
        if len(emitter_pts):
            q = len(emitter_pts)
            v = emitter_pts[None, :, :] - o[e][:, None, :]
            dist = np.linalg.norm(v, axis=-1)
            dd = (v / np.maximum(dist, 1e-12)[..., None]).reshape(-1, 3)
            facing = ((v * n[e][:, None, :]).sum(-1) > 0).reshape(-1)
            t, sh, _ = caster.cast(np.repeat(o[e], q, axis=0), dd)
            blocked = kn[sh] & (t < dist.reshape(-1)) & facing
            emit[e] = blocked.reshape(-1, q).mean(axis=1)
    return hemi, emit


def _render_albedo_seed(xml_text, base_dir, spp, seed):
    """heldout._render_albedo with another seed (the AOV's Monte Carlo noise)."""
    mi = mitsuba()
    scene = heldout._load(xml_text, base_dir)
    return {s.id(): np.array(mi.render(scene, sensor=i, spp=spp, seed=seed),
                             dtype=np.float64)[..., -3:]
            for i, s in enumerate(scene.sensors())}


def collect(out, scene_dir, spp=64, vectorized=None, log=print, floor=False):
    """Per held-out view the judge's arrays and the per-pixel facts the breakdown needs;
    returns (views, meta)."""
    mi = mitsuba()
    truth_xml = os.path.join(scene_dir, "truth.xml")
    t0 = time.perf_counter()
    orig_xml = heldout.build_scene(out, truth_xml, None, spp)
    rec_text = heldout._albedo_scene(ET.fromstring(orig_xml), spp)
    troot = ET.parse(truth_xml).getroot()
    train_ids = [s.get("id") for s in troot.findall("sensor")
                 if s.get("id", "").startswith("cam_train_")]
    caster = _Caster(ET.tostring(troot, encoding="unicode"), scene_dir, vectorized=vectorized)
    atlas_caster = _Caster(_atlas_scene(orig_xml, out), out, vectorized=caster.vectorized)
    for s in troot.findall("sensor"):
        if not s.get("id", "").startswith("cam_test_"):
            troot.remove(s)
    true_text = heldout._albedo_scene(troot, spp)
    rec = heldout._render_albedo(rec_text, out, spp)
    true = heldout._render_albedo(true_text, scene_dir, spp)
    true1 = _render_albedo_seed(true_text, scene_dir, spp, 1) if floor else None
    log(f"albedo AOVs rendered ({time.perf_counter() - t0:.1f} s, {caster.variant} ray casts)")
    kinds = caster.bsdf_kinds()
    known = np.array([k not in ("diffuse", "emitter") for k in kinds])
    rng = np.random.default_rng(0)
    emitter_pts = caster.emitter_points(EMITTER_RAYS, rng) if known.any() else np.zeros((0, 3))

    # The recovered textures' observed and covered texels.
    report = {}
    rp = os.path.join(out, "report.json")
    if os.path.exists(rp):
        with open(rp) as f:
            report = json.load(f)
    observed, atlases = {}, {}
    for sid in atlas_caster.shape_ids:
        cov = os.path.join(out, "maps", f"{sid}_coverage.exr")
        obj = os.path.join(out, "meshes", f"{sid}.obj")
        if os.path.exists(cov):
            observed[sid] = read_exr_rgb(cov)[..., 0] > 0
            if os.path.exists(obj):
                h, w = observed[sid].shape
                atlases[sid] = (obj, w, h)
    t1 = time.perf_counter()
    covered = covered_masks(atlases, caster.vectorized)
    log(f"atlas rasterised: {len(covered)} shapes ({time.perf_counter() - t1:.1f} s)")
    borders = {sid: border_texels(c, BORDER_TEXELS) for sid, c in covered.items()}
    # distances from observed texels inside the charts (the EXR's gutter holds dilated copies)
    fill_dist = {sid: fill_distance(o & covered[sid] if sid in covered else o)
                 for sid, o in observed.items()}
    cov_texels = {a["shape"]: a.get("covered_texels") for a in report.get("atlas", [])}

    views = {}
    for vid, t in true.items():
        t1 = time.perf_counter()
        shape, seen = heldout.seen_mask(caster, vid, train_ids)
        cam = caster.cameras[vid]
        d = cam.pixel_rays()
        tt, sh2, p, nn, _ = caster.cast_full(cam.origin, d)
        nn = nn / np.maximum(np.linalg.norm(nn, axis=1, keepdims=True), 1e-12)
        nn = np.where(((nn * d).sum(1) > 0)[:, None], -nn, nn)  # facing the camera
        _, ash, _, _, auv = atlas_caster.cast_full(cam.origin, d)
        h, w = cam.h, cam.w
        a = rec[vid]
        e, ok = rel_error(a, t)
        judged = seen & ok
        flat = judged.reshape(-1)
        # observed share and chart border at the hit's texel (the atlas scene's hit)
        obs = np.full(h * w, np.nan)
        border = np.zeros(h * w, bool)
        fdist = np.zeros(h * w, np.int32)
        for k in np.unique(ash[flat]):
            if k < 0:
                continue
            sid = atlas_caster.shape_ids[k]
            m = flat & (ash == k)
            if sid in observed:
                obs[m] = bilinear_observed(observed[sid], auv[m])
                fdist[m] = texel_at(fill_dist[sid], auv[m])
            if sid in borders:
                border[m] = texel_at(borders[sid], auv[m])
        valid = (sh2 >= 0).reshape(h, w)
        bnd = boundary_pixels(np.where(caster.is_emitter[shape], -2, shape), EDGE_PX)
        crease = crease_pixels(p.reshape(h, w, 3), nn.reshape(h, w, 3), tt.reshape(h, w),
                               valid, EDGE_PX)
        vk_h = np.zeros(h * w)
        vk_e = np.zeros(h * w)
        if known.any():
            todo = np.flatnonzero(flat & ~known[np.maximum(shape.reshape(-1), 0)])
            vk_h[todo], vk_e[todo] = via_known(caster, p[todo], nn[todo], known,
                                               emitter_pts, rng)
        if true1 is not None:
            ef, _ = rel_error(true1[vid], t)
        views[vid] = dict(a=a[judged], t=t[judged], e=e[judged], a_img=a, t_img=t,
                          judged=judged, shape_img=shape,
                          shape=shape[judged], obs=obs[flat], border=border[flat],
                          fill_dist=fdist[flat],
                          boundary=bnd[judged], crease=crease[judged],
                          via_hemi=vk_h[flat], via_emit=vk_e[flat])
        if true1 is not None:
            views[vid]["e_floor"] = ef[judged]
            views[vid]["t1_img"] = true1[vid]
        log(f"{vid}: {int(judged.sum())} judged pixels ({time.perf_counter() - t1:.1f} s)")
    meta = dict(shape_ids=caster.shape_ids, kinds=kinds, known=known, observed=observed,
                covered=covered, cov_texels=cov_texels, train_ids=train_ids,
                variant=caster.variant, seconds=time.perf_counter() - t0)
    return views, meta


EDGE_PX = 1
BORDER_TEXELS = 2
SIGMA = 2.0

CLASS_ORDER = ["known material", "light via known", "filled", "edge/seam", "observed interior"]


def classes_of(v, known):
    """The overlapping classes of one view's (or pooled) judged pixels (dict of 1-D arrays), and
    the exclusive ones (in CLASS_ORDER's order of precedence)."""
    has_tex = ~np.isnan(v["obs"])
    obs = np.nan_to_num(v["obs"], nan=0.0)
    shape_known = known[np.maximum(v["shape"], 0)]
    edge = v["boundary"] | v["crease"] | v["border"]
    through = ~shape_known & (v["via_emit"] > 0)
    near = ~shape_known & (v["via_hemi"] >= VIA_KNOWN_SHARE)
    filled = has_tex & (obs <= 1e-9)
    fd = v["fill_dist"]
    c = {
        "observed": has_tex & (obs >= 1.0 - 1e-9),
        "partly observed": has_tex & (obs > 1e-9) & (obs < 1.0 - 1e-9),
        "filled": has_tex & (obs <= 1e-9),
        f"filled, <= {FILL_NEAR} tx": filled & (fd <= FILL_NEAR),
        f"filled, {FILL_NEAR + 1}-{FILL_FAR} tx": filled & (fd > FILL_NEAR) & (fd <= FILL_FAR),
        f"filled, > {FILL_FAR} tx": filled & (fd > FILL_FAR),
        "no recovered texture": ~has_tex,
        "shape boundary": v["boundary"],
        "crease/step": v["crease"],
        "chart border": v["border"],
        "edge/seam": edge,
        "known material": shape_known,
        "lit through known": through,
        "sees known >= 10%": near,
    }
    ex = {
        "known material": shape_known,
        "light via known": through | near,
        "edge/seam": edge,
        "filled": has_tex & (obs < 0.5),
        "observed interior": np.ones_like(edge),
    }
    return c, ex


def analyse(views, meta, sigma=SIGMA):
    """The breakdown (a dict) of the views' judged pixels."""
    keys = ["a", "t", "e", "shape", "obs", "fill_dist", "border", "boundary", "crease", "via_hemi",
            "via_emit"]
    pooled = {k: np.concatenate([v[k] for v in views.values()]) for k in keys}
    known = meta["known"]
    e = pooled["e"]
    tot = float((e ** 2).sum())
    st = pooled["t"].sum(-1)
    res = {
        "judge": {
            "albedo_mean_rel_error": float(e.mean()) if e.size else float("nan"),
            "albedo_rel_l1": float(np.abs(pooled["a"] - pooled["t"]).sum() / st.sum())
            if e.size else float("nan"),
            "rms_rel_error": math.sqrt(tot / e.size) if e.size else float("nan"),
            "pixels": int(e.size),
        },
    }
    cls, ex = classes_of(pooled, known)
    l1 = np.abs(pooled["a"] - pooled["t"]).sum(-1)
    res["classes"] = breakdown(e, cls, l1, st)
    lab = exclusive(CLASS_ORDER, ex, e.size)
    res["exclusive"] = breakdown(e, {n: lab == i for i, n in enumerate(CLASS_ORDER)}, l1, st)

    # colour bias
    eg, sg, _ = scaled_error(pooled["a"], pooled["t"])
    es, ss, _ = scaled_error(pooled["a"], pooled["t"], pooled["shape"])
    _, sgl, agl = scaled_error(pooled["a"], pooled["t"], figure="l1")
    _, _, asl = scaled_error(pooled["a"], pooled["t"], pooled["shape"], figure="l1")
    tot1 = float(e.sum())
    res["colour_bias"] = {
        "global_scale": [float(x) for x in sg[None]],
        "mean_ratio_recovered_over_true": [
            float(x) for x in pooled["a"].mean(0) / np.maximum(pooled["t"].mean(0), BLACK)],
        "global_mean_after": float(eg.mean()) if e.size else float("nan"),
        "global_removes_share_of_e": 1.0 - float(eg.sum()) / tot1 if tot1 else 0.0,
        "global_removes_share_of_e2": 1.0 - float((eg ** 2).sum()) / tot if tot else 0.0,
        "per_shape_mean_after": float(es.mean()) if e.size else float("nan"),
        "per_shape_removes_share_of_e": 1.0 - float(es.sum()) / tot1 if tot1 else 0.0,
        "per_shape_removes_share_of_e2": 1.0 - float((es ** 2).sum()) / tot if tot else 0.0,
        "global_scale_l1": [float(x) for x in sgl[None]],
        "global_rel_l1_after": float(np.abs(agl - pooled["t"]).sum() / st.sum())
        if e.size else float("nan"),
        "per_shape_rel_l1_after": float(np.abs(asl - pooled["t"]).sum() / st.sum())
        if e.size else float("nan"),
    }

    # texture detail: low-pass both images within each shape's judged pixels
    elp, lp1, lpt = [], 0.0, 0.0
    for v in views.values():
        lab_img = v["shape_img"]
        al = lowpass_within(v["a_img"], lab_img, v["judged"], sigma)
        tl = lowpass_within(v["t_img"], lab_img, v["judged"], sigma)
        el, _ = rel_error(al, tl)
        elp.append(el[v["judged"]])
        lp1 += float(np.abs(al - tl)[v["judged"]].sum())
        lpt += float(tl[v["judged"]].sum())
    elp = np.concatenate(elp) if elp else np.zeros(0)
    res["texture_detail"] = {
        "sigma_px": sigma,
        "lowpass_share_of_e": float(elp.sum()) / tot1 if tot1 else float("nan"),
        "high_frequency_share_of_e": 1.0 - float(elp.sum()) / tot1 if tot1 else 0.0,
        "lowpass_share_of_e2": float((elp ** 2).sum()) / tot if tot else float("nan"),
        "high_frequency_share_of_e2": 1.0 - float((elp ** 2).sum()) / tot if tot else 0.0,
        "lowpass_mean": float(elp.mean()) if elp.size else float("nan"),
        "lowpass_rel_l1": lp1 / lpt if lpt > 0 else float("nan"),
    }

    # the AOV's own Monte Carlo noise: the true scene against itself with another seed
    if views and all("e_floor" in v for v in views.values()):
        ef = np.concatenate([v["e_floor"] for v in views.values()])
        fl = []
        for v in views.values():
            t1 = lowpass_within(v["t1_img"], v["shape_img"], v["judged"], sigma)
            tl = lowpass_within(v["t_img"], v["shape_img"], v["judged"], sigma)
            el, _ = rel_error(t1, tl)
            fl.append(el[v["judged"]])
        fl = np.concatenate(fl)
        fc = breakdown(ef, cls)
        res["floor"] = {"mean": float(ef.mean()), "rms": math.sqrt(float((ef ** 2).mean())),
                        "lowpass_mean": float(fl.mean()),
                        "class_mean": {k: c["mean"] for k, c in fc.items()}}

    # per shape
    shapes = []
    for k in np.unique(pooled["shape"]):
        m = pooled["shape"] == k
        sid = meta["shape_ids"][k]
        s2 = float((e[m] ** 2).sum())
        obs_share = None
        if sid in meta["observed"]:
            ct = meta["cov_texels"].get(sid)
            if sid in meta["covered"]:
                cv = meta["covered"][sid]
                obs_share = float((meta["observed"][sid] & cv).sum() / max(cv.sum(), 1))
            elif ct:
                obs_share = float(meta["observed"][sid].sum() / ct)
        e_after = es[m]
        shapes.append({
            "shape": sid,
            "kind": meta["kinds"][k],
            "pixels": int(m.sum()),
            "share_of_e": float(e[m].sum()) / tot1 if tot1 else float("nan"),
            "share_of_l1": float(l1[m].sum() / l1.sum()) if l1.sum() > 0 else float("nan"),
            "rel_l1": float(l1[m].sum() / st[m].sum()),
            "share_of_e2": s2 / tot if tot else float("nan"),
            "rms": math.sqrt(s2 / m.sum()),
            "mean": float(e[m].mean()),
            "observed_texel_share": obs_share,
            "filled_pixel_share": float(cls["filled"][m].mean()),
            "edge_pixel_share": float(cls["edge/seam"][m].mean()),
            "filled_share_of_its_e": float(e[m & cls["filled"]].sum() / max(e[m].sum(), 1e-300)),
            "edge_share_of_its_e": float(e[m & cls["edge/seam"]].sum()
                                         / max(e[m].sum(), 1e-300)),
            "mean_after_scale": float(e_after.mean()),
            "scale_removes_share_of_its_e2": 1.0 - float((e_after ** 2).sum()) / s2 if s2 else 0.0,
            "scale": [float(x) for x in ss[int(k)]],
        })
    shapes.sort(key=lambda s: -s["share_of_e"])
    res["shapes"] = shapes
    # shapes grouped by their judged pixels (small shapes are mostly edges)
    sizes = {}
    for lo, hi in SIZE_BINS:
        grp = [s for s in shapes if lo <= s["pixels"] < hi]
        name = f"{lo}-{hi - 1} px" if hi < 1 << 62 else f">= {lo} px"
        sizes[name] = {"shapes": len(grp), "pixels": sum(s["pixels"] for s in grp),
                       "share_of_e": sum(s["share_of_e"] for s in grp),
                       "share_of_e2": sum(s["share_of_e2"] for s in grp),
                       "mean": (sum(s["mean"] * s["pixels"] for s in grp)
                                / max(1, sum(s["pixels"] for s in grp))) if grp else None}
    res["shape_sizes"] = sizes
    res["views"] = {}
    for vid, v in views.items():
        c, _ = classes_of(v, known)
        res["views"][vid] = {"pixels": int(v["e"].size),
                             "albedo_mean_rel_error": float(v["e"].mean()) if v["e"].size
                             else float("nan"),
                             "classes": breakdown(v["e"], c)}
    return res


def _pct(x):
    return "    -" if x is None or (isinstance(x, float) and math.isnan(x)) else f"{100 * x:5.1f}"


def table(res, nshapes=15):
    """The breakdown as text. e% = share of the summed relative error (of the judge's mean),
    E% = share of the summed squared error."""
    j = res["judge"]
    fl = res.get("floor")
    head = (f"{'pix%':>6s} {'e%':>6s} {'E%':>6s} {'L1%':>6s} {'mean%':>7s} {'rms%':>7s} "
            f"{'relL1%':>7s}")
    if fl:
        head += f" {'floor%':>7s}"

    def row(name, s, floor=True):
        r = (f"{name:22s} {_pct(s['share_of_pixels']):>6s} {_pct(s['share_of_e']):>6s} "
             f"{_pct(s['share_of_e2']):>6s} {_pct(s.get('share_of_l1')):>6s} "
             f"{_pct(s['mean']):>7s} {_pct(s['rms']):>7s} {_pct(s.get('rel_l1')):>7s}")
        if fl and floor:
            r += f" {_pct(fl['class_mean'].get(name)):>7s}"
        return r

    lines = [f"held-out albedo: mean rel {100 * j['albedo_mean_rel_error']:.2f}%, rel L1 "
             f"{100 * j['albedo_rel_l1']:.2f}%, rms {100 * j['rms_rel_error']:.2f}% over "
             f"{j['pixels']} pixels", "", f"{'class (overlapping)':22s} {head}"]
    lines += [row(n, s) for n, s in res["classes"].items()]
    lines += ["", f"{'exclusive (in order)':22s} {head.split(' floor%')[0].rstrip()}"]
    lines += [row(n, s, False) for n, s in res["exclusive"].items()]
    cb = res["colour_bias"]
    g = cb["global_scale"]
    r = cb["mean_ratio_recovered_over_true"]
    lines += ["",
              f"colour bias: mean recovered/true R {r[0]:.3f} G {r[1]:.3f} B {r[2]:.3f}; best "
              f"global scale {g[0]:.3f} {g[1]:.3f} {g[2]:.3f}: mean -> "
              f"{100 * cb['global_mean_after']:.2f}% (removes "
              f"{_pct(cb['global_removes_share_of_e']).strip()}% of e, "
              f"{_pct(cb['global_removes_share_of_e2']).strip()}% of E); best scale per shape: "
              f"mean -> {100 * cb['per_shape_mean_after']:.2f}% (removes "
              f"{_pct(cb['per_shape_removes_share_of_e']).strip()}% of e, "
              f"{_pct(cb['per_shape_removes_share_of_e2']).strip()}% of E)",
              f"  for rel. L1: best global scale {cb['global_scale_l1'][0]:.3f} "
              f"{cb['global_scale_l1'][1]:.3f} {cb['global_scale_l1'][2]:.3f}: rel. L1 "
              f"{100 * j['albedo_rel_l1']:.2f}% -> {100 * cb['global_rel_l1_after']:.2f}%; per "
              f"shape -> {100 * cb['per_shape_rel_l1_after']:.2f}%"]
    td = res["texture_detail"]
    lines.append(f"texture detail: after a Gaussian {td['sigma_px']:g} px low-pass of both, mean "
                 f"{100 * td['lowpass_mean']:.2f}%: high-frequency share "
                 f"{_pct(td['high_frequency_share_of_e']).strip()}% of e, "
                 f"{_pct(td['high_frequency_share_of_e2']).strip()}% of E; rel. L1 "
                 f"{100 * j['albedo_rel_l1']:.2f}% -> {100 * td['lowpass_rel_l1']:.2f}%")
    if fl:
        lines.append(f"noise floor (the true AOV against itself, seed 1): mean "
                     f"{100 * fl['mean']:.2f}%, rms {100 * fl['rms']:.2f}%, after the low-pass "
                     f"{100 * fl['lowpass_mean']:.2f}%")
    sz = " | ".join(f"{k}: {v['shapes']} shapes, {v['pixels']} px, e "
                    f"{_pct(v['share_of_e']).strip()}% (mean {_pct(v['mean']).strip()}%)"
                    for k, v in res["shape_sizes"].items() if v["shapes"])
    lines += ["", f"shapes by judged pixels: {sz}"]
    lines += ["", f"{'shape':28s} {'kind':10s} {'pix':>6s} {'e%':>6s} {'E%':>6s} {'L1%':>6s} "
              f"{'mean%':>7s} {'relL1%':>7s} "
              f"{'obsTx%':>7s} {'fill-e%':>7s} {'edge-e%':>7s} {'scaled%':>7s}"]
    for s in res["shapes"][:nshapes]:
        lines.append(f"{s['shape'][:28]:28s} {s['kind'][:10]:10s} {s['pixels']:6d} "
                     f"{_pct(s['share_of_e']):>6s} {_pct(s['share_of_e2']):>6s} "
                     f"{_pct(s['share_of_l1']):>6s} {_pct(s['mean']):>7s} {_pct(s['rel_l1']):>7s} "
                     f"{_pct(s['observed_texel_share']):>7s} "
                     f"{_pct(s['filled_share_of_its_e']):>7s} "
                     f"{_pct(s['edge_share_of_its_e']):>7s} {_pct(s['mean_after_scale']):>7s}")
    if len(res["shapes"]) > nshapes:
        rest = res["shapes"][nshapes:]
        lines.append(f"... {len(rest)} more shapes: {sum(s['pixels'] for s in rest)} pixels, "
                     f"{_pct(sum(s['share_of_e'] for s in rest)).strip()}% of e, "
                     f"{_pct(sum(s['share_of_e2'] for s in rest)).strip()}% of E")
    lines.append("(e%: share of the summed relative error, E%: of the squared, L1%: of the "
                 "summed |a - t|; relL1%: the class's or shape's own rel. L1; obsTx%: the "
                 "shape's covered texels observed; fill-e%, edge-e%: the share of the shape's e "
                 "on its filled, edge/seam pixels; scaled%: its mean after its best colour "
                 "scale)")
    return "\n".join(lines)


def save_images(views, meta, save_dir):
    """Per view `<view>_error.exr` (e of the judged pixels, 0 elsewhere) and `<view>_class.png`
    (8-bit grey: 0 not judged, 50 * (1 + index in CLASS_ORDER) for the exclusive class)."""
    mi = mitsuba()
    os.makedirs(save_dir, exist_ok=True)
    for vid, v in views.items():
        h, w = v["judged"].shape
        err = np.zeros((h, w), np.float32)
        err[v["judged"]] = v["e"]
        _, ex = classes_of(v, meta["known"])
        lab = np.zeros((h, w), np.uint8)
        lab[v["judged"]] = 50 * (1 + exclusive(CLASS_ORDER, ex, v["e"].size))
        mi.Bitmap(np.repeat(err[..., None], 3, -1)).write(os.path.join(save_dir,
                                                                       f"{vid}_error.exr"))
        mi.Bitmap(lab).write(os.path.join(save_dir, f"{vid}_class.png"))


def _clean(x):
    if isinstance(x, dict):
        return {str(k): _clean(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_clean(v) for v in x]
    if isinstance(x, float) and math.isnan(x):
        return None
    return x


def main():
    global EDGE_PX, BORDER_TEXELS
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", help="kdmap output directory (scene.xml, maps/, meshes/)")
    ap.add_argument("scene_dir", help="scene directory (truth.xml with cam_train_*, cam_test_*)")
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--json", help="write the breakdown here")
    ap.add_argument("--edge-px", type=int, default=EDGE_PX)
    ap.add_argument("--border-texels", type=int, default=BORDER_TEXELS)
    ap.add_argument("--sigma", type=float, default=SIGMA, help="low-pass, pixels")
    ap.add_argument("--shapes", type=int, default=15, help="shapes in the printed table")
    ap.add_argument("--floor", action="store_true",
                    help="also the AOV noise floor: the true scene rendered again with seed 1, "
                    "its mean per class (column floor%%)")
    ap.add_argument("--save", metavar="DIR",
                    help="write <view>_error.exr and <view>_class.png (the exclusive class) here")
    ap.add_argument("--cache", metavar="FILE",
                    help="keep the renders and ray casts in FILE (pickle) and read them from it "
                    "when it exists: re-analyse without rendering (--spp, --floor, --edge-px and "
                    "--border-texels then come from the first run)")
    ap.add_argument("--scalar", action="store_true",
                    help="scalar_rgb ray casts (default: the LLVM variant when libLLVM is found)")
    a = ap.parse_args()
    EDGE_PX, BORDER_TEXELS = a.edge_px, a.border_texels
    heldout.ensure_libllvm()

    def log(msg):
        print(msg, file=sys.stderr, flush=True)

    if a.cache and os.path.exists(a.cache):
        with open(a.cache, "rb") as f:
            views, meta = pickle.load(f)
        log(f"renders and ray casts read from {a.cache}")
    else:
        views, meta = collect(a.out, a.scene_dir, a.spp,
                              vectorized=False if a.scalar else None, log=log, floor=a.floor)
        if a.cache:
            with open(a.cache, "wb") as f:
                pickle.dump((views, meta), f, protocol=4)
    res = analyse(views, meta, a.sigma)
    if a.save:
        save_images(views, meta, a.save)
    res["settings"] = {"spp": a.spp, "edge_px": EDGE_PX, "border_texels": BORDER_TEXELS,
                       "sigma_px": a.sigma, "floor": a.floor, "ray_casting": meta["variant"],
                       "out": os.path.abspath(a.out), "scene": os.path.abspath(a.scene_dir)}
    res["seconds"] = meta["seconds"]
    print(table(res, a.shapes))
    if a.json:
        with open(a.json, "w") as f:
            json.dump(_clean(res), f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
