#!/usr/bin/env python3
"""A Bitterli interior (Mitsuba 0.6 form) as a kdmap benchmark scene with photos at eye height.

Why it exists: the scenes kdmap was tuned on have 4-20 large shapes; the interiors people
model (Benedikt Bitterli's rendering resources, CC-BY / CC0: hundreds of shapes, textured wood,
panelling and wallpaper, varnish and gloss paint, glass, metal) are what real users bring.
This script turns one such scene, as kept in public repositories in Mitsuba 0.6 form
(`scene.xml`, `models/`, `textures/`), into the layout of tests/fixtures/<scene>/:

    input.xml                 Mitsuba 3 form; every diffuse shape as diffuse 0.5, every
                              plastic / roughplastic with its coat and a 0.5 base (both to
                              recover); conductors, glass and emitters as they are; cam_train_*
    truth.xml                 the same with the true colours and textures, cam_train_* and
                              cam_test_*
    relit.xml                 truth.xml under other light: area emitters at 40% and warm, an
                              environment map turned by 90 degrees
    images/cam_train_*.exr    the photos (path tracer, box filter)
    truth/cam_test_*.exr      held-out views under the original and the relit light

    .venv/bin/python tools/bitterli_scene.py --src cache/bitterli-src/staircase
    kdmap reconstruct cache/scenes/staircase/input.xml --out /tmp/staircase
    .venv/bin/python tools/heldout.py /tmp/staircase cache/scenes/staircase --spp 64

Changes to the published scene, the same in every file (so the truth is what is rendered):
bump maps and alpha masks are dropped (their inner bsdf kept: leaves become opaque cards), and
the plastics' `nonlinear` is set to false (Mitsuba's default; kdmap reconstructs such a base).
Shapes are named by their mesh file (`Mesh038`), rectangles `rect_<n>`; paths are absolute.

Cameras: the published view is the anchor (its position, height, field of view and aspect;
photos 640 pixels along the longer side). Training cameras turn from -yaw to +yaw about it and
step sideways by up to `--shift` of the depth it looks into, odd ones also forward by half
that, tilting down and up by 6 degrees in turn; held-out cameras sit between them, level. A
camera whose step would pass through geometry stops short of it.
Photos already rendered are kept unless --force.
"""

import argparse
import math
import os
import re
import sys
import xml.etree.ElementTree as ET

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

KNOWN = {"conductor", "roughconductor", "dielectric", "roughdielectric", "thindielectric"}
COATED = {"plastic", "roughplastic"}
DROPPED = {"banner", "fileFormat", "pixelFormat", "high_quality_edges"}


def snake(name):
    """Mitsuba 0.6 parameter names to Mitsuba 3 ones (`intIOR` -> `int_ior`)."""
    return re.sub(r"([a-z0-9])([A-Z])", r"\1_\2", name).lower()


def unwrap(parent):
    """Replace every bumpmap and mask below `parent` by its inner bsdf (keeping the id)."""
    for i, child in enumerate(list(parent)):
        unwrap(child)
        if child.tag == "bsdf" and child.get("type") in ("bumpmap", "mask"):
            inner = child.find("bsdf")
            if child.get("id") and not inner.get("id"):
                inner.set("id", child.get("id"))
            parent.remove(child)
            parent.insert(i, inner)


def upgrade(root, src):
    """The Mitsuba 0.6 scene in Mitsuba 3 form, without its sensors and integrator."""
    root.set("version", "3.0.0")
    for e in list(root):
        if e.tag in ("sensor", "integrator"):
            root.remove(e)
    unwrap(root)
    for e in root.iter():
        if e.get("name") in DROPPED:
            e.set("name", "_drop")
        elif e.get("name"):
            e.set("name", snake(e.get("name")))
        if e.get("name") == "filename":
            e.set("value", os.path.join(src, e.get("value")))
    for parent in root.iter():
        for c in list(parent):
            if c.get("name") == "_drop":
                parent.remove(c)
    for b in root.iter("bsdf"):
        if b.get("type") in COATED:
            for c in list(b):
                if c.get("name") == "nonlinear":
                    b.remove(c)
    rects = 0
    for s in root.findall("shape"):
        fn = s.find("string[@name='filename']")
        if fn is not None:
            s.set("id", os.path.splitext(os.path.basename(fn.get("value")))[0])
        else:
            s.set("id", f"rect_{rects}" if s.get("type") == "rectangle" else f"shape_{rects}")
            rects += 1
    return root


def to_unknown(root):
    """input.xml's materials: every diffuse reflectance and coated base a uniform 0.5."""
    for b in root.iter("bsdf"):
        key = {"diffuse": "reflectance"}.get(b.get("type"))
        if b.get("type") in COATED:
            key = "diffuse_reflectance"
        if key is None:
            continue
        for c in list(b):
            if c.get("name") == key:
                b.remove(c)
        ET.SubElement(b, "rgb", name=key, value="0.5, 0.5, 0.5")


def relight(root):
    """relit.xml's light: area emitters at 40% and warm, environment maps turned 90 degrees."""
    for em in root.iter("emitter"):
        if em.get("type") == "area":
            r = em.find("rgb[@name='radiance']")
            v = [float(x) for x in r.get("value").replace(",", " ").split()]
            v = v * 3 if len(v) == 1 else v
            r.set("value", ", ".join(f"{x * f:g}" for x, f in zip(v, (0.48, 0.4, 0.3))))
        elif em.get("type") == "envmap":
            t = em.find("transform[@name='to_world']")
            if t is None:
                t = ET.SubElement(em, "transform", name="to_world")
            ET.SubElement(t, "rotate", y="1", angle="90")


def anchor(sensor):
    """(origin, forward, up, fov, aspect) of the published sensor."""
    m = [float(x) for x in sensor.find("transform/matrix").get("value").split()]
    col = lambda j: (m[j], m[4 + j], m[8 + j])  # noqa: E731
    film = sensor.find("film")
    w = int(film.find("integer[@name='width']").get("value"))
    h = int(film.find("integer[@name='height']").get("value"))
    # Mitsuba's camera looks along +z of its frame, x to the left
    return col(3), col(2), col(1), float(sensor.find("float[@name='fov']").get("value")), w / h


def add(a, b, s=1.0):
    return tuple(x + s * y for x, y in zip(a, b))


def cross(a, b):
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def norm(a):
    n = math.sqrt(sum(x * x for x in a))
    return tuple(x / n for x in a)


def turn(f, up, yaw, pitch):
    """`f` turned by `yaw` degrees about `up`, then tilted by `pitch` degrees."""
    right = norm(cross(f, up))
    y, p = math.radians(yaw), math.radians(pitch)
    g = norm(add(tuple(math.cos(y) * x for x in f), right, math.sin(y)))
    return norm(add(tuple(math.cos(p) * x for x in g), up, math.sin(p)))


def poses(o, f, up, n_train, n_test, yaw, shift, free):
    """[(id, origin, forward)] of the training and held-out cameras; `free(a, b)` says how far
    one can go from a towards b (a fraction <= 1)."""
    right = norm(cross(f, up))
    out = []

    def cam(sid, t, back, pitch):
        step = add(tuple(t * shift * x for x in right), f, -back * shift)
        p = add(o, step, 0.8 * free(o, add(o, step)))
        out.append((sid, p, turn(f, up, -t * yaw, pitch)))

    for i in range(n_train):
        t = -1 + 2 * i / max(n_train - 1, 1)
        cam(f"cam_train_{i}", t, -0.5 * (i % 2), 6.0 * (1 if i % 2 else -1))
    for i in range(n_test):
        t = -1 + 2 * (i + 0.5) / n_test
        t = t * (n_train - 1) / n_train if n_train > 1 else t
        cam(f"cam_test_{i}", t, -0.25, 0.0)
    return out


def sensor_xml(sid, p, f, up, fov, res, spp):
    tgt = add(p, f)
    fmt = lambda v: ", ".join(f"{x:.6f}" for x in v)  # noqa: E731
    return (
        f'<sensor type="perspective" id="{sid}"><float name="fov" value="{fov}"/>'
        f'<transform name="to_world"><lookat origin="{fmt(p)}" target="{fmt(tgt)}" '
        f'up="{fmt(up)}"/></transform><sampler type="independent">'
        f'<integer name="sample_count" value="{spp}"/></sampler><film type="hdrfilm">'
        f'<integer name="width" value="{res[0]}"/><integer name="height" value="{res[1]}"/>'
        f'<string name="pixel_format" value="rgb"/><rfilter type="box"/></film></sensor>'
    )


def write(root, path, sensors, depth):
    root = ET.fromstring(ET.tostring(root))
    root.insert(0, ET.fromstring(
        f'<integrator type="path"><integer name="max_depth" value="{depth}"/></integrator>'))
    for i, s in enumerate(sensors):
        root.insert(1 + i, ET.fromstring(s))
    ET.indent(root)
    ET.ElementTree(root).write(path, encoding="unicode")


def free_fn(mi, scene):
    """How far one may step from a to b before geometry, as a fraction of the step."""
    def free(a, b):
        d = tuple(y - x for x, y in zip(a, b))
        n = math.sqrt(sum(x * x for x in d))
        if n == 0:
            return 1.0
        ray = mi.Ray3f(mi.Point3f(*a), mi.Vector3f(*(x / n for x in d)))
        si = scene.ray_intersect(ray)
        t = float(si.t[0]) if hasattr(si.t, "__len__") else float(si.t)
        return min(1.0, t / n) if math.isfinite(t) else 1.0
    return free


def depth_ahead(mi, scene, o, f):
    si = scene.ray_intersect(mi.Ray3f(mi.Point3f(*o), mi.Vector3f(*f)))
    t = float(si.t[0]) if hasattr(si.t, "__len__") else float(si.t)
    return t if math.isfinite(t) else 1.0


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--src", required=True, help="the published scene: scene.xml, models/, ...")
    ap.add_argument("out", nargs="?", help="default cache/scenes/<name of --src>")
    ap.add_argument("--res", help="photo size WxH (default: the published film's aspect, "
                    "640 pixels along its longer side)")
    ap.add_argument("--train", type=int, default=8)
    ap.add_argument("--test", type=int, default=3)
    ap.add_argument("--yaw", type=float, default=20.0, help="degrees each side (default 20)")
    ap.add_argument("--shift", type=float, default=0.15,
                    help="step sideways, as a share of the depth ahead (default 0.15)")
    ap.add_argument("--spp", type=int, default=256)
    ap.add_argument("--truth-spp", type=int, default=512)
    ap.add_argument("--max-depth", type=int, default=16)
    ap.add_argument("--no-truth", action="store_true", help="skip the held-out renders")
    ap.add_argument("--force", action="store_true", help="render the photos again")
    a = ap.parse_args()
    src = os.path.abspath(a.src)
    xml = os.path.join(src, "scene.xml")
    if not os.path.isfile(xml):
        sys.exit(f"{xml} not found: extract a Bitterli scene in Mitsuba 0.6 form there")
    out = a.out or os.path.join(REPO, "cache", "scenes", os.path.basename(src.rstrip("/")))
    os.makedirs(out, exist_ok=True)

    from exrio import mitsuba, render_sensors as render
    from heldout import _llvm_available as llvm_available
    mi = mitsuba()
    if llvm_available():
        mi.set_variant("llvm_ad_rgb")
    src_root = ET.parse(xml).getroot()
    o, f, up, fov, aspect = anchor(src_root.find("sensor"))
    if a.res:
        res = tuple(int(x) for x in a.res.lower().split("x"))
    else:
        res = (640, round(640 / aspect)) if aspect >= 1 else (round(640 * aspect), 640)
    truth = upgrade(src_root, src)
    geo = os.path.join(out, "geometry.xml")
    write(truth, geo, [], a.max_depth)
    scene = mi.load_file(geo)
    os.remove(geo)
    shift = a.shift * depth_ahead(mi, scene, o, f)
    cams = poses(o, f, up, a.train, a.test, a.yaw, shift, free_fn(mi, scene))
    train = [sensor_xml(s, p, d, up, fov, res, a.spp) for s, p, d in cams if "train" in s]
    test = [sensor_xml(s, p, d, up, fov, res, a.truth_spp) for s, p, d in cams if "test" in s]
    write(truth, os.path.join(out, "truth.xml"), train + test, a.max_depth)
    relit = ET.fromstring(ET.tostring(truth))
    relight(relit)
    write(relit, os.path.join(out, "relit.xml"), train + test, a.max_depth)
    unknown = ET.fromstring(ET.tostring(truth))
    to_unknown(unknown)
    write(unknown, os.path.join(out, "input.xml"), train, a.max_depth)
    print(f"wrote {os.path.relpath(out, REPO)}/input.xml, truth.xml, relit.xml "
          f"({len(truth.findall('shape'))} shapes)", flush=True)
    render(mi, os.path.join(out, "truth.xml"), os.path.join(out, "images"), "cam_train_",
           a.spp, a.force)
    if not a.no_truth:
        render(mi, os.path.join(out, "truth.xml"), os.path.join(out, "truth"), "cam_test_",
               a.truth_spp, a.force)
        render(mi, os.path.join(out, "relit.xml"), os.path.join(out, "truth"), "cam_test_",
               a.truth_spp, a.force, "_relit")


if __name__ == "__main__":
    main()
