#!/usr/bin/env python3
"""Make the coated-room fixture: the Cornell box of tests/fixtures/cbox-tex (its meshes and
cameras) with a varnished floor (`roughplastic`, GGX alpha 0.15, over a uniform wood-brown
base) and a gloss-painted tall box (`plastic` over a blue base), the other surfaces matte and
uniform; training photos rendered with Mitsuba 3 as half-float EXR.

    .venv/bin/python tools/coat_scene.py [OUT] [--spp 1024] [--res 128] [--matte]

Writes `OUT` (default tests/fixtures/coat-cbox): `input.xml` (what a user hands in: the coats
as they are, their bases and every diffuse reflectance the 0.5 placeholder), `truth.xml` (the
true scene with the held-out cameras `cam_test_*`, for tools/heldout.py --albedo-only),
`meshes/` (copied) and `images/cam_train_<k>.exr` (path tracer, `spp` samples per pixel, box
filter, `res` x `res`). `--matte` makes the all-matte control instead (the same bases as
`diffuse`), e.g. into cache/scenes/coat-cbox-matte.
"""

import argparse
import os
import shutil
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SRC = os.path.join(ROOT, "tests", "fixtures", "cbox-tex")

CAMERAS = [
    ("cam_train_0", 42, "-0.8, 1.0, 3.6", "0, 1.0, 0"),
    ("cam_train_1", 40, "0.0, 1.1, 3.8", "0, 1.0, 0"),
    ("cam_train_2", 42, "0.8, 0.9, 3.6", "0, 1.0, 0"),
    ("cam_train_3", 50, "0.3, 1.7, 3.2", "0, 0.4, 0"),
    ("cam_test_0", 44, "-0.4, 1.3, 3.3", "0, 1.0, 0"),
    ("cam_test_1", 41, "0.5, 0.7, 3.5", "0.1, 0.9, 0"),
]

FLOOR_BASE = "0.6, 0.42, 0.25"
BOX_BASE = "0.15, 0.3, 0.6"
MATTE = {
    "ceiling": "0.73, 0.73, 0.73",
    "back": "0.73, 0.73, 0.73",
    "left": "0.63, 0.065, 0.05",
    "right": "0.14, 0.45, 0.091",
    "short_box": "0.7, 0.7, 0.3",
}


def sensor(sid, fov, origin, target, res, spp):
    return f"""  <sensor type="perspective" id="{sid}">
    <float name="fov" value="{fov}"/>
    <string name="fov_axis" value="x"/>
    <transform name="to_world"><lookat origin="{origin}" target="{target}" up="0, 1, 0"/></transform>
    <sampler type="independent"><integer name="sample_count" value="{spp}"/></sampler>
    <film type="hdrfilm"><integer name="width" value="{res}"/><integer name="height" value="{res}"/>
      <string name="pixel_format" value="rgb"/><rfilter type="box"/></film>
  </sensor>
"""


def rgb(name, v):
    return f'<rgb name="{name}" value="{v}"/>'


def coats(base_floor, base_box, matte):
    """The floor's and the tall box's bsdfs."""
    if matte:
        return (f'<bsdf type="diffuse">{rgb("reflectance", base_floor)}</bsdf>',
                f'<bsdf type="diffuse">{rgb("reflectance", base_box)}</bsdf>')
    floor = ('<bsdf type="roughplastic"><string name="distribution" value="ggx"/>'
             '<float name="alpha" value="0.15"/><float name="int_ior" value="1.5"/>'
             f'{rgb("diffuse_reflectance", base_floor)}</bsdf>')
    box = ('<bsdf type="plastic"><float name="int_ior" value="1.5"/>'
           f'{rgb("diffuse_reflectance", base_box)}</bsdf>')
    return floor, box


def scene(res, spp, truth, matte):
    """The scene's XML: `truth` the true bases and every camera, else the placeholders and
    the training cameras."""
    out = ['<scene version="3.0.0">',
           '  <integrator type="path"><integer name="max_depth" value="-1"/>'
           '<integer name="rr_depth" value="8"/></integrator>']
    for sid, fov, o, t in CAMERAS:
        if truth or sid.startswith("cam_train"):
            out.append(sensor(sid, fov, o, t, res, spp))
    floor, box = coats(FLOOR_BASE if truth else "0.5, 0.5, 0.5",
                       BOX_BASE if truth else "0.5, 0.5, 0.5", matte)

    def shape(sid, bsdf):
        return (f'  <shape type="obj" id="{sid}"><string name="filename" '
                f'value="meshes/{sid}.obj"/>{bsdf}</shape>')

    out.append(shape("floor", floor))
    for sid, c in MATTE.items():
        c = c if truth else "0.5, 0.5, 0.5"
        out.append(shape(sid, f'<bsdf type="diffuse">{rgb("reflectance", c)}</bsdf>'))
    out.append(shape("tall_box", box))
    out.append('  <shape type="obj" id="light"><string name="filename" value="meshes/light.obj"/>'
               '<bsdf type="diffuse"><rgb name="reflectance" value="0"/></bsdf>'
               '<emitter type="area"><rgb name="radiance" value="17, 12, 4"/></emitter></shape>')
    out.append("</scene>\n")
    return "\n".join(out)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("out", nargs="?", default=os.path.join(ROOT, "tests", "fixtures", "coat-cbox"))
    ap.add_argument("--spp", type=int, default=1024)
    ap.add_argument("--res", type=int, default=128)
    ap.add_argument("--matte", action="store_true")
    a = ap.parse_args()
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    from exrio import mitsuba  # noqa: E402
    from heldout import ensure_libllvm  # noqa: E402
    mi = mitsuba("llvm_ad_rgb" if ensure_libllvm() else "scalar_rgb")
    os.makedirs(os.path.join(a.out, "images"), exist_ok=True)
    shutil.copytree(os.path.join(SRC, "meshes"), os.path.join(a.out, "meshes"),
                    dirs_exist_ok=True)
    with open(os.path.join(a.out, "input.xml"), "w") as f:
        f.write(scene(a.res, a.spp, False, a.matte))
    truth = scene(a.res, a.spp, True, a.matte)
    with open(os.path.join(a.out, "truth.xml"), "w") as f:
        f.write(truth)
    cwd = os.getcwd()
    os.chdir(a.out)
    try:
        sc = mi.load_string(truth)
    finally:
        os.chdir(cwd)
    for i, s in enumerate(sc.sensors()):
        if not s.id().startswith("cam_train"):
            continue
        img = mi.render(sc, sensor=i, spp=a.spp, seed=i)
        bmp = mi.Bitmap(img).convert(pixel_format=mi.Bitmap.PixelFormat.RGB,
                                     component_format=mi.Struct.Type.Float16)
        path = os.path.join(a.out, "images", f"{s.id()}.exr")
        bmp.write(path)
        print(path, flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
