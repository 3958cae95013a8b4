#!/usr/bin/env python3
"""The lego scene of the Mitsuba 3 tutorials as a kdmap benchmark: hundreds of small shapes.

Why it exists: kdmap was tuned on scenes of 4-20 large shapes; the lego bulldozer
(`scenes/lego` of github.com/mitsuba-renderer/mitsuba-tutorials: 439 PLY bricks, 2.0M
triangles, lit by an HDR environment map) is what a scene of fine geometry looks like. This
script turns a copy of it into the layout of tests/fixtures/<scene>/ with cameras of its own:

    input.xml                 every brick as a shape named by its mesh file, diffuse 0.5
                              (twosided, as in the tutorial), the envmap, cam_train_*
    truth.xml                 the same with the tutorial's true colours, cam_train_* and cam_test_*
    images/cam_train_*.exr    the photos, rendered from truth.xml (path tracer, box filter)

    .venv/bin/python tools/lego_scene.py --src cache/lego-src/scenes/lego
    .venv/bin/python tools/heldout.py <out> cache/scenes/lego --spp 64 --albedo-only

Get the source with git (`git archive HEAD scenes/lego` of the tutorials repository). Output
defaults to cache/scenes/lego (git-ignored); photos already rendered are kept unless --force.
Training cameras look at the model from four sides 30 degrees up, held-out ones from between
them 20 and 40 degrees up.
"""

import argparse
import math
import os
import sys
import xml.etree.ElementTree as ET

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
CENTER = (0.494, 0.460, 0.494)
DISTANCE = 1.6
FOV = 39.0
# (azimuth, elevation) in degrees, around the up axis y
TRAIN = [(20, 30), (110, 30), (200, 30), (290, 30)]
TEST = [(65, 20), (245, 40)]


def camera(sid, az, el, res, spp):
    a, e = math.radians(az), math.radians(el)
    o = (
        CENTER[0] + DISTANCE * math.cos(e) * math.cos(a),
        CENTER[1] + DISTANCE * math.sin(e),
        CENTER[2] + DISTANCE * math.cos(e) * math.sin(a),
    )
    org = ", ".join(f"{v:.5f}" for v in o)
    tgt = ", ".join(f"{v:.5f}" for v in CENTER)
    return (
        f'  <sensor type="perspective" id="{sid}">\n'
        f'    <float name="fov" value="{FOV}"/>\n'
        f'    <transform name="to_world"><lookat origin="{org}" target="{tgt}" up="0, 1, 0"/>'
        f"</transform>\n"
        f'    <sampler type="independent"><integer name="sample_count" value="{spp}"/></sampler>\n'
        f'    <film type="hdrfilm"><integer name="width" value="{res}"/>'
        f'<integer name="height" value="{res}"/>\n'
        f'      <string name="pixel_format" value="rgb"/><rfilter type="box"/></film>\n'
        f"  </sensor>\n"
    )


def colours(root):
    """The tutorial's bsdf id -> its diffuse reflectance text (inside `twosided`)."""
    out = {}
    for b in root.findall("bsdf"):
        rgb = b.find(".//rgb[@name='reflectance']")
        if b.get("id") and rgb is not None:
            out[b.get("id")] = rgb.get("value")
    return out


def shapes(root, src, truth):
    """Every ply shape, named by its mesh file, with its true colour or 0.5."""
    cols = colours(root)
    text = []
    for s in root.findall("shape"):
        fn = s.find("string[@name='filename']").get("value")
        ref = s.find("ref").get("id")
        rgb = cols.get(ref, "0.5 0.5 0.5") if truth else "0.5, 0.5, 0.5"
        sid = os.path.splitext(os.path.basename(fn))[0]
        text.append(
            f'  <shape type="ply" id="{sid}"><string name="filename" '
            f'value="{os.path.join(src, fn)}"/><bsdf type="twosided"><bsdf type="diffuse">'
            f'<rgb name="reflectance" value="{rgb}"/></bsdf></bsdf></shape>\n'
        )
    return "".join(text)


def scene_xml(root, src, truth, res, spp):
    env = os.path.join(src, "textures", "cathedral.hdr")
    cams = [camera(f"cam_train_{i}", a, e, res, spp) for i, (a, e) in enumerate(TRAIN)]
    if truth:
        cams += [camera(f"cam_test_{i}", a, e, res, spp) for i, (a, e) in enumerate(TEST)]
    return (
        '<scene version="3.0.0">\n'
        '  <integrator type="path"><integer name="max_depth" value="8"/></integrator>\n'
        + "".join(cams)
        + f'  <emitter type="envmap"><string name="filename" value="{env}"/>'
        '<float name="scale" value="0.5"/><transform name="to_world">'
        '<rotate x="0" y="1" z="0" angle="20"/></transform></emitter>\n'
        + shapes(root, src, truth)
        + "</scene>\n"
    )


def render(out, spp, force):
    from exrio import mitsuba, render_sensors

    mi = mitsuba("llvm_ad_rgb")
    render_sensors(mi, os.path.join(out, "truth.xml"), os.path.join(out, "images"), "cam_train_",
                   spp, force)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--src", default=os.path.join(REPO, "cache", "lego-src", "scenes", "lego"))
    ap.add_argument("out", nargs="?", default=os.path.join(REPO, "cache", "scenes", "lego"))
    ap.add_argument("--res", type=int, default=256)
    ap.add_argument("--spp", type=int, default=128)
    ap.add_argument("--force", action="store_true")
    a = ap.parse_args()
    src = os.path.abspath(a.src)
    if not os.path.isfile(os.path.join(src, "scene.xml")):
        sys.exit(f"{src}/scene.xml not found: extract scenes/lego of mitsuba-tutorials there")
    root = ET.parse(os.path.join(src, "scene.xml")).getroot()
    os.makedirs(a.out, exist_ok=True)
    for name, truth in (("input.xml", False), ("truth.xml", True)):
        with open(os.path.join(a.out, name), "w") as f:
            f.write(scene_xml(root, src, truth, a.res, a.spp))
    render(a.out, a.spp, a.force)


if __name__ == "__main__":
    main()
