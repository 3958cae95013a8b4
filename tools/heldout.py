#!/usr/bin/env python3
"""Score a kdmap reconstruction with an independent renderer (Mitsuba 3) on held-out views.

    .venv/bin/python tools/heldout.py <out dir> <scene dir> [--spp 64] [--floor] [--llvm]

Loads the recovered scene `<out>/scene.xml`, swaps its (training) sensors for the held-out
sensors `cam_test_*` of `<scene>/truth.xml` and renders them under the original lighting; then
builds the relit scene (the recovered shapes and BSDFs, minus any area-emitter shape, with the
emitters and sensors of `<scene>/relit.xml`) and renders it. Both scenes are written next to
the output (`<out>/heldout_original.xml`, `<out>/heldout_relit.xml`; render them with
`mitsuba -m scalar_rgb <file>`), the renders to `<out>/heldout/<view>[_relit].exr`.

Against `<scene>/truth/<view>.exr` and `<view>_relit.exr` (Mitsuba, 1024 spp):
- `mean_rel_lum_error`: mean over pixels whose true luminance is > 1e-6 of |Y - Y_true| / Y_true;
- `rel_l1_error`: sum |render - truth| / sum |truth| over all pixels and channels;
- `block8_rel_lum_error`: as the first, over 8x8-pixel block means (much less Monte Carlo noise).
The per-pixel figures include the render's Monte Carlo noise at `spp` (and the truth's at 1024):
`--floor` also renders the TRUE scene (truth.xml / relit.xml) at the same spp and reports the
same figures for it, the floor a perfect reconstruction would reach.

Held-out ALBEDO judge (key "albedo"; the project's "mean relative albedo error over pixels a
training camera saw"), which judges the texture itself rather than images it lights:
- renders Mitsuba's `albedo` AOV (`aov` integrator, `albedo:albedo`, box filter, `spp`, seed 0)
  of the recovered scene and of the true scene (truth.xml) from every `cam_test_*` view;
- masks the pixels whose pixel-centre ray first hits a non-emitter shape of truth.xml at a point
  that at least one training camera `cam_train_*` sees (projects inside its film, in front of
  its near plane, and the ray from that camera's position to the point hits it first, within
  1e-3 x distance + 1e-4); pixels with true albedo sum <= 1e-6 are skipped;
- `albedo_mean_rel_error`: mean over masked pixels of sum_c |a_c - t_c| / sum_c t_c;
  `albedo_rel_l1`: sum |a - t| / sum t over them; `albedo_psnr_db`: 10 log10(1 / mean of
  (a_c - t_c)^2) over them (the k_d PSNR inverse-rendering papers report); `masked_pixels`, `masked_fraction` (of all
  held-out pixels). Pooled over the views, also per view and per shape (first-hit shape).
Its floor is the AOV's Monte Carlo noise alone, and small: both scenes are rendered with the
same seed, so pixels see the same sub-pixel positions, and the AOV has no lighting noise (only
the box-filter mix of surfaces and texels inside a pixel, identical for a perfect
reconstruction up to its texture resampling). Renders use scalar_rgb, or with `--llvm`
Mitsuba's LLVM variant when libLLVM is found (large interiors: minutes instead of hours).
Writes `<out>/heldout/<view>_albedo.exr`, `<view>_albedo_true.exr` and
`<view>_albedo_mask.png`. `--albedo-only` runs just this judge.

With the albedo judge, the image figures also get `block8_rel_lum_error_seen`: the block figure
over the 8x8 blocks whose every pixel is in that mask. It leaves out what no training photo
saw (the ceiling above an area light that relit.xml removes, the far side of an object), whose
albedo a reconstruction can only guess, so it tells resolution and noise apart from that guess.
"""

import argparse
import json
import os
import sys
import time
import xml.etree.ElementTree as ET

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from exrio import mitsuba, read_exr_rgb  # noqa: E402

LUMA = np.array([0.2126, 0.7152, 0.0722])
BLACK = 1e-6


def _set_spp(sensor, spp):
    for s in sensor.iter("sampler"):
        for i in s.iter("integer"):
            if i.get("name") == "sample_count":
                i.set("value", str(spp))


def _heldout_sensors(xml_path):
    root = ET.parse(xml_path).getroot()
    return [s for s in root.findall("sensor") if s.get("id", "").startswith("cam_test_")]


def _absolute_files(elem, base):
    """`elem` with every relative `filename` (an envmap's map, an emitter shape's mesh) made
    absolute against `base`, the directory of the file it came from."""
    for f in elem.iter("string"):
        v = f.get("value")
        if f.get("name") == "filename" and v and not os.path.isabs(v):
            f.set("value", os.path.join(base, v))
    return elem


def build_scene(out, sensors_from, emitters_from=None, spp=64):
    """The recovered scene with `sensors_from`'s held-out sensors; with `emitters_from`, its
    emitters (and emitter shapes) replaced by those of that file. Returns the XML text."""
    tree = ET.parse(os.path.join(out, "scene.xml"))
    root = tree.getroot()
    for s in root.findall("sensor"):
        root.remove(s)
    if emitters_from is not None:
        for e in root.findall("emitter"):
            root.remove(e)
        for sh in root.findall("shape"):
            if sh.find("emitter") is not None:
                root.remove(sh)
        src = ET.parse(emitters_from).getroot()
        src_dir = os.path.dirname(os.path.abspath(emitters_from))
        for e in src.findall("emitter"):
            root.append(_absolute_files(e, src_dir))
        for sh in src.findall("shape"):
            if sh.find("emitter") is not None:
                root.append(_absolute_files(sh, src_dir))
    # Sensors first, as Mitsuba lists them in file order.
    at = 0
    for i, child in enumerate(list(root)):
        if child.tag == "integrator":
            at = i + 1
    for k, s in enumerate(_heldout_sensors(sensors_from)):
        _set_spp(s, spp)
        root.insert(at + k, s)
    ET.indent(tree)
    return ET.tostring(root, encoding="unicode")


def errors(render, truth):
    """The three error figures of `render` against `truth` (float arrays (h, w, 3))."""
    r = render.astype(np.float64)
    t = truth.astype(np.float64)
    yr, yt = r @ LUMA, t @ LUMA
    m = yt > BLACK
    pix = float(np.mean(np.abs(yr[m] - yt[m]) / yt[m])) if m.any() else float("nan")
    l1 = float(np.abs(r - t).sum() / max(np.abs(t).sum(), 1e-300))
    h, w = yt.shape
    b = 8
    hb, wb = h // b, w // b
    br = yr[: hb * b, : wb * b].reshape(hb, b, wb, b).mean(axis=(1, 3))
    bt = yt[: hb * b, : wb * b].reshape(hb, b, wb, b).mean(axis=(1, 3))
    mb = bt > BLACK
    blk = float(np.mean(np.abs(br[mb] - bt[mb]) / bt[mb])) if mb.any() else float("nan")
    return {"mean_rel_lum_error": pix, "rel_l1_error": l1, "block8_rel_lum_error": blk,
            "nonblack_pixels": int(m.sum())}


def _variant(llvm):
    """The renders' variant: scalar_rgb, or with `llvm` the LLVM variant when it works (many
    times faster on interiors of hundreds of thousands of pixels; its own sampler, the same
    seed in the recovered and the true scene)."""
    mi = mitsuba()
    return mi.variant_context(LLVM_VARIANT if llvm and _llvm_available() else mi.variant())


def _render_all(xml_text, base_dir, save_dir, suffix, spp, truth_dir, llvm=False):
    mi = mitsuba()
    views = {}
    with _variant(llvm):
        scene = _load(xml_text, base_dir, optimize=True)
        imgs = []
        for i, sensor in enumerate(scene.sensors()):
            t0 = time.perf_counter()
            img = np.array(mi.render(scene, sensor=i, spp=spp))[..., :3]
            imgs.append((sensor.id(), img, time.perf_counter() - t0))
    for sid, img, secs in imgs:
        if save_dir is not None:
            os.makedirs(save_dir, exist_ok=True)
            mi.Bitmap(img.astype(np.float32)).write(os.path.join(save_dir, f"{sid}{suffix}.exr"))
        truth = read_exr_rgb(os.path.join(truth_dir, f"{sid}{suffix}.exr"))
        e = errors(img, truth)
        e["seconds"] = secs
        views[sid] = e
    return views


def block_error_seen(render, truth, seen, b=8):
    """`block8_rel_lum_error` over the b x b blocks of `seen` (h, w) that are seen throughout
    (nan if none)."""
    yr, yt = render.astype(np.float64) @ LUMA, truth.astype(np.float64) @ LUMA
    h, w = yt.shape
    hb, wb = h // b, w // b

    def blocks(a):
        return a[: hb * b, : wb * b].reshape(hb, b, wb, b)

    br, bt = blocks(yr).mean(axis=(1, 3)), blocks(yt).mean(axis=(1, 3))
    full = blocks(seen.astype(np.float64)).min(axis=(1, 3)) > 0.5
    m = full & (bt > BLACK)
    return float(np.mean(np.abs(br[m] - bt[m]) / bt[m])) if m.any() else float("nan")


def add_seen_figures(res, save, truth_dir, masks):
    """`block8_rel_lum_error_seen` per view and on average into res["original"] and
    res["relit"], from the renders in `save` and the judge's masks {view: seen}."""
    for key, suffix in (("original", ""), ("relit", "_relit")):
        if key not in res:
            continue
        figs = []
        for vid, v in res[key]["views"].items():
            if vid not in masks:
                continue
            r = read_exr_rgb(os.path.join(save, f"{vid}{suffix}.exr"))
            t = read_exr_rgb(os.path.join(truth_dir, f"{vid}{suffix}.exr"))
            v["block8_rel_lum_error_seen"] = block_error_seen(r, t, masks[vid])
            figs.append(v["block8_rel_lum_error_seen"])
        if figs:
            res[key]["block8_rel_lum_error_seen"] = float(np.nanmean(figs))


def _summary(views):
    keys = ["mean_rel_lum_error", "rel_l1_error", "block8_rel_lum_error"]
    s = {k: float(np.mean([v[k] for v in views.values()])) for k in keys}
    s["views"] = views
    s["seconds"] = float(sum(v["seconds"] for v in views.values()))
    return s


# ---------------------------------------------------------------------------------------------
# Held-out albedo judge: "mean relative albedo error over pixels a training camera saw".

ALBEDO_INTEGRATOR = ('<integrator type="aov"><string name="aovs" value="albedo:albedo"/>'
                     "</integrator>")
LLVM_VARIANT = "llvm_ad_rgb"
LIBLLVM_GLOBS = ("/usr/lib/x86_64-linux-gnu/libLLVM-*.so", "/usr/lib/llvm-*/lib/libLLVM.so",
                 "/usr/lib/x86_64-linux-gnu/libLLVM.so.*", "/usr/lib64/libLLVM*.so")
VIS_RTOL = 1e-3  # a training camera sees a point when its ray hits within 1e-3 * distance ...
VIS_ATOL = 1e-4  # ... + 1e-4 scene units of it


def ensure_libllvm():
    """Point Dr.Jit's LLVM backend at an installed libLLVM (DRJIT_LIBLLVM_PATH, e.g.
    /usr/lib/x86_64-linux-gnu/libLLVM-19.so from `apt-get install libllvm19`) unless the
    variable is set; returns the path or None. Must run before the process's first LLVM-variant
    call."""
    cur = os.environ.get("DRJIT_LIBLLVM_PATH")
    if cur:
        return cur
    import glob
    import re

    found = []
    for gi, g in enumerate(LIBLLVM_GLOBS):
        for p in glob.glob(g):
            m = re.search(r"libLLVM-(\d+)|libLLVM\.so\.(\d+)|llvm-(\d+)", p)
            v = int(next(x for x in m.groups() if x)) if m else 0
            found.append((v, -gi, p))
    found = [p for _, _, p in sorted(found, reverse=True)]
    if found:
        os.environ["DRJIT_LIBLLVM_PATH"] = found[0]
        return found[0]
    return None


_LLVM_OK = None


def _llvm_available():
    """True when the LLVM variant works in this process (libLLVM found); cached."""
    global _LLVM_OK
    if _LLVM_OK is None:
        mi = mitsuba()
        ensure_libllvm()
        try:
            with mi.variant_context(LLVM_VARIANT):
                import drjit as dr

                _LLVM_OK = int(np.array(dr.arange(mi.UInt32, 4)).sum()) == 6
        except Exception:
            _LLVM_OK = False
    return _LLVM_OK


def _load(xml_text, base_dir, optimize=True):
    """mi.load_string with `base_dir` first on the file resolver (relative mesh/texture paths)."""
    mi = mitsuba()
    fr = mi.file_resolver()
    saved = [fr[i] for i in range(len(fr))]
    fr.prepend(os.path.abspath(base_dir))
    try:
        return mi.load_string(xml_text, optimize=optimize)
    finally:
        fr.clear()
        for p in saved:
            fr.append(p)


class _Camera:
    """A Mitsuba `perspective` sensor as numpy math: pixel-centre rays and the projection of
    world points onto the film, with Mitsuba's conventions (camera_to_sample =
    scale(-0.5, -0.5 aspect, 1) * translate(-1, -1/aspect, 0) * perspective(x_fov, near, far);
    the film's x runs along the camera's -x, its y along -y)."""

    def __init__(self, sensor):
        mi = mitsuba()
        p = mi.traverse(sensor)
        self.id = sensor.id()
        self.w, self.h = (int(v) for v in np.array(p["film.size"]).reshape(-1)[:2])
        crop = np.array(p["film.crop_size"]).reshape(-1)[:2]
        off = np.array(p["film.crop_offset"]).reshape(-1)[:2]
        ppx = float(np.array(p["principal_point_offset_x"]).reshape(-1)[0])
        ppy = float(np.array(p["principal_point_offset_y"]).reshape(-1)[0])
        if tuple(crop) != (self.w, self.h) or off.any() or ppx or ppy:
            raise ValueError(f"sensor {self.id}: crop windows and principal point offsets "
                             "are not supported by the albedo judge")
        self.to_world = np.array(p["to_world"].matrix, dtype=np.float64).reshape(4, 4)
        self.to_local = np.linalg.inv(self.to_world)
        self.origin = self.to_world[:3, 3].copy()
        fov = float(np.array(p["x_fov"]).reshape(-1)[0])
        self.cot = 1.0 / np.tan(np.radians(fov) / 2.0)
        self.aspect = self.w / self.h
        self.near = float(np.array(p["near_clip"]).reshape(-1)[0])

    def pixel_rays(self):
        """Unit world directions (h*w, 3) through the pixel centres, row-major."""
        y, x = np.mgrid[0: self.h, 0: self.w]
        sx = (x.reshape(-1) + 0.5) / self.w
        sy = (y.reshape(-1) + 0.5) / self.h
        d = np.stack([(1.0 - 2.0 * sx) / self.cot, (1.0 - 2.0 * sy) / (self.aspect * self.cot),
                      np.ones_like(sx)], axis=1)
        d = d @ self.to_world[:3, :3].T
        return d / np.linalg.norm(d, axis=1, keepdims=True)

    def project(self, pts):
        """Film position in pixels (n, 2) of world points (n, 3) and whether it lies on the
        film in front of the near plane."""
        q = pts @ self.to_local[:3, :3].T + self.to_local[:3, 3]
        z = q[:, 2]
        zs = np.where(z > 0, z, 1.0)
        sx = 0.5 - 0.5 * self.cot * q[:, 0] / zs
        sy = 0.5 - 0.5 * self.aspect * self.cot * q[:, 1] / zs
        inside = (z > self.near) & (sx >= 0) & (sx < 1) & (sy >= 0) & (sy < 1)
        return np.stack([sx * self.w, sy * self.h], axis=1), inside


class _RayCaster:
    """First hits of batches of rays in a scene: a scalar_rgb loop by default, or vectorised
    with the LLVM variant (`vectorized=True`, needs libLLVM; None: LLVM when available). Both
    give identical masks and take the same time here (about 1.5 s per 256x256 held-out view
    with 3 training cameras on cbox-tex: the loop is ~6 us per ray), so the default needs no
    system library."""

    def __init__(self, xml_text, base_dir, vectorized=False):
        mi = mitsuba()
        self.vectorized = _llvm_available() if vectorized is None else vectorized
        self.variant = LLVM_VARIANT if self.vectorized else mi.variant()
        with mi.variant_context(self.variant):
            self.scene = _load(xml_text, base_dir, optimize=False)
            self.shapes = list(self.scene.shapes())
            self.shape_ids = [s.id() for s in self.shapes]
            self.is_emitter = np.array([s.is_emitter() for s in self.shapes] + [True])
            self.cameras = {s.id(): _Camera(s) for s in self.scene.sensors()}
            if self.vectorized:
                import drjit as dr

                ptrs = np.array(dr.reinterpret_array(mi.UInt32, self.scene.shapes_dr()))
                self._index_of = {int(p): i for i, p in enumerate(ptrs)}
            else:
                self._index_of = {id(s): i for i, s in enumerate(self.shapes)}

    def cast(self, o, d):
        """Rays from o (n, 3) or (3,) along unit d (n, 3): hit distance (inf on a miss), the
        hit shape's index in self.shapes (-1 on a miss) and the hit point (n, 3)."""
        return self.cast_full(o, d, surface=False)

    def cast_full(self, o, d, surface=True):
        """cast()'s (t, shape index, point), and with `surface` also the hit's unit normal
        (n, 3) and UV (n, 2)."""
        mi = mitsuba()
        n = len(d)
        o = np.broadcast_to(np.asarray(o, dtype=np.float64), (n, 3))
        with mi.variant_context(self.variant):
            if self.vectorized:
                import drjit as dr

                def f(a):
                    return (mi.Float(np.ascontiguousarray(a[:, k]).astype(np.float32))
                            for k in range(3))

                ray = mi.Ray3f(mi.Point3f(*f(o)), mi.Vector3f(*f(d)))
                si = self.scene.ray_intersect(ray)
                valid = np.array(si.is_valid())
                t = np.where(valid, np.array(si.t, dtype=np.float64), np.inf)
                p = np.array(si.p, dtype=np.float64).T
                ptr = np.array(dr.reinterpret_array(mi.UInt32, si.shape))
                uniq, inv = np.unique(ptr, return_inverse=True)
                idx = np.array([self._index_of.get(int(v), -1) for v in uniq], dtype=np.int64)
                shape = np.where(valid, idx[inv.reshape(-1)], -1)
                if not surface:
                    return t, shape, p
                nn = np.array(si.n, dtype=np.float64).T
                uv = np.array(si.uv, dtype=np.float64).T
                return t, shape, p, nn, uv
            t = np.full(n, np.inf)
            shape = np.full(n, -1, dtype=np.int64)
            p = np.zeros((n, 3))
            nn = np.zeros((n, 3))
            uv = np.zeros((n, 2))
            for i in range(n):
                si = self.scene.ray_intersect(mi.Ray3f(mi.Point3f(*o[i]), mi.Vector3f(*d[i])))
                if si.is_valid():
                    t[i] = si.t
                    shape[i] = self._index_of.get(id(si.shape), -1)
                    p[i] = (si.p[0], si.p[1], si.p[2])
                    nn[i] = (si.n[0], si.n[1], si.n[2])
                    uv[i] = (si.uv[0], si.uv[1])
            return (t, shape, p, nn, uv) if surface else (t, shape, p)


def seen_mask(caster, view_id, train_ids):
    """For held-out sensor `view_id`: per pixel (h, w), the first-hit shape index (-1: none)
    and whether that point is a non-emitter surface seen by at least one training camera
    (inside its film, in front of its near plane, and the first hit of the ray from that
    camera's position to the point, within VIS_RTOL * distance + VIS_ATOL)."""
    cam = caster.cameras[view_id]
    t, shape, pts = caster.cast(cam.origin, cam.pixel_rays())
    surf = (shape >= 0) & ~caster.is_emitter[shape]
    seen = np.zeros_like(surf)
    for tid in train_ids:
        tc = caster.cameras[tid]
        _, inside = tc.project(pts)
        todo = np.flatnonzero(surf & inside & ~seen)
        if todo.size == 0:
            continue
        v = pts[todo] - tc.origin
        dist = np.linalg.norm(v, axis=1)
        th, _, _ = caster.cast(tc.origin, v / dist[:, None])
        seen[todo[np.abs(th - dist) <= VIS_RTOL * dist + VIS_ATOL]] = True
    return shape.reshape(cam.h, cam.w), seen.reshape(cam.h, cam.w)


def _albedo_scene(root, spp):
    """`root` (an ET scene, modified) with the `aov` albedo integrator, box pixel filters and
    `spp` samples per pixel in every sensor; returns the XML text."""
    for i in root.findall("integrator"):
        root.remove(i)
    root.insert(0, ET.fromstring(ALBEDO_INTEGRATOR))
    for s in root.findall("sensor"):
        _set_spp(s, spp)
        for film in s.iter("film"):
            for rf in film.findall("rfilter"):
                film.remove(rf)
            film.append(ET.Element("rfilter", {"type": "box"}))
    return ET.tostring(root, encoding="unicode")


def _render_albedo(xml_text, base_dir, spp, llvm=False):
    """{sensor id: albedo AOV (h, w, 3) float64}, scalar_rgb (or `_variant(llvm)`), seed 0 (the
    same sample positions in the recovered and the true scene: their difference is the
    albedo's, not the sampler's)."""
    mi = mitsuba()
    with _variant(llvm):
        scene = _load(xml_text, base_dir)
        return {s.id(): np.array(mi.render(scene, sensor=i, spp=spp, seed=0),
                                 dtype=np.float64)[..., -3:]
                for i, s in enumerate(scene.sensors())}


def albedo_errors(a, t, mask):
    """The albedo figures over the pixels of `mask` (h, w) whose true albedo sum is > 1e-6:
    mean of sum_c |a_c - t_c| / sum_c t_c, and sum |a - t| / sum t."""
    st = t.sum(axis=-1)
    m = mask & (st > BLACK)
    num = np.abs(a - t).sum(axis=-1)
    sq = float(((a - t)[m] ** 2).sum())
    n = int(m.sum())
    return {
        "albedo_mean_rel_error": float(np.mean(num[m] / st[m])) if n else float("nan"),
        "albedo_rel_l1": float(num[m].sum() / st[m].sum()) if n else float("nan"),
        "albedo_psnr_db": psnr(sq, 3 * n),
        "masked_pixels": n,
        "masked_fraction": float(n / m.size),
        "_sums": (float((num[m] / st[m]).sum()), float(num[m].sum()), float(st[m].sum()), n,
                  int(m.size), sq),
    }


def psnr(sq, count):
    """PSNR in dB of albedo (peak 1) from a sum of squared errors over `count` values: the
    k_d PSNR inverse-rendering papers (FIPT, ...) report; inf for an exact match."""
    if count == 0:
        return float("nan")
    return float("inf") if sq == 0 else float(10 * np.log10(count / sq))


def albedo_score(out, scene_dir, spp=64, save_dir=None, orig_xml=None, masks=None, llvm=False):
    """The held-out albedo judge: albedo AOVs of the recovered scene (`<out>/scene.xml` with the
    held-out sensors) and of the true scene (`truth.xml`) from every `cam_test_*` view,
    compared over the pixels whose first hit (pixel-centre ray) is a non-emitter shape that a
    training camera `cam_train_*` of truth.xml sees. Figures pooled over all views' masked
    pixels, and per view and per shape. `masks` (a dict) gets every view's mask."""
    mi = mitsuba()
    t_start = time.perf_counter()
    truth_xml = os.path.join(scene_dir, "truth.xml")
    if orig_xml is None:
        orig_xml = build_scene(out, truth_xml, None, spp)
    rec_text = _albedo_scene(ET.fromstring(orig_xml), spp)
    troot = ET.parse(truth_xml).getroot()
    train_ids = [s.get("id") for s in troot.findall("sensor")
                 if s.get("id", "").startswith("cam_train_")]
    caster = _RayCaster(ET.tostring(troot, encoding="unicode"), scene_dir)
    for s in troot.findall("sensor"):
        if not s.get("id", "").startswith("cam_test_"):
            troot.remove(s)
    true_text = _albedo_scene(troot, spp)
    t0 = time.perf_counter()
    rec = _render_albedo(rec_text, out, spp, llvm)
    true = _render_albedo(true_text, scene_dir, spp, llvm)
    render_s = time.perf_counter() - t0
    views, shapes = {}, {}
    tot = np.zeros(6)
    mask_s = 0.0
    for vid, t in true.items():
        t0 = time.perf_counter()
        shape, seen = seen_mask(caster, vid, train_ids)
        mask_s += time.perf_counter() - t0
        if masks is not None:
            masks[vid] = seen
        a = rec[vid]
        e = albedo_errors(a, t, seen)
        tot += np.array(e.pop("_sums"))
        views[vid] = e
        for k in np.unique(shape[seen]):
            sid = caster.shape_ids[k]
            se = albedo_errors(a, t, seen & (shape == k))
            s = shapes.setdefault(sid, np.zeros(6))
            s += np.array(se.pop("_sums"))
        if save_dir is not None:
            os.makedirs(save_dir, exist_ok=True)
            mi.Bitmap(a.astype(np.float32)).write(os.path.join(save_dir, f"{vid}_albedo.exr"))
            mi.Bitmap(t.astype(np.float32)).write(os.path.join(save_dir, f"{vid}_albedo_true.exr"))
            mi.Bitmap((seen * 255).astype(np.uint8)).write(
                os.path.join(save_dir, f"{vid}_albedo_mask.png"))

    def pooled(s):
        n = int(s[3])
        return {"albedo_mean_rel_error": s[0] / n if n else float("nan"),
                "albedo_rel_l1": s[1] / s[2] if s[2] > 0 else float("nan"),
                "albedo_psnr_db": psnr(s[5], 3 * n),
                "masked_pixels": n}

    res = pooled(tot)
    res["masked_fraction"] = float(tot[3] / tot[4]) if tot[4] else float("nan")
    res["spp"] = spp
    res["train_views"] = train_ids
    res["views"] = views
    res["shapes"] = {k: pooled(v) for k, v in sorted(shapes.items())}
    res["ray_casting"] = caster.variant
    res["render_seconds"] = render_s
    res["mask_seconds"] = mask_s
    res["seconds"] = time.perf_counter() - t_start
    return res


def score(out, scene_dir, spp=64, floor=False, albedo=True, llvm=False):
    """Render the held-out views of the recovered scene under the original and the relit
    lighting, and (`albedo`) judge its albedo from the same views (albedo_score); return
    {"spp", "original": {...}, "relit": {...}, "albedo": {...}[, "floor": {...}]} ("albedo"
    is {"error": ...} if that judge failed)."""
    truth_xml = os.path.join(scene_dir, "truth.xml")
    relit_xml = os.path.join(scene_dir, "relit.xml")
    truth_dir = os.path.join(scene_dir, "truth")
    res = {"spp": spp}
    orig = build_scene(out, truth_xml, None, spp)
    relit = build_scene(out, relit_xml, relit_xml, spp)
    for name, text in (("heldout_original.xml", orig), ("heldout_relit.xml", relit)):
        with open(os.path.join(out, name), "w") as f:
            f.write(text)
    save = os.path.join(out, "heldout")
    res["original"] = _summary(_render_all(orig, out, save, "", spp, truth_dir, llvm))
    if os.path.exists(relit_xml):
        res["relit"] = _summary(_render_all(relit, out, save, "_relit", spp, truth_dir, llvm))
    if albedo:
        masks = {}
        try:
            res["albedo"] = albedo_score(out, scene_dir, spp, save, orig, masks, llvm)
            add_seen_figures(res, save, truth_dir, masks)
        except Exception as e:  # reported, the image figures above stand on their own
            res["albedo"] = {"error": f"{type(e).__name__}: {e}"}
    if floor:
        res["floor"] = {}
        for key, xml, suffix in (("original", truth_xml, ""), ("relit", relit_xml, "_relit")):
            with open(xml) as f:
                text = f.read()
            root = ET.fromstring(text)
            for s in root.findall("sensor"):
                if s.get("id", "").startswith("cam_test_"):
                    _set_spp(s, spp)
                else:
                    root.remove(s)
            text = ET.tostring(root, encoding="unicode")
            res["floor"][key] = _summary(_render_all(text, scene_dir, None, suffix, spp, truth_dir,
                                                     llvm))
    return res


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", help="kdmap (or tools/mitsuba_inverse.py) output directory "
                    "(holds scene.xml)")
    ap.add_argument("scene_dir", help="scene directory (truth.xml, relit.xml, truth/)")
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--floor", action="store_true",
                    help="also render the true scene at the same spp (the noise floor)")
    ap.add_argument("--no-albedo", action="store_true", help="skip the held-out albedo judge")
    ap.add_argument("--albedo-only", action="store_true",
                    help="only the held-out albedo judge (no image renders)")
    ap.add_argument("--llvm", action="store_true",
                    help="render with Mitsuba's LLVM variant when it works (large scenes; "
                    "default scalar_rgb)")
    a = ap.parse_args()
    if a.albedo_only:
        res = {"spp": a.spp, "albedo": albedo_score(a.out, a.scene_dir, a.spp,
                                                    os.path.join(a.out, "heldout"),
                                                    llvm=a.llvm)}
        print(json.dumps(res, indent=1))
        return 0
    res = score(a.out, a.scene_dir, a.spp, a.floor, albedo=not a.no_albedo, llvm=a.llvm)
    print(json.dumps(res, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
