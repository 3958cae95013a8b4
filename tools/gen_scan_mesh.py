#!/usr/bin/env python3
"""Why: a scan-like test scene for timing the unwrap of a mesh without UVs (scanned meshes: no UVs, a million tiny triangles).

Writes into OUT (default cache/scan, which .gitignore ignores):

    scan.ply                a geodesic sphere subdivided to about --triangles triangles, its
                            radius displaced by a few smooth waves plus per-vertex noise (what a
                            scanner leaves): binary PLY, positions only, no normals, no UVs
    input.xml               a Mitsuba 3 scene: the scan, one rectangular area light, one camera
    images/cam.exr          a flat grey photo (float RGB, uncompressed) of the camera's size

The geometry is a pure function of --triangles and --seed. Run:

    .venv/bin/python tools/gen_scan_mesh.py [--triangles 1000000] [--out cache/scan]
    /usr/bin/time -v target/release/kdmap project cache/scan/input.xml --out cache/scan-out
"""

import argparse
import os
import struct

import numpy as np


def icosahedron():
    """The 12 vertices (unit sphere) and 20 outward-facing faces of an icosahedron."""
    t = (1 + 5**0.5) / 2
    v = np.array([[-1, t, 0], [1, t, 0], [-1, -t, 0], [1, -t, 0], [0, -1, t], [0, 1, t],
                  [0, -1, -t], [0, 1, -t], [t, 0, -1], [t, 0, 1], [-t, 0, -1], [-t, 0, 1]], float)
    f = np.array([[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9],
                  [5, 11, 4], [11, 10, 2], [10, 7, 6], [7, 1, 8], [3, 9, 4], [3, 4, 2],
                  [3, 2, 6], [3, 6, 8], [3, 8, 9], [4, 9, 5], [2, 4, 11], [6, 2, 10],
                  [8, 6, 7], [9, 8, 1]])
    return v / np.linalg.norm(v, axis=1, keepdims=True), f


def face_grid(k):
    """Barycentric (i, j) of a face's grid points and its k*k triangles as grid indices."""
    ij = [(i, j) for i in range(k + 1) for j in range(k + 1 - i)]
    at = {p: n for n, p in enumerate(ij)}
    tris = []
    for i in range(k):
        for j in range(k - i):
            tris.append((at[i, j], at[i + 1, j], at[i, j + 1]))
            if i + j < k - 1:
                tris.append((at[i + 1, j], at[i + 1, j + 1], at[i, j + 1]))
    return np.array(ij, float), np.array(tris)


def geodesic_sphere(k):
    """A unit sphere of 20 k^2 triangles: every icosahedron face split k times per edge."""
    v, f = icosahedron()
    ij, tris = face_grid(k)
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    pts = (a[:, None] + ij[None, :, :1] / k * (b - a)[:, None] + ij[None, :, 1:] / k * (c - a)[:, None])
    pts = pts.reshape(-1, 3)
    pts /= np.linalg.norm(pts, axis=1, keepdims=True)
    faces = (tris[None] + (np.arange(len(f)) * len(ij))[:, None, None]).reshape(-1, 3)
    key = np.round(pts * 1e7).astype(np.int64)
    _, first, inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
    return pts[first], inverse.reshape(-1)[faces]


def displace(p, seed):
    """Radius 1 plus smooth waves (8 random directions) and per-vertex scanner noise."""
    rng = np.random.default_rng(seed)
    r = np.ones(len(p))
    for _ in range(8):
        d = rng.normal(size=3)
        r += 0.02 * np.sin(rng.uniform(2, 9) * (p @ (d / np.linalg.norm(d))) + rng.uniform(0, 6.3))
    r += rng.normal(scale=0.0015, size=len(p))
    return p * r[:, None]


def write_ply(path, pos, faces):
    """Binary little-endian PLY: float x y z, uchar/int vertex_indices."""
    head = (f"ply\nformat binary_little_endian 1.0\nelement vertex {len(pos)}\n"
            "property float x\nproperty float y\nproperty float z\n"
            f"element face {len(faces)}\nproperty list uchar int vertex_indices\nend_header\n")
    rec = np.zeros(len(faces), dtype=[("n", "u1"), ("i", "<i4", 3)])
    rec["n"], rec["i"] = 3, faces
    with open(path, "wb") as f:
        f.write(head.encode())
        f.write(pos.astype("<f4").tobytes())
        f.write(rec.tobytes())


def write_exr(path, w, h, value):
    """A flat float RGB OpenEXR, scanlines uncompressed (what any reader takes)."""
    def attr(name, kind, data):
        return name.encode() + b"\0" + kind.encode() + b"\0" + struct.pack("<i", len(data)) + data
    ch = b"".join(c.encode() + b"\0" + struct.pack("<iB3xii", 2, 0, 1, 1) for c in "BGR") + b"\0"
    box = struct.pack("<4i", 0, 0, w - 1, h - 1)
    head = (b"\x76\x2f\x31\x01" + struct.pack("<i", 2) + attr("channels", "chlist", ch)
            + attr("compression", "compression", b"\0") + attr("dataWindow", "box2i", box)
            + attr("displayWindow", "box2i", box) + attr("lineOrder", "lineOrder", b"\0")
            + attr("pixelAspectRatio", "float", struct.pack("<f", 1))
            + attr("screenWindowCenter", "v2f", struct.pack("<2f", 0, 0))
            + attr("screenWindowWidth", "float", struct.pack("<f", 1)) + b"\0")
    line = np.full(3 * w, value, "<f4").tobytes()
    start = len(head) + 8 * h
    size = 8 + len(line)
    table = struct.pack(f"<{h}Q", *(start + y * size for y in range(h)))
    with open(path, "wb") as f:
        f.write(head + table)
        for y in range(h):
            f.write(struct.pack("<ii", y, len(line)) + line)


SCENE = """<scene version="3.0.0">
  <sensor type="perspective" id="cam">
    <float name="fov" value="45"/>
    <transform name="to_world"><lookat origin="0.6, 0.8, 3.2" target="0, 0, 0" up="0, 1, 0"/></transform>
    <film type="hdrfilm"><integer name="width" value="{w}"/><integer name="height" value="{h}"/>
      <rfilter type="box"/></film>
  </sensor>
  <shape type="ply" id="scan"><string name="filename" value="scan.ply"/><bsdf type="diffuse"/></shape>
  <shape type="rectangle" id="light">
    <transform name="to_world"><scale value="0.5"/><rotate x="1" angle="90"/><translate value="0, 2.5, 0"/></transform>
    <emitter type="area"><rgb name="radiance" value="10, 10, 10"/></emitter>
  </shape>
</scene>
"""


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--triangles", type=int, default=1_000_000)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--size", type=int, default=512, help="photo width and height in pixels")
    ap.add_argument("--out", default=os.path.join(os.path.dirname(__file__), "..", "cache", "scan"))
    a = ap.parse_args()
    k = max(1, round((a.triangles / 20) ** 0.5))
    pos, faces = geodesic_sphere(k)
    pos = displace(pos, a.seed)
    os.makedirs(os.path.join(a.out, "images"), exist_ok=True)
    write_ply(os.path.join(a.out, "scan.ply"), pos, faces)
    with open(os.path.join(a.out, "input.xml"), "w") as f:
        f.write(SCENE.format(w=a.size, h=a.size))
    write_exr(os.path.join(a.out, "images", "cam.exr"), a.size, a.size, 0.3)
    print(f"{a.out}: {len(faces)} triangles, {len(pos)} vertices (k = {k})")


if __name__ == "__main__":
    main()
