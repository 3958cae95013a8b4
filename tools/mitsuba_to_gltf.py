#!/usr/bin/env python3
"""Convert a Mitsuba 3 scene (the subset kdmap reads) to glTF 2.0 (.gltf + .bin), the way
kdmap's glTF loader reads it back: the same world-space triangles, UVs and normals, the same
cameras, lights and area emitters, in scene units divided by --photometric-scale.

Mitsuba loads the scene (so OBJ/PLY/rectangle/cube shapes and transforms come out exactly
as Mitsuba sees them); each shape becomes one node named by its id with a world-space mesh.
Conventions (see src/scene/gltf.rs):
  - Mitsuba's sensor frame (+z forward, +x image left) is glTF's camera frame (-Z forward,
    +X right) turned half a turn about y: node matrix = to_world @ diag(-1, 1, -1, 1);
  - yfov = 2 atan(tan(x_fov / 2) / aspect); aspectRatio = film width / height;
  - an area emitter of radiance L becomes emissiveFactor L / max(L) with
    KHR_materials_emissive_strength max(L) / scale, on a black, one-sided material;
  - point and directional lights become KHR_lights_punctual lights (intensity / scale);
    spot lights are refused (their cone is not exposed by Mitsuba's Python API);
  - `twosided` BSDFs become doubleSided materials; a diffuse constant reflectance becomes
    baseColorFactor (kdmap ignores it: the albedo is what it recovers).

Usage:
  .venv/bin/python tools/mitsuba_to_gltf.py tests/fixtures/cbox/input.xml \
      tests/fixtures/cbox-gltf/cbox.gltf [--photometric-scale 1.0]
"""
import argparse
import json
import os
import struct
import sys

import numpy as np
import mitsuba as mi

mi.set_variant("scalar_rgb")

TURN = np.diag([-1.0, 1.0, -1.0, 1.0])


def matrix_of(t):
    """A Mitsuba Transform4f as a numpy 4x4 (row-major)."""
    return np.array(t.matrix, dtype=np.float64).reshape(4, 4)


def col_major(m):
    """A 4x4 as glTF's 16 column-major numbers."""
    return [float(v) for v in np.asarray(m).T.reshape(-1)]


class Bin:
    """The binary buffer and the bufferViews/accessors pointing into it."""

    def __init__(self):
        self.data = bytearray()
        self.views = []
        self.accessors = []

    def add(self, arr, comp, ty, target, bounds=False):
        arr = np.ascontiguousarray(arr)
        while len(self.data) % 4:
            self.data.append(0)
        self.views.append({"buffer": 0, "byteOffset": len(self.data),
                           "byteLength": arr.nbytes, "target": target})
        self.data += arr.tobytes()
        n = {"SCALAR": 1, "VEC2": 2, "VEC3": 3}[ty]
        acc = {"bufferView": len(self.views) - 1, "componentType": comp,
               "count": int(arr.size // n), "type": ty}
        if bounds:
            a = arr.reshape(-1, n)
            acc["min"] = [float(v) for v in a.min(axis=0)]
            acc["max"] = [float(v) for v in a.max(axis=0)]
        self.accessors.append(acc)
        return len(self.accessors) - 1


def rgb_of(params, key):
    v = params.get(key)
    if v is None:
        return None
    return np.array([float(v[0]), float(v[1]), float(v[2])]) if hasattr(v, "__len__") and len(v) == 3 \
        else np.array([float(v)] * 3)


def shape_material(shape, scale):
    """The glTF material of a Mitsuba shape."""
    bsdf = shape.bsdf()
    two = "twosided" in str(bsdf).lower().split("[")[0]
    m = {"name": shape.id(), "doubleSided": bool(two),
         "pbrMetallicRoughness": {"metallicFactor": 0.0, "roughnessFactor": 1.0}}
    params = mi.traverse(bsdf)
    for key in ("reflectance.value", "brdf_0.reflectance.value"):
        c = rgb_of(params, key)
        if c is not None:
            m["pbrMetallicRoughness"]["baseColorFactor"] = [*map(float, c), 1.0]
            break
    if shape.is_emitter():
        radiance = rgb_of(mi.traverse(shape.emitter()), "radiance.value") / scale
        peak = float(radiance.max())
        m["pbrMetallicRoughness"]["baseColorFactor"] = [0.0, 0.0, 0.0, 1.0]
        m["emissiveFactor"] = [float(v) for v in radiance / peak]
        m["extensions"] = {"KHR_materials_emissive_strength": {"emissiveStrength": peak}}
    return m


def convert(src, dst, scale):
    scene = mi.load_file(src, optimize=False)  # no merging of shapes that share a BSDF
    b = Bin()
    nodes, meshes, materials, cameras, lights = [], [], [], [], []
    for shape in scene.shapes():
        if not shape.is_mesh():
            sys.exit(f"{src}: shape '{shape.id()}' is not a mesh")
        p = mi.traverse(shape)
        pos = np.array(p["vertex_positions"], dtype=np.float32)
        faces = np.array(p["faces"], dtype=np.uint32)
        attrs = {"POSITION": b.add(pos, 5126, "VEC3", 34962, bounds=True)}
        if shape.has_vertex_normals():
            attrs["NORMAL"] = b.add(np.array(p["vertex_normals"], dtype=np.float32), 5126, "VEC3", 34962)
        if shape.has_vertex_texcoords():
            # Mitsuba's uv already has v down (its OBJ loader flips), as glTF wants
            attrs["TEXCOORD_0"] = b.add(np.array(p["vertex_texcoords"], dtype=np.float32), 5126, "VEC2", 34962)
        idx = b.add(faces, 5125, "SCALAR", 34963)
        materials.append(shape_material(shape, scale))
        meshes.append({"name": shape.id(), "primitives": [
            {"attributes": attrs, "indices": idx, "material": len(materials) - 1}]})
        nodes.append({"name": shape.id(), "mesh": len(meshes) - 1})
    for sensor in scene.sensors():
        params = mi.traverse(sensor)
        w, h = (int(v) for v in sensor.film().size())
        aspect = w / h
        x_fov = np.radians(float(params["x_fov"][0] if hasattr(params["x_fov"], "__len__") else params["x_fov"]))
        yfov = 2.0 * np.arctan(np.tan(x_fov / 2.0) / aspect)
        cameras.append({"name": sensor.id(), "type": "perspective",
                        "perspective": {"yfov": float(yfov), "aspectRatio": aspect, "znear": 0.01}})
        m = matrix_of(sensor.world_transform()) @ TURN
        nodes.append({"name": sensor.id(), "camera": len(cameras) - 1, "matrix": col_major(m)})
    for e in scene.emitters():
        if mi.has_flag(e.flags(), mi.EmitterFlags.Surface):
            continue
        params = mi.traverse(e)
        kind = type(e).__name__.lower()
        name = str(e).split("[")[0].strip().lower()
        if "point" in name:
            c = rgb_of(params, "intensity.value") / scale
            m = np.eye(4)
            m[:3, 3] = np.array(params["position"]).reshape(-1)[:3]
            light = {"type": "point"}
        elif "directional" in name:
            c = rgb_of(params, "irradiance.value") / scale
            m = matrix_of(params["to_world"]) @ TURN
            light = {"type": "directional"}
        else:
            sys.exit(f"{src}: emitter {name or kind} is not supported by this tool")
        peak = float(c.max())
        light.update({"color": [float(v) for v in c / peak], "intensity": peak})
        lights.append(light)
        nodes.append({"name": f"light_{len(lights) - 1}", "matrix": col_major(m),
                      "extensions": {"KHR_lights_punctual": {"light": len(lights) - 1}}})
    bin_name = os.path.splitext(os.path.basename(dst))[0] + ".bin"
    doc = {
        "asset": {"version": "2.0", "generator": "kdmap tools/mitsuba_to_gltf.py"},
        "scene": 0, "scenes": [{"nodes": list(range(len(nodes)))}],
        "nodes": nodes, "meshes": meshes, "materials": materials,
        "accessors": b.accessors, "bufferViews": b.views,
        "buffers": [{"byteLength": len(b.data), "uri": bin_name}],
        "extensionsUsed": ["KHR_materials_emissive_strength"],
    }
    if cameras:
        doc["cameras"] = cameras
    if lights:
        doc["extensionsUsed"].append("KHR_lights_punctual")
        doc["extensions"] = {"KHR_lights_punctual": {"lights": lights}}
    with open(dst, "w") as f:
        json.dump(doc, f, indent=1)
        f.write("\n")
    with open(os.path.join(os.path.dirname(dst) or ".", bin_name), "wb") as f:
        f.write(bytes(b.data))
    print(f"{dst}: {len(meshes)} meshes, {len(cameras)} cameras, {len(lights)} punctual lights, "
          f"{len(b.data)} bytes of buffer")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("scene")
    ap.add_argument("out", help="the .gltf to write (its .bin goes beside it)")
    ap.add_argument("--photometric-scale", type=float, default=1.0,
                    help="scene units per photometric unit (kdmap's [units] photometric_scale)")
    a = ap.parse_args()
    convert(a.scene, a.out, a.photometric_scale)


if __name__ == "__main__":
    main()
