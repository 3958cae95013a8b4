#!/usr/bin/env python3
"""The representational floor of a kdmap run on the held-out albedo judge.

    .venv/bin/python tools/repr_floor.py <out dir> <scene dir> [--spp 64]

Copies the run to `<out>-truthtex`, puts the TRUE albedo baked into the run's own atlas (each
texel the truth averaged over its square: `<out>/accuracy/<shape>_truth.exr`, written by
`kdmap accuracy <out> <scene>/truth.xml`, which must have run) in place of each recovered
`textures/<shape>_albedo.exr`, and scores that with the held-out albedo judge
(`heldout.albedo_score`, what `tools/heldout.py --albedo-only` runs): what a perfect solver
would score at the run's texel density. (Chart gutters of the baked truth are
not dilated, so seams bleed a little: the figure is a slight overestimate.)
"""

import argparse
import glob
import os
import shutil
import sys


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("out")
    ap.add_argument("scene_dir")
    ap.add_argument("--spp", type=int, default=64)
    a = ap.parse_args()
    truths = glob.glob(os.path.join(a.out, "accuracy", "*_truth.exr"))
    if not truths:
        sys.exit(f"{a.out}/accuracy: no *_truth.exr; run `kdmap accuracy {a.out} "
                 f"{a.scene_dir}/truth.xml` first")
    dst = a.out.rstrip("/") + "-truthtex"
    shutil.rmtree(dst, ignore_errors=True)
    shutil.copytree(a.out, dst)
    for t in truths:
        shape = os.path.basename(t)[: -len("_truth.exr")]
        shutil.copyfile(t, os.path.join(dst, "textures", f"{shape}_albedo.exr"))
    import heldout

    try:
        j = heldout.albedo_score(dst, a.scene_dir, a.spp, os.path.join(dst, "heldout"))
    except Exception as e:  # a Mitsuba failure: one line
        sys.exit(f"held-out albedo judge failed: {type(e).__name__}: {e}")
    e = j["albedo_mean_rel_error"]
    print(f"representational floor (held-out albedo, true texels at the run's density): "
          f"{100 * e:.2f}% ({dst})")


if __name__ == "__main__":
    main()
