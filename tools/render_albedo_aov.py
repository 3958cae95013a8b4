#!/usr/bin/env python3
"""Render the true albedo as the training cameras see it (Mitsuba 3's `albedo` AOV, box pixel
filter unless `--filter` says otherwise) for a scene shipped under tests/fixtures, and write it
as half-float EXRs to `<scene>/albedo/<sensor id>.exr` (`<scene>/albedo-<filter>/` for another
filter).

These images are what a perfect photo of the albedo alone would be at the photos' resolution:
projected onto the atlas by kdmap, they give the *resolution floor* of a reconstruction, the
error no solver can go below because the photos do not resolve finer texture detail (used by
tests/it/accuracy.rs). Needs `pip install mitsuba numpy` (the `scalar_rgb` variant needs no
system libraries).

    .venv/bin/python tools/render_albedo_aov.py tests/fixtures/cbox-tex [--spp 256] [--filter tent]

With `--filter tent` (or `gaussian`) the same images through that pixel filter: the fixture
that shows the projection undoes a wider filter's blur as well as a box's.
"""
import argparse
import os
import re
import sys

import mitsuba as mi
import numpy as np


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("scene_dir")
    ap.add_argument("--spp", type=int, default=256)
    ap.add_argument("--filter", choices=["box", "tent", "gaussian"], default="box")
    a = ap.parse_args()
    mi.set_variant("scalar_rgb")
    d = os.path.abspath(a.scene_dir)
    src = open(os.path.join(d, "truth.xml")).read()
    src = re.sub(
        r"<integrator.*?</integrator>",
        '<integrator type="aov"><string name="aovs" value="a:albedo"/></integrator>',
        src,
        flags=re.S,
    )
    src = re.sub(r'(name="sample_count" value=")\d+', rf"\g<1>{a.spp}", src)
    src = re.sub(r'<rfilter type="\w+"\s*/>', f'<rfilter type="{a.filter}"/>', src)
    sub = "albedo" if a.filter == "box" else f"albedo-{a.filter}"
    cwd = os.getcwd()
    os.chdir(d)  # relative mesh and texture paths
    try:
        scene = mi.load_string(src)
    finally:
        os.chdir(cwd)
    os.makedirs(os.path.join(d, sub), exist_ok=True)
    for i, s in enumerate(scene.sensors()):
        if not s.id().startswith("cam_train"):
            continue
        img = np.array(mi.render(scene, sensor=i))[:, :, -3:].astype(np.float32)
        out = os.path.join(d, sub, f"{s.id()}.exr")
        bmp = mi.Bitmap(np.ascontiguousarray(img), mi.Bitmap.PixelFormat.RGB)
        bmp.convert(component_format=mi.Struct.Type.Float16).write(out)
        print(f"{out}: mean albedo {img.reshape(-1, 3).mean(0)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
