#!/usr/bin/env python3
"""Score a kdmap reconstruction with an independent renderer (Mitsuba 3) on held-out views.

    .venv/bin/python tools/heldout.py <out dir> <scene dir> [--spp 64] [--floor]

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
        for e in src.findall("emitter"):
            root.append(e)
        for sh in src.findall("shape"):
            if sh.find("emitter") is not None:
                root.append(sh)
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


def _render_all(xml_text, base_dir, save_dir, suffix, spp, truth_dir):
    mi = mitsuba()
    fr = mi.file_resolver()
    saved = [fr[i] for i in range(len(fr))]
    fr.prepend(os.path.abspath(base_dir))
    try:
        scene = mi.load_string(xml_text)
    finally:
        fr.clear()
        for p in saved:
            fr.append(p)
    views = {}
    for i, sensor in enumerate(scene.sensors()):
        sid = sensor.id()
        t0 = time.perf_counter()
        img = np.array(mi.render(scene, sensor=i, spp=spp))[..., :3]
        secs = time.perf_counter() - t0
        if save_dir is not None:
            os.makedirs(save_dir, exist_ok=True)
            mi.Bitmap(img.astype(np.float32)).write(os.path.join(save_dir, f"{sid}{suffix}.exr"))
        truth = read_exr_rgb(os.path.join(truth_dir, f"{sid}{suffix}.exr"))
        e = errors(img, truth)
        e["seconds"] = secs
        views[sid] = e
    return views


def _summary(views):
    keys = ["mean_rel_lum_error", "rel_l1_error", "block8_rel_lum_error"]
    s = {k: float(np.mean([v[k] for v in views.values()])) for k in keys}
    s["views"] = views
    s["seconds"] = float(sum(v["seconds"] for v in views.values()))
    return s


def score(out, scene_dir, spp=64, floor=False):
    """Render the held-out views of the recovered scene under the original and the relit
    lighting; return {"spp", "original": {...}, "relit": {...}[, "floor": {...}]}."""
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
    res["original"] = _summary(_render_all(orig, out, save, "", spp, truth_dir))
    if os.path.exists(relit_xml):
        res["relit"] = _summary(_render_all(relit, out, save, "_relit", spp, truth_dir))
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
            res["floor"][key] = _summary(_render_all(text, scene_dir, None, suffix, spp, truth_dir))
    return res


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", help="kdmap output directory (holds scene.xml)")
    ap.add_argument("scene_dir", help="scene directory (truth.xml, relit.xml, truth/)")
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--floor", action="store_true",
                    help="also render the true scene at the same spp (the noise floor)")
    a = ap.parse_args()
    res = score(a.out, a.scene_dir, a.spp, a.floor)
    print(json.dumps(res, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
