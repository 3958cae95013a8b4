#!/usr/bin/env python3
"""Make tests/fixtures/gltf-lights: the check of kdmap's glTF light units against Mitsuba 3.

A 4 x 4 diffuse floor (albedo 0.5) lit by a glTF point, spot and directional light, seen by one
camera from above. The glTF file states the lights in photometric units (cd, lux) 100 times
larger than the scene units, and the run config says `[units] photometric_scale = 0.01`.
`twin.xml` is the same scene for Mitsuba in scene units, with the spot cone kdmap derives
from glTF's (beam = inner cone, cutoff of equal power: src/scene/gltf/lights.rs); its render
(box filter, 48 x 32 pixels, half-float EXR) is the photo. A kdmap run on the glTF recovers
0.5 on the floor only if its light units agree with Mitsuba's render
(tests/it/gltf.rs, `gltf_light_units_match_a_mitsuba_render`).

Usage: .venv/bin/python tools/make_gltf_lights_fixture.py [--out tests/fixtures/gltf-lights]
"""
import argparse
import base64
import json
import math
import os

import numpy as np

from exrio import mitsuba

SCALE = 0.01  # scene units per photometric unit, as in run.toml
W, H = 48, 32
YFOV = math.radians(50.0)
CAM = (0.0, 3.0, 0.0)  # looking straight down, image up = -z
POINT = dict(pos=(-1.0, 1.5, 0.3), intensity=(2.0, 1.6, 1.2))
SPOT = dict(pos=(1.0, 2.0, -0.2), intensity=(5.0, 5.0, 6.0), inner=0.35, outer=0.7)
SUN = dict(dir=(0.3, -1.0, 0.2), irradiance=(0.25, 0.3, 0.35))


def gltf_falloff(t, i, o):
    s = 1.0 / max(math.cos(i) - math.cos(o), 1e-3)
    x = min(max((math.cos(t) - math.cos(o)) * s, 0.0), 1.0)
    return x * x


def mitsuba_falloff(t, b, c):
    return 1.0 if t <= b else 0.0 if t >= c else (c - t) / (c - b)


def power(f, o, n=2048):
    h = o / n
    return sum(f((k + 0.5) * h) * math.sin((k + 0.5) * h) * h for k in range(n))


def spot_cutoff(i, o):
    """kdmap's cutoff for a glTF cone (inner, outer): equal power, beam = inner."""
    target = power(lambda t: gltf_falloff(t, i, o), o)
    lo, hi = i, o
    for _ in range(50):
        c = 0.5 * (lo + hi)
        if power(lambda t: mitsuba_falloff(t, i, c), o) < target:
            lo = c
        else:
            hi = c
    return 0.5 * (lo + hi)


def twin_xml():
    cutoff = spot_cutoff(SPOT["inner"], SPOT["outer"])
    rgb = lambda v: ", ".join(f"{x:.9g}" for x in v)
    px, py, pz = SPOT["pos"]
    return f"""<scene version="3.0.0">
  <integrator type="direct"/>
  <sensor type="perspective" id="cam">
    <float name="fov" value="{math.degrees(YFOV):.9g}"/><string name="fov_axis" value="y"/>
    <transform name="to_world"><lookat origin="{rgb(CAM)}" target="0, 0, 0" up="0, 0, -1"/></transform>
    <sampler type="independent"><integer name="sample_count" value="256"/></sampler>
    <film type="hdrfilm"><integer name="width" value="{W}"/><integer name="height" value="{H}"/>
      <string name="pixel_format" value="rgb"/><rfilter type="box"/></film>
  </sensor>
  <shape type="rectangle" id="floor">
    <transform name="to_world"><scale value="2"/><rotate x="1" angle="-90"/></transform>
    <bsdf type="diffuse"><rgb name="reflectance" value="0.5"/></bsdf>
  </shape>
  <emitter type="point"><point name="position" value="{rgb(POINT['pos'])}"/>
    <rgb name="intensity" value="{rgb(POINT['intensity'])}"/></emitter>
  <emitter type="spot">
    <transform name="to_world"><lookat origin="{px}, {py}, {pz}" target="{px}, 0, {pz}" up="0, 0, 1"/></transform>
    <rgb name="intensity" value="{rgb(SPOT['intensity'])}"/>
    <float name="cutoff_angle" value="{math.degrees(cutoff):.9g}"/>
    <float name="beam_width" value="{math.degrees(SPOT['inner']):.9g}"/></emitter>
  <emitter type="directional"><vector name="direction" value="{rgb(SUN['dir'])}"/>
    <rgb name="irradiance" value="{rgb(SUN['irradiance'])}"/></emitter>
</scene>
"""


def light(kind, value, extra=None):
    v = np.array(value) / SCALE
    peak = float(v.max())
    d = {"type": kind, "color": [float(x) for x in v / peak], "intensity": peak}
    d.update(extra or {})
    return d


def look_down_matrix(pos):
    """glTF node matrix (column-major) at `pos` whose -Z points down -y, +Y towards -z."""
    # columns: X = +x, Y = -z, Z = +y (so -Z = -y)
    return [1, 0, 0, 0, 0, 0, -1, 0, 0, 1, 0, 0, *pos, 1]


def along_matrix(d):
    """glTF node matrix whose -Z is unit `d` (a directional light)."""
    z = -np.array(d) / np.linalg.norm(d)
    up = np.array([0.0, 0.0, 1.0])
    x = np.cross(up, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return [*x, 0, *y, 0, *z, 0, 0, 0, 0, 1]


def gltf_doc():
    pos = np.array([[-2, 0, 2], [2, 0, 2], [2, 0, -2], [-2, 0, -2]], dtype=np.float32)
    idx = np.array([0, 1, 2, 0, 2, 3], dtype=np.uint16)
    buf = pos.tobytes() + idx.tobytes()
    return {
        "asset": {"version": "2.0", "generator": "kdmap tools/make_gltf_lights_fixture.py"},
        "extensionsUsed": ["KHR_lights_punctual"],
        "scene": 0,
        "scenes": [{"nodes": [0, 1, 2, 3, 4]}],
        "nodes": [
            {"name": "floor", "mesh": 0},
            {"name": "cam", "camera": 0, "matrix": look_down_matrix(CAM)},
            {"name": "point", "translation": list(POINT["pos"]),
             "extensions": {"KHR_lights_punctual": {"light": 0}}},
            {"name": "spot", "matrix": look_down_matrix(SPOT["pos"]),
             "extensions": {"KHR_lights_punctual": {"light": 1}}},
            {"name": "sun", "matrix": along_matrix(SUN["dir"]),
             "extensions": {"KHR_lights_punctual": {"light": 2}}},
        ],
        "cameras": [{"type": "perspective", "perspective": {"yfov": YFOV, "aspectRatio": W / H, "znear": 0.01}}],
        "extensions": {"KHR_lights_punctual": {"lights": [
            light("point", POINT["intensity"]),
            light("spot", SPOT["intensity"], {"spot": {"innerConeAngle": SPOT["inner"], "outerConeAngle": SPOT["outer"]}}),
            light("directional", SUN["irradiance"]),
        ]}},
        "meshes": [{"name": "floor", "primitives": [{"attributes": {"POSITION": 0}, "indices": 1, "material": 0}]}],
        "materials": [{"name": "floor", "pbrMetallicRoughness": {"baseColorFactor": [0.5, 0.5, 0.5, 1], "metallicFactor": 0}}],
        "buffers": [{"byteLength": len(buf),
                     "uri": "data:application/octet-stream;base64," + base64.b64encode(buf).decode()}],
        "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": 48, "target": 34962},
                        {"buffer": 0, "byteOffset": 48, "byteLength": 12, "target": 34963}],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3", "min": [-2, 0, -2], "max": [2, 0, 2]},
            {"bufferView": 1, "componentType": 5123, "count": 6, "type": "SCALAR"},
        ],
    }


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", default="tests/fixtures/gltf-lights")
    a = ap.parse_args()
    os.makedirs(os.path.join(a.out, "images"), exist_ok=True)
    xml = twin_xml()
    with open(os.path.join(a.out, "twin.xml"), "w") as f:
        f.write(xml)
    with open(os.path.join(a.out, "scene.gltf"), "w") as f:
        json.dump(gltf_doc(), f, indent=1)
        f.write("\n")
    with open(os.path.join(a.out, "run.toml"), "w") as f:
        f.write('# made by tools/make_gltf_lights_fixture.py\nscene = "scene.gltf"\n\n'
                f"[units]\nphotometric_scale = {SCALE}\n")
    mi = mitsuba("scalar_rgb")
    img = mi.render(mi.load_string(xml), spp=256)
    bmp = mi.Bitmap(img).convert(component_format=mi.Struct.Type.Float16)
    bmp.write(os.path.join(a.out, "images", "cam.exr"))
    arr = np.array(img)
    print(f"{a.out}: photo {W}x{H}, mean radiance {arr.mean(axis=(0, 1))}")


if __name__ == "__main__":
    main()
