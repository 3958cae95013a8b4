#!/usr/bin/env python3
"""Check that a kdmap output directory's scene.xml loads and renders in Mitsuba 3.

Run manually (not part of the test suite; needs Mitsuba 3 and numpy):

    python3 -m venv .venv && .venv/bin/pip install mitsuba numpy
    .venv/bin/python tools/check_scene_mitsuba.py <out dir> [--spp 16] [--sensor 0]

Loads <out dir>/scene.xml with the scalar_rgb variant, lists what it holds, renders one
sensor at low spp into <out dir>/renders/<sensor>_mitsuba.exr and, if kdmap's own re-render
renders/<sensor>.exr is there, prints the mean luminance of both (they agree only as far as
the run converged: kdmap's render uses the recovered E_d + E_i, Mitsuba traces the light).
Exit code 0 when the scene loads and renders.
"""

import argparse
import os
import sys


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", help="kdmap output directory (holds scene.xml)")
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--sensor", type=int, default=0)
    args = ap.parse_args()

    import mitsuba as mi

    mi.set_variant("scalar_rgb")
    path = os.path.join(args.out, "scene.xml")
    scene = mi.load_file(path, spp=args.spp)
    print(f"loaded {path}: {len(scene.shapes())} shapes, {len(scene.emitters())} emitters, "
          f"{len(scene.sensors())} sensors")
    for s in scene.shapes():
        kind = str(s.bsdf()).split("[")[0].strip()
        tag = "  emitter" if s.is_emitter() else ""
        print(f"  shape {s.id():<12} {s.face_count():>6} faces  bsdf {kind}{tag}")
    sensor = scene.sensors()[args.sensor]
    sid = sensor.id()
    img = mi.render(scene, sensor=sensor, spp=args.spp)
    bmp = mi.Bitmap(img)
    dst = os.path.join(args.out, "renders", f"{sid}_mitsuba.exr")
    os.makedirs(os.path.dirname(dst), exist_ok=True)
    bmp.write(dst)
    print(f"rendered sensor {sid} at {args.spp} spp -> {dst}")

    try:
        import numpy as np
    except ImportError:
        return 0
    lum = np.array([0.2126, 0.7152, 0.0722])
    mit = np.array(bmp)[..., :3]
    print(f"  Mitsuba mean luminance {float((mit @ lum).mean()):.6f}")
    ours = os.path.join(args.out, "renders", f"{sid}.exr")
    if os.path.exists(ours):
        k = np.array(mi.Bitmap(ours))[..., :3]
        print(f"  kdmap   mean luminance {float((k @ lum).mean()):.6f} ({ours})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
