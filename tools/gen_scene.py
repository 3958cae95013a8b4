#!/usr/bin/env python3
"""Parametric scene generator for kdmap: large, deterministic test scenes rendered by Mitsuba 3.

Why it exists: the scenes shipped in tests/fixtures are small (a Cornell box and an open scene,
a few thousand triangles, 3 views of 256x256). Performance work (atlas size, memory-mapped tile
stores, photon throughput on millions of triangles) and accuracy questions (hard shadow
boundaries, many views, textures seen at several scales) need bigger scenes whose true albedo is
known. This script builds them from a seed: geometry (world-space OBJ meshes with UVs and
normals), procedural sRGB albedo textures (numpy -> PNG), emitters and cameras, and renders the
photos and held-out views with Mitsuba 3's path tracer, in exactly the layout of
tests/fixtures/<scene>/:

    input.xml                 what a kdmap user hands in: meshes with a neutral diffuse 0.5,
                              emitters, training sensors cam_train_*
    images/cam_train_*.exr    the photos (linear RGB, half float), rendered from truth.xml
    truth.xml, textures/      the same scene with the TRUE albedo and all sensors (never an input)
    relit.xml                 same geometry, other lights (emitter shapes dropped), test sensors
    truth/cam_test_*.exr      held-out views under the original light
    truth/cam_test_*_relit.exr  ... and under relit.xml's light
    meshes/<shape id>.obj     world-space meshes (v, vt with v up, vn)
    albedo/cam_train_*.exr    (with --albedo) Mitsuba's albedo AOV through the training cameras
    scene.json                parameters, their hash, triangle counts, texel-relevant sizes, times

Presets: room (furnished closed room, >1M triangles, 16 views of 512x384), room-small (the same
generator tiny, for smoke tests), open (hard shadows: directional + point light on a large
textured ground), open-b (open with another seed and a brick ground), mirror-cbox (Cornell box with a mirror and a glass sphere, tent filter,
focus_distance, referenced BSDFs: refused by kdmap today), envmap (lit only by a procedural sky:
refused by kdmap today). Every preset value can be overridden on the command line; all random
choices come from --seed. Output defaults to cache/scenes/<preset> (git-ignored); a scene already
generated with the same parameters is reused unless --force.

    .venv/bin/python tools/gen_scene.py --preset room-small
    .venv/bin/python tools/gen_scene.py --preset room --spp 128 --albedo
    .venv/bin/python tools/gen_scene.py --preset open /tmp/open --seed 7 --train 8
    .venv/bin/python tools/gen_scene.py --preset room --dry-run     # meshes, textures, XML only

Rendering uses the llvm_ad_rgb variant (needs libLLVM; DRJIT_LIBLLVM_PATH is set here when it is
unset and a libLLVM is found) and falls back to scalar_rgb otherwise.
"""

import argparse
import glob
import hashlib
import json
import math
import os
import platform
import re
import shutil
import struct
import sys
import time
import zlib

import numpy as np

GENERATOR_VERSION = 1
REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DEFAULT_CACHE = os.path.join(REPO, "cache", "scenes")
OUTPUT_SUBDIRS = ("meshes", "textures", "images", "truth", "albedo")
NEUTRAL = (0.5, 0.5, 0.5)
TEXTURE_KINDS = ("checker", "bricks", "wood", "noise", "photo")
OBJECT_KINDS = ("sphere", "torus", "cylinder", "box")
FURNITURE_KINDS = ("table", "chair", "sofa", "shelf", "cabinet")
LIGHT_KINDS = ("area", "point", "spot", "directional")

# ------------------------------------------------------------------------------------------
# Presets. Every key is also a command-line override (see parse_args).

PRESETS = {
    "room": dict(
        layout="room",
        room=(6.0, 3.0, 5.0),
        objects="table:1,chair:2,sofa:1,shelf:1,sphere:4,torus:2,cylinder:2,box:1",
        tris=140000,
        flat_cell=0.5,
        textures="wood,bricks,photo,checker,noise,wood",
        textured_objects=3,
        tiling=1.0,
        texture_res=512,
        train=16,
        test=2,
        res=(512, 384),
        lights="area:1,point:1,spot:1",
        spp=64,
        seed=1,
    ),
    "room-small": dict(
        layout="room",
        room=(6.0, 3.0, 5.0),
        objects="table:1,chair:1,sofa:1,shelf:1,sphere:2,torus:1,cylinder:1,box:1",
        tris=300,
        flat_cell=1.0,
        textures="wood,bricks,photo,checker,noise",
        textured_objects=2,
        tiling=1.0,
        texture_res=128,
        train=4,
        test=2,
        res=(128, 96),
        lights="area:1,point:1,spot:1",
        spp=64,
        seed=1,
    ),
    "open": dict(
        layout="open",
        room=(20.0, 0.0, 20.0),
        objects="sphere:1,box:1,torus:1",
        tris=20000,
        flat_cell=1.0,
        textures="checker,wood,noise,bricks,photo",
        textured_objects=2,
        tiling=1.0,
        texture_res=512,
        train=5,
        test=2,
        res=(256, 256),
        lights="directional:1,point:1",
        spp=1024,
        seed=1,
    ),
    "mirror-cbox": dict(
        layout="mirror-cbox",
        room=(2.0, 2.0, 2.0),
        objects="mirror:1,glass:1",
        tris=8000,
        flat_cell=0.5,
        textures="none",
        textured_objects=0,
        tiling=1.0,
        texture_res=256,
        train=3,
        test=2,
        res=(256, 256),
        lights="area:1",
        spp=512,
        seed=1,
    ),
    "envmap": dict(
        layout="envmap",
        room=(12.0, 0.0, 12.0),
        objects="sphere:1,box:1,cylinder:1,torus:1",
        tris=8000,
        flat_cell=1.0,
        textures="noise,checker,wood",
        textured_objects=1,
        tiling=1.0,
        texture_res=256,
        train=3,
        test=2,
        res=(256, 256),
        lights="envmap:1",
        spp=256,
        seed=1,
    ),
}
# "open" again with another seed and other textures (a brick ground at 256 px): the scene the
# fold into the input UVs (kdmap's output::uv_fold) was checked on, not tuned on
PRESETS["open-b"] = dict(PRESETS["open"], textures="bricks,photo,wood", texture_res=256, seed=7)

# ------------------------------------------------------------------------------------------
# Meshes


class Mesh:
    """A triangle mesh with per-vertex positions, UVs (OBJ convention, v up) and optional
    normals; one index per corner for all three (written as f i/i/i)."""

    def __init__(self, v, uv, n, f):
        self.v = np.asarray(v, np.float64).reshape(-1, 3)
        self.uv = np.asarray(uv, np.float64).reshape(-1, 2)
        self.n = None if n is None else np.asarray(n, np.float64).reshape(-1, 3)
        self.f = np.asarray(f, np.int64).reshape(-1, 3)

    @staticmethod
    def merge(meshes):
        meshes = [m for m in meshes if m is not None and len(m.f)]
        off = np.cumsum([0] + [len(m.v) for m in meshes[:-1]])
        has_n = all(m.n is not None for m in meshes)
        return Mesh(
            np.concatenate([m.v for m in meshes]),
            np.concatenate([m.uv for m in meshes]),
            np.concatenate([m.n for m in meshes]) if has_n else None,
            np.concatenate([m.f + o for m, o in zip(meshes, off)]),
        )

    def transformed(self, rot=None, shift=(0, 0, 0)):
        r = np.eye(3) if rot is None else np.asarray(rot, np.float64)
        n = None if self.n is None else self.n @ r.T
        return Mesh(self.v @ r.T + np.asarray(shift, np.float64), self.uv, n, self.f)

    def tri_areas(self, uv=False):
        p = self.uv if uv else self.v
        a, b, c = p[self.f[:, 0]], p[self.f[:, 1]], p[self.f[:, 2]]
        if uv:
            e1, e2 = b - a, c - a
            return 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
        return 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)

    def area(self):
        return float(self.tri_areas().sum())

    def bbox(self):
        return self.v.min(0), self.v.max(0)

    def orient_to_normals(self):
        """Flip triangles whose winding disagrees with their vertex normals (outward, CCW)."""
        if self.n is None:
            return self
        a, b, c = self.v[self.f[:, 0]], self.v[self.f[:, 1]], self.v[self.f[:, 2]]
        g = np.cross(b - a, c - a)
        ns = self.n[self.f].sum(1)
        bad = (g * ns).sum(1) < 0
        self.f[bad] = self.f[bad][:, [0, 2, 1]]
        return self


def grid_quad(origin, eu, ev, nu, nv, uv0=(0.0, 0.0), uv1=(1.0, 1.0)):
    """A planar grid of nu x nv cells spanning origin + s eu + t ev; normal cross(eu, ev)."""
    origin, eu, ev = (np.asarray(x, np.float64) for x in (origin, eu, ev))
    nu, nv = max(1, int(nu)), max(1, int(nv))
    s, t = np.meshgrid(np.linspace(0, 1, nu + 1), np.linspace(0, 1, nv + 1), indexing="xy")
    s, t = s.ravel(), t.ravel()
    v = origin + s[:, None] * eu + t[:, None] * ev
    uv = np.stack([uv0[0] + s * (uv1[0] - uv0[0]), uv0[1] + t * (uv1[1] - uv0[1])], 1)
    nrm = np.cross(eu, ev)
    nrm = nrm / np.linalg.norm(nrm)
    j, i = np.meshgrid(np.arange(nv), np.arange(nu), indexing="ij")
    i00 = (j * (nu + 1) + i).ravel()
    i10, i01, i11 = i00 + 1, i00 + nu + 1, i00 + nu + 2
    f = np.concatenate([np.stack([i00, i10, i11], 1), np.stack([i00, i11, i01], 1)])
    return Mesh(v, uv, np.tile(nrm, (len(v), 1)), f)


def _cells(length, cell):
    return max(1, int(math.ceil(length / cell - 1e-9)))


def box(lo, hi, cell=1e9, period=1.0, skip=()):
    """Axis-aligned box [lo, hi] with flat faces (own vertices per face), each face a grid of
    cells of at most `cell`; UVs in metres / `period` (texture repeats). `skip`: faces to omit
    ('+x', '-x', '+y', '-y', '+z', '-z'), e.g. hidden faces resting on a support."""
    (x0, y0, z0), (x1, y1, z1) = lo, hi
    dx, dy, dz = x1 - x0, y1 - y0, z1 - z0
    faces = {
        "+x": ((x1, y0, z1), (0, 0, -dz), (0, dy, 0)),
        "-x": ((x0, y0, z0), (0, 0, dz), (0, dy, 0)),
        "+z": ((x0, y0, z1), (dx, 0, 0), (0, dy, 0)),
        "-z": ((x1, y0, z0), (-dx, 0, 0), (0, dy, 0)),
        "+y": ((x0, y1, z1), (dx, 0, 0), (0, 0, -dz)),
        "-y": ((x0, y0, z0), (dx, 0, 0), (0, 0, dz)),
    }
    out = []
    for name, (o, eu, ev) in faces.items():
        if name in skip:
            continue
        lu, lv = np.linalg.norm(eu), np.linalg.norm(ev)
        out.append(
            grid_quad(o, eu, ev, _cells(lu, cell), _cells(lv, cell), (0, 0), (lu / period, lv / period))
        )
    return Mesh.merge(out)


def uv_sphere(center, radius, tris, uv_rep=(1.0, 1.0)):
    """UV sphere of about `tris` triangles (2 nu (nv - 1)), smooth normals, seam and pole
    vertices duplicated so the UVs (u = longitude, v = latitude, v up) are continuous."""
    m = max(2, int(round(math.sqrt(max(tris, 16) / 4.0))))
    nv, nu = m + 1, 2 * m
    th = np.pi * np.arange(1, nv) / nv  # ring latitudes (nv - 1 rings)
    ph = 2 * np.pi * np.arange(nu + 1) / nu
    T, P = np.meshgrid(th, ph, indexing="ij")
    d = np.stack([np.sin(T) * np.cos(P), np.cos(T), np.sin(T) * np.sin(P)], -1).reshape(-1, 3)
    uv = np.stack([(P / (2 * np.pi)).ravel(), (1 - T / np.pi).ravel()], 1)
    nring = nv - 1
    ring = lambda j, i: j * (nu + 1) + i  # noqa: E731
    base = len(d)
    ip = np.arange(nu)
    top = np.stack([np.zeros(nu), np.ones(nu), np.zeros(nu)], 1)
    bot = -top
    uv_top = np.stack([(ip + 0.5) / nu, np.ones(nu)], 1)
    uv_bot = np.stack([(ip + 0.5) / nu, np.zeros(nu)], 1)
    d = np.concatenate([d, top, bot])
    uv = np.concatenate([uv, uv_top, uv_bot])
    faces = [np.stack([base + ip, ring(0, ip + 1), ring(0, ip)], 1)]
    faces.append(np.stack([base + nu + ip, ring(nring - 1, ip), ring(nring - 1, ip + 1)], 1))
    if nring > 1:
        J, I = np.meshgrid(np.arange(nring - 1), ip, indexing="ij")
        a, b = ring(J, I).ravel(), ring(J, I + 1).ravel()
        c, e = ring(J + 1, I).ravel(), ring(J + 1, I + 1).ravel()
        faces += [np.stack([a, b, e], 1), np.stack([a, e, c], 1)]
    uv = uv * np.asarray(uv_rep, np.float64)
    m = Mesh(np.asarray(center) + radius * d, uv, d, np.concatenate(faces))
    return m.orient_to_normals()


def torus(center, R, r, tris, rot=None, uv_rep=(1.0, 1.0)):
    """Torus around the local y axis (lying flat), ring radius R, tube radius r, about `tris`
    triangles (2 nu nv), smooth normals; `rot` turns it (e.g. standing upright)."""
    k = min(4.0, max(1.0, R / r))
    nv = max(3, int(round(math.sqrt(max(tris, 18) / (2 * k)))))
    nu = max(3, int(round(max(tris, 18) / (2 * nv))))
    ph = 2 * np.pi * np.arange(nu + 1) / nu
    ps = 2 * np.pi * np.arange(nv + 1) / nv
    P, S = np.meshgrid(ph, ps, indexing="ij")
    radial = np.stack([np.cos(P), np.zeros_like(P), np.sin(P)], -1)
    up = np.array([0.0, 1.0, 0.0])
    n = np.cos(S)[..., None] * radial + np.sin(S)[..., None] * up
    v = R * radial + r * n
    uv = np.stack([(P / (2 * np.pi)).ravel(), (S / (2 * np.pi)).ravel()], 1) * np.asarray(uv_rep)
    I, J = np.meshgrid(np.arange(nu), np.arange(nv), indexing="ij")
    idx = lambda i, j: i * (nv + 1) + j  # noqa: E731
    a, b = idx(I, J).ravel(), idx(I + 1, J).ravel()
    c, e = idx(I, J + 1).ravel(), idx(I + 1, J + 1).ravel()
    f = np.concatenate([np.stack([a, b, e], 1), np.stack([a, e, c], 1)])
    m = Mesh(v.reshape(-1, 3), uv, n.reshape(-1, 3), f).orient_to_normals()
    return m.transformed(rot, center)


def cylinder(bottom, radius, height, tris, caps=("top",), uv_rep=(1.0, 1.0)):
    """Upright cylinder: smooth side (u = angle, v = height) and flat caps (planar UVs) made of
    rings; about `tris` triangles. `caps` lists 'top' and/or 'bottom' (a cap resting on a
    support is hidden, so omitted by default)."""
    tris = max(tris, 24)
    ncap = len(caps)
    nu = max(6, int(round(math.sqrt(tris / 2.5))))
    nr = max(1, nu // 8) if ncap else 0
    side_tris = max(2 * nu, tris - ncap * nu * (2 * nr - 1))
    nh = max(1, int(round(side_tris / (2 * nu))))
    ph = 2 * np.pi * np.arange(nu + 1) / nu
    hs = np.linspace(0, 1, nh + 1)
    H, P = np.meshgrid(hs, ph, indexing="ij")
    radial = np.stack([np.cos(P), np.zeros_like(P), np.sin(P)], -1)
    v = radius * radial + (H * height)[..., None] * np.array([0, 1.0, 0])
    uv = np.stack([(P / (2 * np.pi)).ravel(), H.ravel()], 1) * np.asarray(uv_rep)
    J, I = np.meshgrid(np.arange(nh), np.arange(nu), indexing="ij")
    idx = lambda j, i: j * (nu + 1) + i  # noqa: E731
    a, b = idx(J, I).ravel(), idx(J, I + 1).ravel()
    c, e = idx(J + 1, I).ravel(), idx(J + 1, I + 1).ravel()
    side = Mesh(v.reshape(-1, 3), uv, radial.reshape(-1, 3), np.concatenate(
        [np.stack([a, b, e], 1), np.stack([a, e, c], 1)])).orient_to_normals()
    parts = [side]
    for cap in caps:
        y, ny = (height, 1.0) if cap == "top" else (0.0, -1.0)
        phc = 2 * np.pi * np.arange(nu) / nu
        rr = radius * np.arange(1, nr + 1) / nr
        RR, PP = np.meshgrid(rr, phc, indexing="ij")
        pts = np.stack([RR * np.cos(PP), np.full_like(RR, y), RR * np.sin(PP)], -1).reshape(-1, 3)
        pts = np.concatenate([[[0.0, y, 0.0]], pts])
        cuv = 0.5 + pts[:, [0, 2]] / (2 * radius) * np.array([1.0, -ny])
        ridx = lambda k, i: 1 + k * nu + (i % nu)  # noqa: E731
        ip = np.arange(nu)
        fs = [np.stack([np.zeros(nu, np.int64), ridx(0, ip), ridx(0, ip + 1)], 1)]
        if nr > 1:
            K, I2 = np.meshgrid(np.arange(nr - 1), ip, indexing="ij")
            a2, b2 = ridx(K, I2).ravel(), ridx(K, I2 + 1).ravel()
            c2, e2 = ridx(K + 1, I2).ravel(), ridx(K + 1, I2 + 1).ravel()
            fs += [np.stack([a2, b2, e2], 1), np.stack([a2, e2, c2], 1)]
        nrm = np.tile([0.0, ny, 0.0], (len(pts), 1))
        parts.append(Mesh(pts, cuv * np.asarray(uv_rep), nrm, np.concatenate(fs)).orient_to_normals())
    return Mesh.merge(parts).transformed(None, bottom)


def rot_y(deg):
    a = math.radians(deg)
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def rot_x(deg):
    a = math.radians(deg)
    c, s = math.cos(a), math.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def write_obj(path, mesh, header):
    """World-space OBJ: v, vt (v up), vn when the mesh has normals, f v/vt[/vn] (1-based)."""
    with open(path, "w") as fh:
        fh.write(f"# {header}\n# {len(mesh.v)} vertices, {len(mesh.f)} triangles\n")
        for fmt, arr in (("v %.6f %.6f %.6f\n", mesh.v), ("vt %.6f %.6f\n", mesh.uv),
                         ("vn %.6f %.6f %.6f\n", mesh.n)):
            if arr is None:
                continue
            for s in range(0, len(arr), 200000):
                ch = arr[s:s + 200000]
                fh.write((fmt * len(ch)) % tuple(np.round(ch, 6).ravel().tolist()))
        f = mesh.f + 1
        fmt = "f %d/%d/%d %d/%d/%d %d/%d/%d\n" if mesh.n is not None else "f %d/%d %d/%d %d/%d\n"
        rep = 3 if mesh.n is not None else 2
        for s in range(0, len(f), 200000):
            ch = np.repeat(f[s:s + 200000], rep, axis=1)
            fh.write((fmt * len(ch)) % tuple(ch.ravel().tolist()))


# ------------------------------------------------------------------------------------------
# Procedural textures (linear albedo in [0, 1], written as sRGB PNGs). All tile seamlessly.


def periodic_noise(rng, n, cells, octaves=4, persistence=0.5):
    """Fractal value noise on an n x n periodic grid, in [0, 1]."""
    out = np.zeros((n, n))
    amp, total = 1.0, 0.0
    for o in range(octaves):
        c = cells * 2 ** o
        if c > n:
            break
        lat = rng.random((c, c))
        x = np.arange(n) * c / n
        i0 = np.floor(x).astype(int)
        t = x - i0
        t = t * t * (3 - 2 * t)
        i1 = (i0 + 1) % c
        a = lat[np.ix_(i0, i0)] * (1 - t)[None, :] + lat[np.ix_(i0, i1)] * t[None, :]
        b = lat[np.ix_(i1, i0)] * (1 - t)[None, :] + lat[np.ix_(i1, i1)] * t[None, :]
        out += amp * (a * (1 - t)[:, None] + b * t[:, None])
        total += amp
        amp *= persistence
    return out / total


def _rand_colour(rng, lo=0.1, hi=0.8):
    return rng.uniform(lo, hi, 3)


def tex_checker(rng, n):
    k = int(rng.choice([4, 6, 8]))
    c1, c2 = _rand_colour(rng, 0.5, 0.85), _rand_colour(rng, 0.05, 0.3)
    y, x = np.mgrid[0:n, 0:n]
    m = ((x * k // n + y * k // n) % 2).astype(bool)
    return np.where(m[..., None], c1, c2)


def tex_bricks(rng, n):
    rows, cols = 8, 4
    mortar = np.array([0.62, 0.6, 0.56])
    base = np.array([0.45, 0.16, 0.09]) * rng.uniform(0.8, 1.2, 3)
    y, x = np.mgrid[0:n, 0:n] / n
    row = np.floor(y * rows).astype(int)
    xs = x * cols + 0.5 * (row % 2)
    col = np.floor(xs).astype(int) % cols
    fy, fx = y * rows - row, xs - np.floor(xs)
    gap_y, gap_x = 0.08, 0.08 / 2
    is_mortar = (fy < gap_y) | (fx < gap_x)
    tint = rng.uniform(0.7, 1.25, (rows, cols))[row % rows, col]
    grain = 0.85 + 0.3 * periodic_noise(rng, n, 16, 3)
    brick = np.clip(base[None, None, :] * (tint * grain)[..., None], 0, 0.9)
    return np.where(is_mortar[..., None], mortar * (0.9 + 0.2 * grain[..., None] - 0.1), brick)


def tex_wood(rng, n):
    """Wood-like stripes: planks, each with its own tint and offset, of fine grain lines
    running along them, gently warped by noise."""
    planks = int(rng.choice([4, 6, 8]))
    light = np.array([0.6, 0.4, 0.22]) * rng.uniform(0.85, 1.15)
    dark = np.array([0.3, 0.16, 0.07]) * rng.uniform(0.85, 1.15)
    y, x = np.mgrid[0:n, 0:n] / n
    warp = periodic_noise(rng, n, 4, 3)
    plank = np.floor(y * planks).astype(int)
    fy = y * planks - plank
    t = fy * 7 + 0.8 * warp + 0.35 * np.sin(2 * np.pi * x) + rng.random(planks)[plank]
    g = (0.5 + 0.5 * np.sin(2 * np.pi * t)) ** 3
    tint = rng.uniform(0.8, 1.2, planks)[plank]
    fine = periodic_noise(rng, n, 64, 2)
    c = light * (1 - g[..., None]) + dark * g[..., None]
    c = c * (tint * (0.9 + 0.2 * fine))[..., None]
    seam = fy < 0.025
    return np.where(seam[..., None], dark * 0.6, c)


def tex_noise(rng, n):
    """Stone/fabric-like fractal noise through a 3-colour ramp."""
    v = periodic_noise(rng, n, int(rng.choice([4, 8])), 5, 0.55)
    v = (v - v.min()) / max(1e-9, v.max() - v.min())
    c0, c1, c2 = _rand_colour(rng, 0.05, 0.3), _rand_colour(rng, 0.3, 0.6), _rand_colour(rng, 0.55, 0.85)
    a = np.clip(v * 2, 0, 1)[..., None]
    b = np.clip(v * 2 - 1, 0, 1)[..., None]
    return np.where(v[..., None] < 0.5, c0 * (1 - a) + c1 * a, c1 * (1 - b) + c2 * b)


def tex_photo(rng, n):
    """A smooth, photo-like picture: a soft vertical gradient (sky-ish above, earthy below)
    with a dozen blurred coloured blobs, all periodic."""
    y, x = np.mgrid[0:n, 0:n] / n
    top, bottom = _rand_colour(rng, 0.35, 0.75), _rand_colour(rng, 0.08, 0.4)
    g = 0.5 - 0.5 * np.cos(2 * np.pi * y)  # 0 at the edges, 1 in the middle: tiles
    img = top * (1 - g[..., None]) + bottom * g[..., None]
    for _ in range(12):
        cx, cy = rng.random(2)
        sx, sy = rng.uniform(0.04, 0.16, 2)
        dx = (x - cx + 0.5) % 1 - 0.5
        dy = (y - cy + 0.5) % 1 - 0.5
        w = np.exp(-(dx * dx / (2 * sx * sx) + dy * dy / (2 * sy * sy)))[..., None]
        img = img * (1 - 0.8 * w) + 0.8 * w * _rand_colour(rng, 0.05, 0.8)
    return img


TEXTURE_FUNCS = dict(checker=tex_checker, bricks=tex_bricks, wood=tex_wood, noise=tex_noise, photo=tex_photo)


def linear_to_srgb8(a):
    a = np.clip(a, 0.0, 1.0)
    s = np.where(a <= 0.0031308, 12.92 * a, 1.055 * np.power(a, 1 / 2.4) - 0.055)
    return np.clip(np.round(s * 255), 0, 255).astype(np.uint8)


def write_png(path, rgb8):
    """8-bit RGB PNG (sRGB chunk), written with zlib only."""
    h, w, _ = rgb8.shape
    raw = b"".join(b"\x00" + rgb8[y].tobytes() for y in range(h))

    def chunk(t, d):
        return struct.pack(">I", len(d)) + t + d + struct.pack(">I", zlib.crc32(t + d) & 0xFFFFFFFF)

    data = (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0))
            + chunk(b"sRGB", b"\x00") + chunk(b"IDAT", zlib.compress(raw, 6)) + chunk(b"IEND", b""))
    with open(path, "wb") as fh:
        fh.write(data)


def make_sky(n_w=1024, sun_dir=(0.45, 0.55, -0.7), seed=0):
    """Lat-long sky in Mitsuba's envmap convention (row 0 = +y, u = azimuth): a gradient sky
    (bright horizon, deeper zenith), a dim ground below the horizon and a small bright sun disc
    with a glow. Linear RGB float32 (h, w, 3)."""
    rng = np.random.default_rng(seed)
    h = n_w // 2
    v, u = (np.mgrid[0:h, 0:n_w] + 0.5) / np.array([h, n_w])[:, None, None]
    theta, phi = v * np.pi, u * 2 * np.pi
    d = np.stack([np.sin(phi) * np.sin(theta), np.cos(theta), -np.cos(phi) * np.sin(theta)], -1)
    elev = d[..., 1]
    zen = np.array([0.18, 0.32, 0.75])
    hor = np.array([0.75, 0.82, 0.95])
    t = np.clip(elev, 0, 1)[..., None] ** 0.5
    sky = hor * (1 - t) + zen * t
    ground = np.array([0.12, 0.1, 0.08]) * (1 + 0.3 * np.clip(-elev, 0, 1))[..., None]
    img = np.where(elev[..., None] >= 0, sky, ground)
    img *= (0.95 + 0.1 * periodic_noise(rng, n_w, 8, 3)[:h, :])[..., None]
    s = np.asarray(sun_dir, np.float64)
    s /= np.linalg.norm(s)
    cosang = np.clip((d * s).sum(-1), -1, 1)
    ang = np.degrees(np.arccos(cosang))
    sun_radius = 2.5
    img += (ang < sun_radius)[..., None] * np.array([900.0, 820.0, 700.0])
    img += np.exp(-(ang / 12.0) ** 2)[..., None] * np.array([2.5, 2.0, 1.4])
    return img.astype(np.float32)


# ------------------------------------------------------------------------------------------
# Scene description


class Shape:
    def __init__(self, sid, mesh, kind, albedo=None, texture=None, twosided=False,
                 emitter=None, truth_ref=None, input_ref=None):
        self.id, self.mesh, self.kind = sid, mesh, kind
        self.albedo = albedo  # constant linear RGB, or None if textured / known material
        self.texture = texture  # dict(file, kind, res) or None
        self.twosided = twosided
        self.emitter = emitter  # area radiance (rgb) or None
        # ids of top-level bsdfs referenced with <ref> in truth/relit and in input (mirror-cbox)
        self.truth_ref, self.input_ref = truth_ref, input_ref


def safe_up(origin, target):
    """+y, or +x when the view direction is (nearly) vertical, for a lookat transform."""
    d = np.asarray(target, np.float64) - np.asarray(origin, np.float64)
    d /= max(np.linalg.norm(d), 1e-12)
    return (1.0, 0.0, 0.0) if abs(d[1]) > 0.98 else (0.0, 1.0, 0.0)


class Sensor:
    def __init__(self, sid, origin, target, fov, res):
        self.id = sid
        self.origin = np.asarray(origin, np.float64)
        self.target = np.asarray(target, np.float64)
        self.up = np.asarray(safe_up(origin, target), np.float64)
        self.fov, self.res = float(fov), tuple(res)


def fmt3(v):
    return ", ".join(_num(x) for x in v)


def _num(x):
    s = f"{float(x):.4f}".rstrip("0").rstrip(".")
    return "0" if s in ("-0", "") else s


def rgb_xml(name, c):
    return f'<rgb name="{name}" value="{fmt3(c)}"/>'


class SceneSpec:
    def __init__(self, params):
        self.p = params
        self.shapes = []
        self.emitters = []  # dicts
        self.relit_emitters = []
        self.train, self.test = [], []
        self.top_bsdfs = []  # (xml, 'truth' | 'input' | 'both') declared before the shapes
        self.textures = {}  # file -> float array (linear albedo) or ('exr', array)
        self.rfilter = "box"
        self.focus_distance = False

    # ---- XML ----
    def sensor_xml(self, s):
        w, h = s.res
        extra = ""
        if self.focus_distance:
            extra = f'\n    <float name="focus_distance" value="{_num(np.linalg.norm(s.target - s.origin))}"/>'
        return (
            f'  <sensor type="perspective" id="{s.id}">\n'
            f'    <float name="fov" value="{_num(s.fov)}"/>\n'
            f'    <string name="fov_axis" value="x"/>{extra}\n'
            f'    <transform name="to_world"><lookat origin="{fmt3(s.origin)}" target="{fmt3(s.target)}" up="{fmt3(s.up)}"/></transform>\n'
            f'    <sampler type="independent"><integer name="sample_count" value="{self.p["spp"]}"/></sampler>\n'
            f'    <film type="hdrfilm"><integer name="width" value="{w}"/><integer name="height" value="{h}"/>\n'
            f'      <string name="pixel_format" value="rgb"/><rfilter type="{self.rfilter}"/></film>\n'
            f"  </sensor>\n"
        )

    def bsdf_xml(self, sh, which):
        ref = sh.input_ref if which == "input" else sh.truth_ref
        if ref is not None:
            return f'<ref id="{ref}"/>'
        if sh.emitter is not None:
            inner = f'<bsdf type="diffuse">{rgb_xml("reflectance", (0, 0, 0))}</bsdf>'
        elif which == "input":
            inner = f'<bsdf type="diffuse">{rgb_xml("reflectance", NEUTRAL)}</bsdf>'
        elif sh.texture is not None:
            inner = ('<bsdf type="diffuse"><texture type="bitmap" name="reflectance">'
                     f'<string name="filename" value="{sh.texture["file"]}"/></texture></bsdf>')
        else:
            inner = f'<bsdf type="diffuse">{rgb_xml("reflectance", sh.albedo)}</bsdf>'
        if sh.twosided:
            return f'<bsdf type="twosided">{inner}</bsdf>'
        return inner

    @staticmethod
    def emitter_xml(e):
        k = e["type"]
        if k == "point":
            x, y, z = e["position"]
            return (f'  <emitter type="point"><point name="position" x="{_num(x)}" y="{_num(y)}" z="{_num(z)}"/>'
                    f'{rgb_xml("intensity", e["intensity"])}</emitter>\n')
        if k == "spot":
            return (f'  <emitter type="spot"><transform name="to_world"><lookat origin="{fmt3(e["origin"])}" '
                    f'target="{fmt3(e["target"])}" up="{fmt3(e["up"])}"/></transform>{rgb_xml("intensity", e["intensity"])}'
                    f'<float name="cutoff_angle" value="{_num(e["cutoff"])}"/>'
                    f'<float name="beam_width" value="{_num(e["beam"])}"/></emitter>\n')
        if k == "directional":
            x, y, z = e["direction"]
            return (f'  <emitter type="directional"><vector name="direction" x="{_num(x)}" y="{_num(y)}" z="{_num(z)}"/>'
                    f'{rgb_xml("irradiance", e["irradiance"])}</emitter>\n')
        if k == "envmap":
            return (f'  <emitter type="envmap"><string name="filename" value="{e["file"]}"/>'
                    f'<float name="scale" value="{_num(e["scale"])}"/>'
                    f'<transform name="to_world"><rotate y="1" angle="{_num(e["rotate_y"])}"/></transform></emitter>\n')
        raise ValueError(k)

    def xml(self, which):
        """which: 'input' (neutral albedo, training sensors), 'truth' (true albedo, all
        sensors), 'relit' (true albedo, relit emitters, no emitter shapes, test sensors)."""
        out = ['<scene version="3.0.0">\n',
               '  <integrator type="path"><integer name="max_depth" value="-1"/>'
               '<integer name="rr_depth" value="8"/></integrator>\n']
        sensors = {"input": self.train, "truth": self.train + self.test, "relit": self.test}[which]
        for s in sensors:
            out.append(self.sensor_xml(s) + "\n")
        for x, where in self.top_bsdfs:
            if where == "both" or (where == "input") == (which == "input"):
                out.append(f"  {x}\n")
        for sh in self.shapes:
            if which == "relit" and sh.emitter is not None:
                continue
            em = ""
            if sh.emitter is not None:
                em = f'<emitter type="area">{rgb_xml("radiance", sh.emitter)}</emitter>'
            out.append(f'  <shape type="obj" id="{sh.id}"><string name="filename" value="meshes/{sh.id}.obj"/>'
                       f"{self.bsdf_xml(sh, which)}{em}</shape>\n")
        for e in self.relit_emitters if which == "relit" else self.emitters:
            out.append(self.emitter_xml(e))
        out.append("</scene>\n")
        return "".join(out)


# ------------------------------------------------------------------------------------------
# Layout helpers


def parse_counts(spec, allowed):
    out = []
    if not spec or spec.strip().lower() == "none":
        return out
    for item in spec.split(","):
        item = item.strip()
        if not item:
            continue
        name, _, cnt = item.partition(":")
        name = name.strip()
        if name not in allowed:
            raise SystemExit(f"unknown kind '{name}' in '{spec}' (allowed: {', '.join(allowed)})")
        out += [name] * (int(cnt) if cnt else 1)
    return out


def rect_overlap(a, b, pad=0.0):
    return not (a[1] + pad <= b[0] or b[1] + pad <= a[0] or a[3] + pad <= b[2] or b[3] + pad <= a[2])


def seg_hits_box(p0, p1, lo, hi):
    """Whether the segment p0 -> p1 passes through the axis-aligned box [lo, hi]."""
    d = p1 - p0
    t0, t1 = 0.0, 1.0
    for k in range(3):
        if abs(d[k]) < 1e-12:
            if p0[k] < lo[k] or p0[k] > hi[k]:
                return False
            continue
        a, b = (lo[k] - p0[k]) / d[k], (hi[k] - p0[k]) / d[k]
        a, b = min(a, b), max(a, b)
        t0, t1 = max(t0, a), min(t1, b)
        if t0 > t1:
            return False
    return True


class Builder:
    """Builds a SceneSpec from parameters; all randomness from one seeded generator (and
    per-texture sub-generators, so a texture does not change when another object is added)."""

    def __init__(self, p):
        self.p = p
        self.rng = np.random.default_rng(p["seed"])
        self.s = SceneSpec(p)
        self.tex_pool = [t for t in p["textures"].split(",") if t and t != "none"]
        for t in self.tex_pool:
            if t not in TEXTURE_FUNCS:
                raise SystemExit(f"unknown texture '{t}' (allowed: {', '.join(TEXTURE_FUNCS)})")
        self.tex_count = 0
        self.obstacles = []  # (id, lo, hi) boxes cameras must not enter / see through
        self.target_box = None  # camera targets are clipped into it (a room's inside)

    def texture(self, sid, kind=None):
        if kind is None:
            kind = self.tex_pool[self.tex_count % len(self.tex_pool)]
        self.tex_count += 1
        res = int(self.p["texture_res"])
        sub = np.random.default_rng([self.p["seed"], 7919, len(self.s.textures)])
        img = TEXTURE_FUNCS[kind](sub, res)
        img = np.clip(img, 0.02, 0.9)
        f = f"textures/{sid}.png"
        self.s.textures[f] = img
        return dict(file=f, kind=kind, res=res)

    def add(self, sh, obstacle=True):
        self.s.shapes.append(sh)
        if obstacle:
            lo, hi = sh.mesh.bbox()
            self.obstacles.append((sh.id, lo, hi))
        return sh

    def colour(self, lo=0.1, hi=0.8):
        return tuple(float(x) for x in np.round(self.rng.uniform(lo, hi, 3), 3))

    # ---- objects (props) ----
    def make_prop(self, kind, idx, support, textured):
        """A prop of `kind` standing on `support` (dict x0 x1 z0 z1 y hmax size), placed without
        overlapping `self.placed` footprints. Returns a Shape or None."""
        p, rng = self.p, self.rng
        big = support["size"] == "large"
        for _ in range(200):
            if kind == "sphere":
                r = rng.uniform(0.25, 0.5) if big else rng.uniform(0.07, 0.16)
                foot, hgt = r, 2 * r
            elif kind == "torus":
                R = rng.uniform(0.3, 0.55) if big else rng.uniform(0.08, 0.16)
                r = R * rng.uniform(0.25, 0.4)
                upright = big and support.get("upright_tori", False)
                foot, hgt = R + r, (2 * (R + r) if upright else 2 * r)
            elif kind == "cylinder":
                r = rng.uniform(0.15, 0.35) if big else rng.uniform(0.04, 0.1)
                hgt = rng.uniform(0.4, 1.0) if big else rng.uniform(0.1, 0.35)
                foot = r
            else:  # box
                sx, sz = (rng.uniform(0.4, 1.0, 2) if big else rng.uniform(0.08, 0.25, 2))
                hgt = rng.uniform(0.3, 0.9) if big else rng.uniform(0.08, 0.25)
                foot = 0.5 * math.hypot(sx, sz)
            if hgt > support["hmax"]:
                continue
            x0, x1 = support["x0"] + foot, support["x1"] - foot
            z0, z1 = support["z0"] + foot, support["z1"] - foot
            if x0 > x1 or z0 > z1:
                continue
            x, z = rng.uniform(x0, x1), rng.uniform(z0, z1)
            fp = (x - foot, x + foot, z - foot, z + foot)
            if any(rect_overlap(fp, q, 0.03) for q in self.placed):
                continue
            y = support["y"]
            sid = f"{kind}_{idx}"
            tris = int(p["tris"])
            uvr = (p["tiling"], p["tiling"])
            if kind == "sphere":
                mesh = uv_sphere((x, y + r, z), r, tris, (2 * p["tiling"], p["tiling"]))
            elif kind == "torus":
                if upright:
                    rot = rot_y(rng.uniform(0, 180)) @ rot_x(90)
                    mesh = torus((x, y + R + r, z), R, r, tris, rot, (3 * p["tiling"], p["tiling"]))
                else:
                    mesh = torus((x, y + r, z), R, r, tris, None, (3 * p["tiling"], p["tiling"]))
            elif kind == "cylinder":
                mesh = cylinder((x, y, z), r, hgt, tris, ("top",), uvr)
            else:
                ang = rng.uniform(0, 90)
                b = box((-sx / 2, 0, -sz / 2), (sx / 2, hgt, sz / 2), p["flat_cell"],
                        max(sx, sz, hgt) / p["tiling"], skip=("-y",))
                mesh = b.transformed(rot_y(ang), (x, y, z))  # footprint: the half diagonal
            self.placed.append(fp)
            tex = self.texture(sid) if textured and self.tex_pool else None
            return Shape(sid, mesh, kind, None if tex else self.colour(), tex)
        return None

    # ---- cameras ----
    def place_cameras(self, n, prefix, candidates_fn, interest, res, fov_range, seed_off, used=None):
        """n cameras, each aimed at one point of `interest` ((id, point) list; objects first,
        then the room's walls and floor, each group shuffled) from a position drawn by
        candidates_fn, outside every object, with a free line of sight, as far as possible
        from the cameras placed before. `used` collects the targets' ids and points (the
        held-out views aim at what the training views looked at)."""
        rng = np.random.default_rng([self.p["seed"], seed_off])
        out = []
        objs = [t for t in interest if t[0] in {o[0] for o in self.obstacles}]
        rest = [t for t in interest if t[0] not in {o[0] for o in self.obstacles}]
        rng.shuffle(objs)
        rng.shuffle(rest)
        targets = objs + rest
        for i in range(n):
            best, best_score = None, -1
            for k in range(len(targets)):
                tgt_name, tgt = targets[(i + k) % len(targets)]
                for _ in range(300):
                    o = candidates_fn(rng, i, n)
                    t = np.asarray(tgt) + rng.uniform(-0.15, 0.15, 3)
                    if self.target_box is not None:
                        t = np.clip(t, self.target_box[0], self.target_box[1])
                    if np.linalg.norm(t - o) < 1.2:
                        continue
                    if any(np.all(o > lo - 0.25) and np.all(o < hi + 0.25) for _, lo, hi in self.obstacles):
                        continue
                    # the line of sight to the target must be free of other objects (boxes that
                    # hold the target, e.g. a shelf around a prop, do not count)
                    blocked = False
                    for oid, lo, hi in self.obstacles:
                        if oid == tgt_name or (np.all(t > lo - 0.05) and np.all(t < hi + 0.05)):
                            continue
                        if seg_hits_box(o, o + (t - o) * 0.9, lo + 0.02, hi - 0.02):
                            blocked = True
                            break
                    if blocked:
                        continue
                    score = min([np.linalg.norm(o - c.origin) for c in self.s.train + out] + [10.0])
                    if score > best_score:
                        best, best_score = (o, t), score
                    if best_score > 2.0:
                        break
                if best is not None:
                    break
            if best is None:
                raise SystemExit(f"could not place camera {prefix}{i}: scene too cluttered")
            fov = rng.uniform(*fov_range)
            out.append(Sensor(f"{prefix}{i}", np.round(best[0], 3), np.round(best[1], 3), round(fov, 1), res))
            if used is not None:
                used.append((tgt_name, tgt))
        return out

    # ---- lights ----
    def lights(self, kinds, relit, place):
        """Emitters (dicts) of the given kinds; `place(kind, rng, relit)` gives geometry."""
        rng = np.random.default_rng([self.p["seed"], 31337 if relit else 4242])
        out = []
        for k in kinds:
            if k == "area":
                continue  # an emitter shape, made by the layout
            out.append(place(k, rng, relit))
        return out


# ---- room -------------------------------------------------------------------------------


def furniture_mesh(kind, rng, cell, period):
    """Furniture made of boxes, in a local frame: footprint centred at the origin on y = 0,
    front facing +z. Returns (mesh, (w, d), supports as local (x0, x1, z0, z1, y, hmax))."""
    parts, sup = [], []
    if kind == "table":
        w, d, h = rng.uniform(1.2, 1.8), rng.uniform(0.75, 1.0), 0.75
        t = 0.05
        parts.append(box((-w / 2, h - t, -d / 2), (w / 2, h, d / 2), cell, period))
        for sx in (-1, 1):
            for sz in (-1, 1):
                cx, cz = sx * (w / 2 - 0.08), sz * (d / 2 - 0.08)
                parts.append(box((cx - 0.03, 0, cz - 0.03), (cx + 0.03, h - t, cz + 0.03), cell, period,
                                 skip=("+y", "-y")))
        sup.append((-w / 2, w / 2, -d / 2, d / 2, h, 0.5))
    elif kind == "chair":
        w, d, sh, bh = 0.45, 0.45, 0.45, 0.95
        t = 0.05
        parts.append(box((-w / 2, sh - t, -d / 2), (w / 2, sh, d / 2), cell, period))
        for sx in (-1, 1):
            for sz in (-1, 1):
                cx, cz = sx * (w / 2 - 0.04), sz * (d / 2 - 0.04)
                parts.append(box((cx - 0.02, 0, cz - 0.02), (cx + 0.02, sh - t, cz + 0.02), cell, period,
                                 skip=("+y", "-y")))
        parts.append(box((-w / 2, sh, -d / 2), (w / 2, bh, -d / 2 + 0.05), cell, period, skip=("-y",)))
    elif kind == "sofa":
        w, d = rng.uniform(1.7, 2.3), 0.9
        parts.append(box((-w / 2, 0, -d / 2), (w / 2, 0.42, d / 2), cell, period, skip=("-y",)))
        parts.append(box((-w / 2, 0.42, -d / 2), (w / 2, 0.88, -d / 2 + 0.22), cell, period, skip=("-y",)))
        for sx in (-1, 1):
            x0 = -w / 2 if sx < 0 else w / 2 - 0.2
            parts.append(box((x0, 0.42, -d / 2 + 0.22), (x0 + 0.2, 0.62, d / 2), cell, period,
                             skip=("-y", "-z")))
        sup.append((-w / 2 + 0.2, w / 2 - 0.2, -d / 2 + 0.22, d / 2, 0.42, 0.4))
    elif kind == "shelf":
        w, d, h, nb = rng.uniform(1.0, 1.4), 0.38, 1.8, 4
        t = 0.03
        for sx in (-1, 1):
            x0 = -w / 2 if sx < 0 else w / 2 - t
            parts.append(box((x0, 0, -d / 2), (x0 + t, h, d / 2), cell, period, skip=("-y",)))
        parts.append(box((-w / 2 + t, 0, -d / 2), (w / 2 - t, h, -d / 2 + 0.02), cell, period, skip=("-y",)))
        ys = np.linspace(0.05, h - t, nb)
        for k, yb in enumerate(ys):
            parts.append(box((-w / 2 + t, yb, -d / 2 + 0.02), (w / 2 - t, yb + t, d / 2), cell, period))
            if k < nb - 1:
                sup.append((-w / 2 + t, w / 2 - t, -d / 2 + 0.02, d / 2, yb + t, ys[k + 1] - yb - t - 0.03))
            else:
                sup.append((-w / 2 + t, w / 2 - t, -d / 2 + 0.02, d / 2, yb + t, 0.35))
    else:  # cabinet
        w, d, h = rng.uniform(0.6, 1.2), 0.5, rng.uniform(0.7, 1.1)
        parts.append(box((-w / 2, 0.08, -d / 2), (w / 2, h, d / 2), cell, period, skip=()))
        parts.append(box((-w / 2 + 0.03, 0, -d / 2 + 0.03), (w / 2 - 0.03, 0.08, d / 2 - 0.03), cell, period,
                         skip=("+y", "-y")))
        sup.append((-w / 2, w / 2, -d / 2, d / 2, h, 0.5))
    return Mesh.merge(parts), (w, d), sup


def build_room(b):
    p, rng, s = b.p, b.rng, b.s
    W, H, D = p["room"]
    cell = p["flat_cell"]
    hx, hz = W / 2, D / 2
    tex_kinds = list(b.tex_pool)
    period = 1.5 / p["tiling"]

    # Shell: planes facing inward, twosided (open surfaces).
    shell = [
        ("floor", (-hx, 0, hz), (W, 0, 0), (0, 0, -D)),
        ("ceiling", (-hx, H, -hz), (W, 0, 0), (0, 0, D)),
        ("wall_back", (-hx, 0, -hz), (W, 0, 0), (0, H, 0)),
        ("wall_front", (hx, 0, hz), (-W, 0, 0), (0, H, 0)),
        ("wall_left", (-hx, 0, hz), (0, 0, -D), (0, H, 0)),
        ("wall_right", (hx, 0, -hz), (0, 0, D), (0, H, 0)),
    ]
    textured_shell = {"floor": 0, "wall_back": 1, "wall_left": 2}
    for sid, o, eu, ev in shell:
        lu, lv = np.linalg.norm(eu), np.linalg.norm(ev)
        m = grid_quad(o, eu, ev, _cells(lu, cell), _cells(lv, cell), (0, 0), (lu / period, lv / period))
        tex = None
        k = textured_shell.get(sid)
        if k is not None and k < len(tex_kinds):
            tex = b.texture(sid, tex_kinds[k])
        alb = None if tex else (tuple(b.colour(0.6, 0.8)) if sid.startswith("wall") else (0.78, 0.78, 0.76))
        b.add(Shape(sid, m, "plane", alb, tex, twosided=True), obstacle=False)
    b.tex_count = 3

    kinds = parse_counts(p["objects"], FURNITURE_KINDS + OBJECT_KINDS)
    furn = [k for k in kinds if k in FURNITURE_KINDS]
    props = [k for k in kinds if k in OBJECT_KINDS]
    n_tex = int(p["textured_objects"])
    all_ids = list(range(len(furn) + len(props)))
    textured = set(rng.permutation(all_ids)[:n_tex].tolist()) if b.tex_pool else set()

    # Furniture: wall pieces (sofa, shelf, cabinet) back against a wall, tables free, chairs at
    # a table's side when there is one.
    footprints = []  # (x0, x1, z0, z1)
    supports = [dict(x0=-hx + 0.05, x1=hx - 0.05, z0=-hz + 0.05, z1=hz - 0.05, y=0.0, hmax=1.2,
                     size="large", name="floor")]
    tables = []
    counters = {}
    for fi, kind in enumerate(furn):
        idx = counters.get(kind, 0)
        counters[kind] = idx + 1
        sid = f"{kind}_{idx}" if furn.count(kind) > 1 else kind
        mesh, (w, d), sups = furniture_mesh(kind, rng, cell, 1.0 / p["tiling"])
        placed = False
        for attempt in range(500):
            if kind == "chair" and tables and attempt < 300:
                tx, tz, tw, td = tables[attempt % len(tables)]
                side = rng.integers(0, 4)
                ang = [0, 180, 90, 270][side]  # chair front (+z local) faces the table
                if side == 0:
                    x, z = tx + rng.uniform(-tw / 3, tw / 3), tz - td / 2 - 0.3
                elif side == 1:
                    x, z = tx + rng.uniform(-tw / 3, tw / 3), tz + td / 2 + 0.3
                elif side == 2:
                    x, z = tx - tw / 2 - 0.3, tz + rng.uniform(-td / 4, td / 4)
                else:
                    x, z = tx + tw / 2 + 0.3, tz + rng.uniform(-td / 4, td / 4)
                pad = 0.0
            elif kind in ("sofa", "shelf", "cabinet"):
                wall = rng.integers(0, 4)
                ang = [0, 180, 90, 270][wall]
                if wall == 0:  # back wall (-z), facing +z
                    x, z = rng.uniform(-hx + w / 2 + 0.1, hx - w / 2 - 0.1), -hz + d / 2 + 0.02
                elif wall == 1:
                    x, z = rng.uniform(-hx + w / 2 + 0.1, hx - w / 2 - 0.1), hz - d / 2 - 0.02
                elif wall == 2:  # left wall (-x), facing +x
                    x, z = -hx + d / 2 + 0.02, rng.uniform(-hz + w / 2 + 0.1, hz - w / 2 - 0.1)
                else:
                    x, z = hx - d / 2 - 0.02, rng.uniform(-hz + w / 2 + 0.1, hz - w / 2 - 0.1)
                pad = 0.35
            else:
                ang = [0, 90][rng.integers(0, 2)]
                x, z = rng.uniform(-hx + 1.2, hx - 1.2), rng.uniform(-hz + 1.2, hz - 1.2)
                pad = 0.6
            rw, rd = (w, d) if ang in (0, 180) else (d, w)
            fp = (x - rw / 2, x + rw / 2, z - rd / 2, z + rd / 2)
            if fp[0] < -hx or fp[1] > hx or fp[2] < -hz or fp[3] > hz:
                continue
            if any(rect_overlap(fp, q, pad if kind != "chair" else 0.05) for q in footprints):
                continue
            placed = True
            break
        if not placed:
            print(f"  note: no room left for {sid}; skipped", flush=True)
            continue
        # local front +z -> rotation: ang 0 faces +z, 180 faces -z, 90 faces +x, 270 faces -x
        R = rot_y({0: 0, 180: 180, 90: 90, 270: -90}[ang])
        world = mesh.transformed(R, (x, 0, z))
        footprints.append(fp)
        if kind == "table":
            tables.append((x, z, rw, rd))
        for (sx0, sx1, sz0, sz1, sy, hmax) in sups:
            c = np.array([[sx0, 0, sz0], [sx1, 0, sz1]]) @ R.T + np.array([x, 0, z])
            supports.append(dict(x0=c[:, 0].min(), x1=c[:, 0].max(), z0=c[:, 2].min(), z1=c[:, 2].max(),
                                 y=sy, hmax=hmax, size="small", name=sid))
        tex = b.texture(sid) if fi in textured else None
        b.add(Shape(sid, world, kind, None if tex else b.colour(0.15, 0.75), tex))

    # Props on the floor, tables, shelves, sofa seats.
    b.placed = [tuple(f) for f in footprints]
    floor_placed = b.placed
    counters = {}
    for pi, kind in enumerate(props):
        idx = counters.get(kind, 0)
        counters[kind] = idx + 1
        shape = None
        for attempt in range(20):
            sup = supports[0] if rng.random() < 0.4 or len(supports) == 1 else supports[
                1 + rng.integers(0, len(supports) - 1)]
            if sup["name"] == "floor":
                b.placed = floor_placed
            else:
                b.placed = sup.setdefault("placed", [])
            shape = b.make_prop(kind, idx, sup, (len(furn) + pi) in textured)
            if shape is not None:
                break
        b.placed = floor_placed
        if shape is None:
            print(f"  note: no room left for {kind}_{idx}; skipped", flush=True)
            continue
        b.add(shape)

    # Lights: area on the ceiling, points in the upper room, spots from the upper corners.
    kinds_l = parse_counts(p["lights"], LIGHT_KINDS)
    for k, kind in enumerate(kinds_l):
        if kind == "area":
            lw, ld = 1.2, 0.6
            cx = rng.uniform(-hx + 1, hx - 1) if k else 0.0
            cz = rng.uniform(-hz + 1, hz - 1) if k else 0.0
            m = grid_quad((cx - lw / 2, H - 0.005, cz - ld / 2), (lw, 0, 0), (0, 0, ld), 1, 1)
            rad = (14.0, 12.5, 10.5)
            b.add(Shape(f"light_{k}" if kinds_l.count("area") > 1 else "light", m, "area_light",
                        emitter=rad), obstacle=False)
    interest = interest_points(b)

    corners_used = []

    def place(kind, lrng, relit):
        if kind == "point":
            for _ in range(100):
                pos = np.array([lrng.uniform(-hx + 0.6, hx - 0.6), lrng.uniform(H * 0.6, H - 0.3),
                                lrng.uniform(-hz + 0.6, hz - 0.6)])
                if not any(np.all(pos > lo - 0.3) and np.all(pos < hi + 0.3) for _, lo, hi in b.obstacles):
                    break
            col = np.array([1.0, 0.9, 0.75]) if not relit else np.array([0.75, 0.85, 1.0])
            return dict(type="point", position=np.round(pos, 3), intensity=np.round(col * 5.0, 3))
        if kind == "spot":
            # upper corners; the relit spots take the corners the original ones left free
            c = int(lrng.integers(0, 4))
            if relit:
                c = next(((c + k) % 4 for k in range(4) if (c + k) % 4 not in corners_used), c)
            else:
                corners_used.append(c)
            sx, sz = [(-1, -1), (1, -1), (1, 1), (-1, 1)][c]
            o = np.array([sx * (hx - 0.3), H - 0.2, sz * (hz - 0.3)])
            t = np.asarray(interest[lrng.integers(0, len(interest))][1])
            col = np.array([1.0, 0.95, 0.85]) if not relit else np.array([1.0, 0.7, 0.5])
            return dict(type="spot", origin=np.round(o, 3), target=np.round(t, 3), up=safe_up(o, t),
                        intensity=np.round(col * 25.0, 3), cutoff=30.0, beam=22.0)
        if kind == "directional":
            print("  note: a directional light in a closed room lights nothing", flush=True)
            d = np.array([lrng.uniform(-0.5, 0.5), -1.0, lrng.uniform(-0.5, 0.5)])
            return dict(type="directional", direction=np.round(d, 3), irradiance=(2.0, 2.0, 2.0))
        raise SystemExit(f"light kind '{kind}' is not available in a room")

    s.emitters = b.lights(kinds_l, False, place)
    relit_kinds = [k for k in kinds_l if k != "area"] or ["point"]
    if "area" in kinds_l:
        relit_kinds = relit_kinds + ["point"]
    s.relit_emitters = b.lights(relit_kinds, True, place)

    margin = 0.45
    b.target_box = (np.array([-hx + 0.05, 0.05, -hz + 0.05]), np.array([hx - 0.05, H - 0.05, hz - 0.05]))

    def cand(crng, i, n):
        return np.array([crng.uniform(-hx + margin, hx - margin), crng.uniform(1.3, min(2.0, H - 0.4)),
                         crng.uniform(-hz + margin, hz - margin)])

    res = tuple(p["res"])
    seen = []
    s.train = b.place_cameras(p["train"], "cam_train_", cand, interest, res, (55, 70), 101, seen)
    s.test = b.place_cameras(p["test"], "cam_test_", cand, seen, res, (55, 70), 202)


def interest_points(b):
    pts = []
    for sid, lo, hi in b.obstacles:
        c = (lo + hi) / 2
        c[1] = min(hi[1], 1.6)
        pts.append((sid, c))
    W, H, D = b.p["room"]
    if H > 0:
        hx, hz = W / 2, D / 2
        pts += [("wall_back", np.array([0, 1.2, -hz])), ("wall_front", np.array([0, 1.2, hz])),
                ("wall_left", np.array([-hx, 1.2, 0])), ("wall_right", np.array([hx, 1.2, 0]))]
        pts += [("floor", np.array([sx * hx * 0.6, 0, sz * hz * 0.6])) for sx in (-1, 1) for sz in (-1, 1)]
    return pts


# ---- open ground scenes (open, envmap) ----------------------------------------------------


def build_outdoor(b, envmap):
    p, rng, s = b.p, b.rng, b.s
    W, _, D = p["room"]
    period = 1.0 / p["tiling"]
    m = grid_quad((-W / 2, 0, D / 2), (W, 0, 0), (0, 0, -D), _cells(W, p["flat_cell"]),
                  _cells(D, p["flat_cell"]), (0, 0), (W / period, D / period))
    tex = b.texture("ground") if b.tex_pool else None
    b.add(Shape("ground", m, "plane", None if tex else (0.45, 0.45, 0.42), tex, twosided=True), obstacle=False)
    kinds = parse_counts(p["objects"], OBJECT_KINDS)
    n_tex = int(p["textured_objects"])
    area = 1.2 + 0.9 * math.sqrt(len(kinds))
    sup = dict(x0=-area, x1=area, z0=-area, z1=area, y=0.0, hmax=2.5, size="large", upright_tori=True)
    b.placed = []
    counters = {}
    for i, kind in enumerate(kinds):
        idx = counters.get(kind, 0)
        counters[kind] = idx + 1
        sh = b.make_prop(kind, idx, sup, i < n_tex)
        if sh is None:
            print(f"  note: no room left for {kind}_{idx}; skipped", flush=True)
            continue
        b.add(sh)
    if not b.obstacles:
        raise SystemExit("an open scene needs at least one object (--objects)")
    lo = np.min([o[1] for o in b.obstacles], 0)
    hi = np.max([o[2] for o in b.obstacles], 0)
    centre = (lo + hi) / 2
    centre[1] = 0.4 * hi[1]

    kinds_l = parse_counts(p["lights"], LIGHT_KINDS + ("envmap",))
    if envmap:
        sun = np.array([0.45, 0.55, -0.7])
        s.textures["textures/sky.exr"] = ("exr", make_sky(int(p.get("sky_res", 1024)), sun, p["seed"]))
        s.emitters = [dict(type="envmap", file="textures/sky.exr", scale=1.0, rotate_y=0.0)]
        s.relit_emitters = [dict(type="envmap", file="textures/sky.exr", scale=1.0,
                                 rotate_y=round(float(rng.uniform(100, 160)), 1))]
    else:
        for k, kind in enumerate(kinds_l):
            if kind == "area":
                lw = 1.0
                y = 4.0
                m = grid_quad((-lw / 2, y, -lw / 2), (lw, 0, 0), (0, 0, lw), 1, 1)
                b.add(Shape("light" if kinds_l.count("area") == 1 else f"light_{k}", m, "area_light",
                            emitter=(30.0, 28.0, 25.0)), obstacle=False)

        def place(kind, lrng, relit):
            if kind == "directional":
                az = lrng.uniform(0, 2 * np.pi)
                el = lrng.uniform(35, 60)
                d = -np.array([math.cos(math.radians(el)) * math.cos(az), math.sin(math.radians(el)),
                               math.cos(math.radians(el)) * math.sin(az)])
                col = np.array([1.0, 0.95, 0.88]) if not relit else np.array([0.9, 0.95, 1.05])
                return dict(type="directional", direction=np.round(d, 3), irradiance=np.round(col * 3.0, 3))
            if kind == "point":
                az = lrng.uniform(0, 2 * np.pi)
                pos = centre + np.array([2.5 * math.cos(az), 0, 2.5 * math.sin(az)])
                pos[1] = lrng.uniform(2.0, 3.0)
                col = np.array([1.0, 0.85, 0.7]) if not relit else np.array([0.7, 0.85, 1.0])
                return dict(type="point", position=np.round(pos, 3), intensity=np.round(col * 12.0, 3))
            if kind == "spot":
                az = lrng.uniform(0, 2 * np.pi)
                o = centre + np.array([3.5 * math.cos(az), 0, 3.5 * math.sin(az)])
                o[1] = 3.5
                return dict(type="spot", origin=np.round(o, 3), target=np.round(centre, 3), up=safe_up(o, centre),
                            intensity=(30.0, 28.0, 25.0), cutoff=30.0, beam=22.0)
            raise SystemExit(f"light kind '{kind}' is not available here")

        s.emitters = b.lights(kinds_l, False, place)
        relit_kinds = [k for k in kinds_l if k != "area"] or ["point"]
        s.relit_emitters = b.lights(relit_kinds, True, place)

    interest = [(sid, (lo_ + hi_) / 2) for sid, lo_, hi_ in b.obstacles] + [("ground", centre)]
    radius = max(4.5, 2.2 * float(np.max(hi - lo)))

    def cand(crng, i, n):
        az = 2 * np.pi * (i + crng.uniform(-0.3, 0.3)) / max(n, 1)
        r = radius * crng.uniform(0.95, 1.3)
        return centre + np.array([r * math.cos(az), crng.uniform(1.2, 3.2) - centre[1], r * math.sin(az)])

    res = tuple(p["res"])
    s.train = b.place_cameras(p["train"], "cam_train_", cand, interest, res, (40, 50), 101)
    s.test = b.place_cameras(p["test"], "cam_test_", cand, interest, res, (40, 50), 202)


# ---- mirror-cbox ----------------------------------------------------------------------------


def build_mirror_cbox(b):
    """Mitsuba's tutorial Cornell box (mi.cornell_box(): [-1, 1]^3, open front, colours and
    light of the tutorial) with a mirror (conductor) and a glass (dielectric) sphere instead of
    the boxes; BSDFs declared at top level and referenced; tent filter; focus_distance."""
    p, s = b.p, b.s
    s.rfilter = "tent"
    s.focus_distance = True
    white, red, green = (0.885809, 0.698859, 0.666422), (0.570068, 0.0430135, 0.0443706), (
        0.105421, 0.37798, 0.076425)
    cell = p["flat_cell"]
    walls = [
        ("floor", (-1, -1, 1), (2, 0, 0), (0, 0, -2), "white"),
        ("ceiling", (-1, 1, -1), (2, 0, 0), (0, 0, 2), "white"),
        ("back", (-1, -1, -1), (2, 0, 0), (0, 2, 0), "white"),
        ("red_wall", (-1, -1, 1), (0, 0, -2), (0, 2, 0), "red"),
        ("green_wall", (1, -1, -1), (0, 0, 2), (0, 2, 0), "green"),
    ]
    cols = dict(white=white, red=red, green=green)
    for name, c in cols.items():
        s.top_bsdfs.append((f'<bsdf type="diffuse" id="{name}">{rgb_xml("reflectance", c)}</bsdf>', "truth"))
    for sid, *_ in walls:
        # the input states nothing about the walls: a neutral diffuse each, referenced too
        s.top_bsdfs.append((f'<bsdf type="diffuse" id="neutral_{sid}">{rgb_xml("reflectance", NEUTRAL)}</bsdf>',
                            "input"))
    s.top_bsdfs.append(('<bsdf type="conductor" id="mirror"><string name="material" value="none"/></bsdf>', "both"))
    s.top_bsdfs.append(('<bsdf type="dielectric" id="glass"><float name="int_ior" value="1.5"/>'
                        '<float name="ext_ior" value="1.0"/></bsdf>', "both"))
    s.top_bsdfs.append((f'<bsdf type="diffuse" id="black">{rgb_xml("reflectance", (0, 0, 0))}</bsdf>', "both"))
    for sid, o, eu, ev, mat in walls:
        m = grid_quad(o, eu, ev, _cells(2, cell), _cells(2, cell))
        b.add(Shape(sid, m, "plane", cols[mat], truth_ref=mat, input_ref=f"neutral_{sid}"), obstacle=False)
    # grid_quad's normal is cross(eu, ev) = -y: the light faces down
    m = grid_quad((-0.23, 0.99, -0.18), (0.46, 0, 0), (0, 0, 0.38), 1, 1)
    b.add(Shape("light", m, "area_light", emitter=(18.387, 13.9873, 6.75357), truth_ref="black",
                input_ref="black"), obstacle=False)
    b.add(Shape("mirror_sphere", uv_sphere((-0.42, -0.62, -0.3), 0.38, p["tris"]), "sphere",
                truth_ref="mirror", input_ref="mirror"))
    b.add(Shape("glass_sphere", uv_sphere((0.42, -0.67, 0.3), 0.33, p["tris"]), "sphere",
                truth_ref="glass", input_ref="glass"))
    s.emitters = []
    s.relit_emitters = [dict(type="point", position=np.array([0.3, 0.6, 0.5]), intensity=(2.5, 2.2, 1.8)),
                        dict(type="spot", origin=np.array([-0.8, 0.8, 0.9]), target=np.array([0.0, -0.8, -0.3]),
                             up=(0, 1, 0), intensity=(3.0, 3.0, 3.5), cutoff=35.0, beam=25.0)]
    rng = np.random.default_rng([p["seed"], 5])
    res = tuple(p["res"])

    def views(n, prefix, off):
        out = []
        for i in range(n):
            a = (i - (n - 1) / 2) * 0.35 + off + rng.uniform(-0.05, 0.05)
            o = np.array([3.9 * math.sin(a * 0.3), rng.uniform(-0.2, 0.3), 3.9 * math.cos(a * 0.3)])
            t = np.array([rng.uniform(-0.1, 0.1), rng.uniform(-0.15, 0.05), 0.0])
            out.append(Sensor(f"{prefix}{i}", np.round(o, 3), np.round(t, 3), round(39.3 + rng.uniform(-1, 2), 1), res))
        return out

    s.train = views(p["train"], "cam_train_", 0.0)
    s.test = views(p["test"], "cam_test_", 0.17)


# ------------------------------------------------------------------------------------------
# Mitsuba


def find_libllvm():
    pats = ["/usr/lib/x86_64-linux-gnu/libLLVM-19.so*", "/usr/lib/*/libLLVM-19.so*", "/usr/lib/llvm-19/lib/libLLVM*.so*",
            "/usr/lib/x86_64-linux-gnu/libLLVM*.so*", "/usr/lib/llvm-*/lib/libLLVM*.so*"]
    for pat in pats:
        hits = sorted(glob.glob(pat))
        if hits:
            return hits[0]
    return None


def setup_mitsuba(want):
    """Import Mitsuba with `want` ('auto' = llvm_ad_rgb if libLLVM works, else scalar_rgb)."""
    note = None
    if want in ("auto", "llvm_ad_rgb") and not os.environ.get("DRJIT_LIBLLVM_PATH"):
        lib = find_libllvm()
        if lib:
            os.environ["DRJIT_LIBLLVM_PATH"] = lib
    import mitsuba as mi

    if want == "auto":
        try:
            mi.set_variant("llvm_ad_rgb")
            import drjit as dr

            x = mi.Float([1.0, 2.0]) * 2
            dr.eval(x)
            variant = "llvm_ad_rgb"
        except Exception as e:  # noqa: BLE001
            note = f"llvm_ad_rgb unavailable ({str(e).splitlines()[0] if str(e) else type(e).__name__}); using scalar_rgb"
            mi.set_variant("scalar_rgb")
            variant = "scalar_rgb"
    else:
        mi.set_variant(want)
        variant = want
    return mi, variant, note


def pixel_coverage(mi, scene, idx):
    """{shape id: pixels} whose centre ray first hits that shape, through sensor `idx` (JIT
    variants only; None in scalar variants)."""
    if not mi.variant().startswith(("llvm", "cuda")):
        return None
    import drjit as dr

    sensor = scene.sensors()[idx]
    w, h = sensor.film().crop_size()
    i = dr.arange(mi.UInt32, w * h)
    pos = mi.Point2f((mi.Float(i % w) + 0.5) / w, (mi.Float(i // w) + 0.5) / h)
    ray, _ = sensor.sample_ray(0.0, 0.0, pos, mi.Point2f(0.5, 0.5))
    si = scene.ray_intersect(ray)
    out = {}
    for sh in scene.shapes():
        c = dr.count(si.shape == mi.ShapePtr(sh))
        out[sh.id()] = int(c[0] if hasattr(c, "__len__") else c)
    return out


def render_views(mi, xml_path, wanted, out_for, spp, seed, max_samples, aov=False, log=print, coverage=None):
    """Render the sensors of `xml_path` whose id is in `wanted` to out_for(id) as half-float
    EXRs, in passes of at most `max_samples` samples (weighted mean of the passes: exact for
    the box filter). Returns {id: seconds}; fills `coverage` (a dict) with pixel_coverage."""
    d = os.path.dirname(os.path.abspath(xml_path))
    with open(xml_path) as fh:
        src = fh.read()
    if aov:
        src = re.sub(r"<integrator.*?</integrator>",
                     '<integrator type="aov"><string name="aovs" value="a:albedo"/></integrator>', src, flags=re.S)
    cwd = os.getcwd()
    os.chdir(d)
    try:
        t0 = time.time()
        scene = mi.load_string(src, optimize=False)  # keep one shape per id (no merging)
        log(f"    loaded {os.path.basename(xml_path)}{' (albedo AOV)' if aov else ''} in {time.time() - t0:.1f} s")
    finally:
        os.chdir(cwd)
    times = {}
    for idx, sensor in enumerate(scene.sensors()):
        sid = sensor.id()
        if sid not in wanted:
            continue
        w, h = sensor.film().crop_size()
        if coverage is not None:
            coverage[sid] = pixel_coverage(mi, scene, idx)
        per = max(1, min(spp, max_samples // (w * h)))
        t0 = time.time()
        acc, done, k = None, 0, 0
        while done < spp:
            n = min(per, spp - done)
            s = (seed * 1000003 + wanted.index(sid) * 9176 + k * 7 + (5 if aov else 0)) % (2 ** 31)
            img = np.array(mi.render(scene, sensor=idx, spp=n, seed=s), dtype=np.float64)[:, :, -3:]
            acc = img * n if acc is None else acc + img * n
            done += n
            k += 1
        img = (acc / spp).astype(np.float32)
        out = out_for(sid)
        bmp = mi.Bitmap(np.ascontiguousarray(img), mi.Bitmap.PixelFormat.RGB)
        bmp.convert(component_format=mi.Struct.Type.Float16).write(out)
        dt = time.time() - t0
        times[sid] = round(dt, 2)
        log(f"    {os.path.relpath(out, os.path.dirname(d))}: {w}x{h}, {spp} spp in {k} passes, "
            f"{dt:.1f} s, mean RGB {[round(float(x), 4) for x in img.reshape(-1, 3).mean(0)]}")
    missing = set(wanted) - set(times)
    if missing:
        raise SystemExit(f"sensors not found in {xml_path}: {sorted(missing)}")
    return times


# ------------------------------------------------------------------------------------------
# Driver


def effective_params(a):
    p = dict(PRESETS[a.preset])
    for key in ("objects", "tris", "flat_cell", "textures", "textured_objects", "tiling", "texture_res",
                "train", "test", "lights", "spp", "seed", "sky_res"):
        v = getattr(a, key)
        if v is not None:
            p[key] = v
    if a.room is not None:
        p["room"] = tuple(float(x) for x in a.room.split(","))
        if len(p["room"]) != 3:
            raise SystemExit("--room takes W,H,D (metres)")
    if a.res is not None:
        w, _, h = a.res.lower().partition("x")
        p["res"] = (int(w), int(h))
    p["room"] = tuple(float(x) for x in p["room"])
    p["res"] = tuple(int(x) for x in p["res"])
    p["preset"] = a.preset
    if p["train"] < 1 or p["test"] < 0 or p["spp"] < 1 or min(p["res"]) < 1:
        raise SystemExit("need --train >= 1, --test >= 0, --spp >= 1 and a positive --res")
    return p


def params_hash(p):
    blob = json.dumps(dict(p, generator_version=GENERATOR_VERSION), sort_keys=True, default=list)
    return hashlib.sha256(blob.encode()).hexdigest()[:16]


def build(p):
    b = Builder(p)
    if p["layout"] == "room":
        build_room(b)
    elif p["layout"] in ("open", "envmap"):
        build_outdoor(b, p["layout"] == "envmap")
    elif p["layout"] == "mirror-cbox":
        build_mirror_cbox(b)
    else:
        raise SystemExit(f"unknown layout {p['layout']}")
    ids = [sh.id for sh in b.s.shapes] + [c.id for c in b.s.train + b.s.test]
    assert len(ids) == len(set(ids)), "duplicate ids"
    return b.s


def describe(s):
    shapes = []
    for sh in s.shapes:
        m = sh.mesh
        lo, hi = m.bbox()
        d = dict(id=sh.id, kind=sh.kind, triangles=int(len(m.f)), vertices=int(len(m.v)),
                 area_m2=round(m.area(), 4), bbox=[lo.round(3).tolist(), hi.round(3).tolist()],
                 twosided=sh.twosided)
        if sh.emitter is not None:
            d["area_emitter_radiance"] = list(sh.emitter)
        if sh.truth_ref is not None:
            d["bsdf_ref"] = sh.truth_ref
        if sh.texture is not None:
            uv_area = float(m.tri_areas(uv=True).sum())
            res = sh.texture["res"]
            d["texture"] = dict(sh.texture, uv_area_repeats=round(uv_area, 3),
                                metres_per_texture_pixel=round(math.sqrt(m.area() / max(uv_area * res * res, 1e-12)), 5))
        elif sh.albedo is not None:
            d["albedo"] = list(sh.albedo)
        shapes.append(d)
    sensors = []
    for c in s.train + s.test:
        dist = float(np.linalg.norm(c.target - c.origin))
        sensors.append(dict(id=c.id, origin=c.origin.tolist(), target=c.target.tolist(), fov_x=c.fov,
                            res=list(c.res), target_distance_m=round(dist, 3),
                            metres_per_pixel_at_target=round(2 * dist * math.tan(math.radians(c.fov) / 2) / c.res[0], 5)))
    diffuse = [sh for sh in shapes if sh.get("bsdf_ref") not in ("mirror", "glass")]
    area = sum(sh["area_m2"] for sh in diffuse if "area_emitter_radiance" not in sh)
    return dict(
        shapes=shapes, sensors=sensors,
        totals=dict(shapes=len(shapes), triangles=int(sum(sh["triangles"] for sh in shapes)),
                    vertices=int(sum(sh["vertices"] for sh in shapes)),
                    diffuse_area_m2=round(area, 3),
                    texels_at_64_per_unit=int(area * 64 * 64),
                    training_pixels=int(sum(c.res[0] * c.res[1] for c in s.train))),
        emitters=[{k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in e.items()} for e in s.emitters],
        relit_emitters=[{k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in e.items()}
                        for e in s.relit_emitters],
    )


def write_json(path, obj):
    tmp = path + ".tmp"
    with open(tmp, "w") as fh:
        json.dump(obj, fh, indent=1)
    os.replace(tmp, path)


def clear_outputs(out):
    for sub in OUTPUT_SUBDIRS:
        pth = os.path.join(out, sub)
        if os.path.isdir(pth):
            shutil.rmtree(pth)
    for f in ("input.xml", "truth.xml", "relit.xml", "scene.json"):
        pth = os.path.join(out, f)
        if os.path.exists(pth):
            os.remove(pth)


def write_scene(s, out, log):
    t0 = time.time()
    for sub in ("meshes", "textures"):
        os.makedirs(os.path.join(out, sub), exist_ok=True)
    for sh in s.shapes:
        write_obj(os.path.join(out, "meshes", f"{sh.id}.obj"), sh.mesh, f"kdmap gen_scene.py: {sh.id} ({sh.kind})")
    t_mesh = time.time() - t0
    t1 = time.time()
    for f, img in s.textures.items():
        if isinstance(img, tuple):  # ('exr', float array)
            import mitsuba as mi  # noqa: F401  (a variant is set by the caller)

            bmp = mi.Bitmap(np.ascontiguousarray(img[1]), mi.Bitmap.PixelFormat.RGB)
            # half float, as every EXR the generator writes (the sky's 900 fits: max 65504)
            bmp.convert(component_format=mi.Struct.Type.Float16).write(os.path.join(out, f))
        else:
            write_png(os.path.join(out, f), linear_to_srgb8(img))
    t_tex = time.time() - t1
    for which in ("input", "truth", "relit"):
        with open(os.path.join(out, f"{which}.xml"), "w") as fh:
            fh.write(s.xml(which))
    log(f"  wrote {len(s.shapes)} meshes in {t_mesh:.1f} s, {len(s.textures)} textures in {t_tex:.1f} s, 3 XML files")
    return dict(meshes=round(t_mesh, 2), textures=round(t_tex, 2))


def parse_args(argv):
    ap = argparse.ArgumentParser(
        description="Generate a kdmap test scene with Mitsuba 3 (see the module docstring).",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="presets: " + ", ".join(PRESETS) + "\nobject kinds: " + ", ".join(FURNITURE_KINDS + OBJECT_KINDS)
        + "\ntextures: " + ", ".join(TEXTURE_FUNCS) + "\nlights: " + ", ".join(LIGHT_KINDS),
    )
    ap.add_argument("out", nargs="?", help="output directory (default cache/scenes/<preset>)")
    ap.add_argument("--preset", default="room-small", choices=list(PRESETS))
    ap.add_argument("--room", help="room (or ground) size W,H,D in metres (room: 6,3,5)")
    ap.add_argument("--objects", help="kinds and counts, e.g. 'table:1,chair:2,sphere:4,torus:2'")
    ap.add_argument("--tris", type=int, help="triangles per curved object (sphere, torus, cylinder)")
    ap.add_argument("--flat-cell", type=float, help="largest cell of flat surfaces, metres")
    ap.add_argument("--textures", help="texture pool, comma-separated, or 'none'")
    ap.add_argument("--textured-objects", type=int, help="how many objects (besides floor/walls) get a texture")
    ap.add_argument("--tiling", type=float, help="texture repeat factor (more repeats = finer detail)")
    ap.add_argument("--texture-res", type=int, help="texture size in pixels (square)")
    ap.add_argument("--train", type=int, help="number of training views")
    ap.add_argument("--test", type=int, help="number of held-out views")
    ap.add_argument("--res", help="view resolution WxH, e.g. 512x384")
    ap.add_argument("--lights", help="light mix, e.g. 'area:1,point:2,spot:1'")
    ap.add_argument("--sky-res", type=int, help="width of the envmap layout's lat-long sky (height: half; default 1024)")
    ap.add_argument("--spp", type=int, help="samples per pixel of photos and held-out views")
    ap.add_argument("--seed", type=int, help="seed of every random choice")
    ap.add_argument("--albedo", action="store_true", help="also render albedo/cam_train_*.exr (albedo AOV)")
    ap.add_argument("--albedo-spp", type=int, default=64)
    ap.add_argument("--dry-run", action="store_true", help="meshes, textures, XML and scene.json only; no rendering")
    ap.add_argument("--force", action="store_true", help="regenerate even if the same parameters were generated")
    ap.add_argument("--variant", default="auto", help="Mitsuba variant (auto: llvm_ad_rgb, else scalar_rgb)")
    ap.add_argument("--max-samples", type=int, default=4_000_000, help="samples per render pass (memory)")
    ap.add_argument("--nice", type=int, default=10, help="lower this process's priority by N while rendering (0: no)")
    return ap.parse_args(argv)


def main(argv=None):
    a = parse_args(argv)
    p = effective_params(a)
    out = os.path.abspath(a.out or os.path.join(DEFAULT_CACHE, a.preset))
    h = params_hash(p)
    log = lambda m: print(m, flush=True)  # noqa: E731
    meta_path = os.path.join(out, "scene.json")
    if os.path.exists(meta_path) and not a.force:
        try:
            with open(meta_path) as fh:
                old = json.load(fh)
        except (OSError, ValueError):
            old = {}
        if old.get("params_hash") == h and old.get("complete") and (a.dry_run or old.get("rendered")):
            if a.albedo and not old.get("albedo") and not a.dry_run:
                log(f"{out}: same parameters (hash {h}); rendering the missing albedo AOV only")
                mi, variant, note = setup_mitsuba(a.variant)
                if a.nice:
                    os.nice(a.nice)
                os.makedirs(os.path.join(out, "albedo"), exist_ok=True)
                train = [sn["id"] for sn in old["sensors"] if sn["id"].startswith("cam_train_")]
                t = render_views(mi, os.path.join(out, "truth.xml"), train,
                                 lambda i: os.path.join(out, "albedo", f"{i}.exr"), a.albedo_spp, p["seed"],
                                 a.max_samples, aov=True, log=log)
                old["albedo"] = dict(spp=a.albedo_spp, seconds=t)
                write_json(meta_path, old)
                return 0
            log(f"{out}: already generated with these parameters (hash {h}); skipping (--force regenerates)")
            return 0
    if os.path.isdir(out) and os.listdir(out) and not os.path.exists(meta_path):
        raise SystemExit(f"{out} exists and is not a generated scene (no scene.json); not touching it")
    os.makedirs(out, exist_ok=True)
    clear_outputs(out)

    t_all = time.time()
    log(f"generating preset '{a.preset}' into {out} (seed {p['seed']}, hash {h})")
    mi = variant = note = None
    if not a.dry_run or p["layout"] == "envmap":
        mi, variant, note = setup_mitsuba(a.variant if not a.dry_run else "scalar_rgb")
        if note:
            log("  note: " + note)
    t0 = time.time()
    s = build(p)
    t_build = time.time() - t0
    info = describe(s)
    tot = info["totals"]
    log(f"  built {tot['shapes']} shapes, {tot['triangles']:,} triangles, {len(s.train)} + {len(s.test)} views "
        f"in {t_build:.1f} s")
    t_write = write_scene(s, out, log)
    meta = dict(generator="tools/gen_scene.py", generator_version=GENERATOR_VERSION, params=p, params_hash=h,
                command=" ".join([os.path.basename(sys.argv[0])] + (argv if argv is not None else sys.argv[1:])),
                date=time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()), machine=dict(
                    cores=os.cpu_count(), python=platform.python_version()),
                dry_run=a.dry_run, rendered=False, complete=False, **info,
                timings=dict(build_seconds=round(t_build, 2), write_seconds=t_write))
    write_json(meta_path, meta)
    if a.dry_run:
        meta["complete"] = True
        meta["timings"]["total_seconds"] = round(time.time() - t_all, 2)
        write_json(meta_path, meta)
        log(f"dry run: {out} ({tot['triangles']:,} triangles), no images rendered")
        return 0

    if a.nice:
        os.nice(a.nice)
    meta["mitsuba"] = dict(version=mi.__version__, variant=variant, note=note, spp=p["spp"], rfilter=s.rfilter,
                           integrator="path max_depth=-1 rr_depth=8", exr="half float")
    for sub in ("images", "truth"):
        os.makedirs(os.path.join(out, sub), exist_ok=True)
    train = [c.id for c in s.train]
    test = [c.id for c in s.test]
    tr = {}
    t0 = time.time()
    log(f"  rendering {len(train)} photos + {len(test)} held-out views ({variant}, {p['spp']} spp)")
    cov = {}
    tr["photos"] = render_views(mi, os.path.join(out, "truth.xml"), train + test,
                                lambda i: os.path.join(out, "images" if i in train else "truth", f"{i}.exr"),
                                p["spp"], p["seed"], a.max_samples, log=log, coverage=cov)
    if all(v is not None for v in cov.values()):
        # pixels per shape and view (centre rays), and which shapes no training view sees
        meta["coverage_pixels"] = cov
        for sh in meta["shapes"]:
            sh["training_pixels"] = sum(cov[v].get(sh["id"], 0) for v in train)
            sh["heldout_pixels"] = sum(cov[v].get(sh["id"], 0) for v in test)
        unseen = [sh["id"] for sh in meta["shapes"] if sh["training_pixels"] == 0 and "area_emitter_radiance" not in sh]
        meta["unseen_by_training_views"] = unseen
        if unseen:
            log(f"  note: no training view sees {', '.join(unseen)}")
    if test:
        log(f"  rendering {len(test)} relit held-out views")
        tr["relit"] = render_views(mi, os.path.join(out, "relit.xml"), test,
                                   lambda i: os.path.join(out, "truth", f"{i}_relit.exr"), p["spp"], p["seed"] + 1,
                                   a.max_samples, log=log)
    meta["timings"]["render_seconds"] = round(time.time() - t0, 1)
    meta["timings"]["per_view_seconds"] = tr
    if a.albedo:
        os.makedirs(os.path.join(out, "albedo"), exist_ok=True)
        t1 = time.time()
        t = render_views(mi, os.path.join(out, "truth.xml"), train, lambda i: os.path.join(out, "albedo", f"{i}.exr"),
                         a.albedo_spp, p["seed"], a.max_samples, aov=True, log=log)
        meta["albedo"] = dict(spp=a.albedo_spp, seconds=t, total_seconds=round(time.time() - t1, 1))
    meta["rendered"] = True
    meta["complete"] = True
    meta["timings"]["total_seconds"] = round(time.time() - t_all, 1)
    write_json(meta_path, meta)
    log(f"done: {out} in {meta['timings']['total_seconds']} s ({tot['triangles']:,} triangles)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
