#!/usr/bin/env python3
"""Smoke test of tools/gen_scene.py without any rendering (its --dry-run: meshes, textures,
XML, scene.json only). Needs numpy; with Mitsuba installed it also checks that Mitsuba loads
truth.xml and relit.xml (loading, no rendering).

    .venv/bin/python tools/test_gen_scene.py            # every preset, about 30 s
    .venv/bin/python tools/test_gen_scene.py --quick    # without the 1M-triangle room

Checks: the files of the fixture layout exist and are referenced consistently; input.xml uses
only the plugins kdmap reads (for room, room-small, open) with the neutral 0.5 reflectance;
sensors are split train (input) / train + test (truth) / test (relit); relit.xml has no emitter
shape; the OBJ files parse, their indices are in range, their normals are unit and agree with
the triangles' winding, and their counts match scene.json; the room preset reaches 1M triangles;
the same seed gives identical files and a generated scene is reused; the mesh builders give the
analytic areas.
"""

import math
import os
import subprocess
import sys
import tempfile
import unittest
import xml.etree.ElementTree as ET

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import gen_scene as gs  # noqa: E402

QUICK = "--quick" in sys.argv
KDMAP_PRESETS = ("room", "room-small", "open")  # kdmap reads these today


def run(*args):
    r = subprocess.run([sys.executable, os.path.join(HERE, "gen_scene.py"), *args], capture_output=True, text=True)
    if r.returncode != 0:
        raise AssertionError(f"gen_scene.py {' '.join(args)} failed:\n{r.stdout}\n{r.stderr}")
    return r.stdout


def read(path):
    with open(path, "rb") as fh:
        return fh.read()


def read_obj(path):
    v, vt, vn, f = [], [], [], []
    with open(path) as fh:
        for line in fh:
            w = line.split()
            if not w:
                continue
            if w[0] == "v":
                v.append([float(x) for x in w[1:4]])
            elif w[0] == "vt":
                vt.append([float(x) for x in w[1:3]])
            elif w[0] == "vn":
                vn.append([float(x) for x in w[1:4]])
            elif w[0] == "f":
                f.append([[int(i) if i else 0 for i in c.split("/")] for c in w[1:]])
    return np.array(v), np.array(vt), np.array(vn), np.array(f)


class Presets(unittest.TestCase):
    tmp = None

    @classmethod
    def setUpClass(cls):
        cls.tmp = tempfile.TemporaryDirectory(prefix="gen_scene_test_")
        cls.dirs = {}
        for p in gs.PRESETS:
            if QUICK and p == "room":
                continue
            d = os.path.join(cls.tmp.name, p)
            run("--preset", p, d, "--dry-run")
            cls.dirs[p] = d

    @classmethod
    def tearDownClass(cls):
        cls.tmp.cleanup()

    def test_layout_and_xml(self):
        import json

        for p, d in self.dirs.items():
            with self.subTest(preset=p):
                meta = json.loads(read(os.path.join(d, "scene.json")))
                self.assertTrue(meta["complete"] and meta["dry_run"])
                roots = {w: ET.parse(os.path.join(d, f"{w}.xml")).getroot() for w in ("input", "truth", "relit")}
                sens = {w: [s.get("id") for s in r.findall("sensor")] for w, r in roots.items()}
                train = [f"cam_train_{i}" for i in range(gs.PRESETS[p]["train"])]
                test = [f"cam_test_{i}" for i in range(gs.PRESETS[p]["test"])]
                self.assertEqual(sens["input"], train)
                self.assertEqual(sens["truth"], train + test)
                self.assertEqual(sens["relit"], test)
                self.assertFalse([s for s in roots["relit"].findall("shape") if s.find("emitter") is not None])
                ids = [s.get("id") for s in roots["truth"].findall("shape")]
                self.assertEqual(ids, [s["id"] for s in meta["shapes"]])
                for sid in ids:
                    self.assertRegex(sid, r"^[A-Za-z0-9_]+$")
                    self.assertTrue(os.path.exists(os.path.join(d, "meshes", f"{sid}.obj")))
                for r in roots.values():
                    for st in r.iter("string"):
                        if st.get("name") == "filename":
                            self.assertTrue(os.path.exists(os.path.join(d, st.get("value"))), st.get("value"))
                    integ = r.find("integrator")
                    vals = {i.get("name"): i.get("value") for i in integ.findall("integer")}
                    self.assertEqual((integ.get("type"), vals), ("path", {"max_depth": "-1", "rr_depth": "8"}))
                if p in KDMAP_PRESETS:
                    self.check_kdmap_input(roots["input"])
                if p == "room":
                    self.assertGreaterEqual(meta["totals"]["triangles"], 1_000_000)
                    self.assertGreaterEqual(len(ids), 18)
                    self.assertEqual(gs.PRESETS[p]["res"], (512, 384))
                if p == "room-small":
                    self.assertLess(meta["totals"]["triangles"], 10_000)
                if p == "mirror-cbox":
                    types = {b.get("type") for b in roots["input"].findall("bsdf")}
                    self.assertTrue({"conductor", "dielectric"} <= types)
                    self.assertTrue(all(s.find("ref") is not None for s in roots["input"].findall("shape")))
                    self.assertTrue(all(f.get("type") == "tent" for f in roots["truth"].iter("rfilter")))
                if p == "envmap":
                    em = [e.get("type") for e in roots["truth"].iter("emitter")]
                    self.assertEqual(em, ["envmap"])
                    self.assertTrue(os.path.exists(os.path.join(d, "textures", "sky.exr")))

    def check_kdmap_input(self, root):
        for sh in root.findall("shape"):
            self.assertEqual(sh.get("type"), "obj")
            b = sh.find("bsdf")
            em = sh.find("emitter")
            if b.get("type") == "twosided":
                b = b.find("bsdf")
            self.assertEqual(b.get("type"), "diffuse")
            want = "0, 0, 0" if em is not None else "0.5, 0.5, 0.5"
            self.assertEqual(b.find("rgb").get("value"), want)
            if em is not None:
                self.assertEqual(em.get("type"), "area")
        for e in root.findall("emitter"):
            self.assertIn(e.get("type"), ("point", "spot", "directional"))
        for s in root.findall("sensor"):
            self.assertEqual(s.get("type"), "perspective")
            self.assertEqual(s.find("film").get("type"), "hdrfilm")
            self.assertEqual(s.find("film/rfilter").get("type"), "box")
            self.assertEqual(s.find("sampler").get("type"), "independent")
            self.assertIn("fov_axis", [x.get("name") for x in s.findall("string")])
        self.assertFalse(root.findall("texture"))

    def test_meshes(self):
        import json

        for p, d in self.dirs.items():
            if p == "room":
                continue  # 100 MB of text; its builders are the same as room-small's
            meta = json.loads(read(os.path.join(d, "scene.json")))
            for sh in meta["shapes"]:
                with self.subTest(preset=p, shape=sh["id"]):
                    v, vt, vn, f = read_obj(os.path.join(d, "meshes", f"{sh['id']}.obj"))
                    self.assertEqual((len(v), len(f)), (sh["vertices"], sh["triangles"]))
                    self.assertEqual(f.shape[1:], (3, 3))
                    for k, arr in enumerate((v, vt, vn)):
                        self.assertGreaterEqual(f[..., k].min(), 1)
                        self.assertLessEqual(f[..., k].max(), len(arr))
                    self.assertTrue(np.allclose(np.linalg.norm(vn, axis=1), 1, atol=1e-4))
                    a, b, c = (v[f[:, i, 0] - 1] for i in range(3))
                    g = np.cross(b - a, c - a)
                    area = 0.5 * np.linalg.norm(g, axis=1)
                    self.assertGreater(area.min(), 0)
                    self.assertAlmostEqual(area.sum(), sh["area_m2"], delta=1e-3 * max(1, sh["area_m2"]))
                    ns = vn[f[..., 2] - 1].sum(1)
                    self.assertTrue(((g * ns).sum(1) > 0).all(), "winding disagrees with normals")

    def test_same_seed_same_files_and_reuse(self):
        d = self.dirs["room-small"]
        out = run("--preset", "room-small", d, "--dry-run")
        self.assertIn("skipping", out)
        d2 = os.path.join(self.tmp.name, "again")
        run("--preset", "room-small", d2, "--dry-run")
        for sub in ("input.xml", "truth.xml", "relit.xml", "meshes/floor.obj", "meshes/sphere_0.obj",
                    "textures/floor.png"):
            self.assertEqual(read(os.path.join(d, sub)), read(os.path.join(d2, sub)), sub)
        d3 = os.path.join(self.tmp.name, "seed2")
        run("--preset", "room-small", d3, "--dry-run", "--seed", "2")
        self.assertNotEqual(read(os.path.join(d, "truth.xml")), read(os.path.join(d3, "truth.xml")))

    def test_overrides(self):
        d = os.path.join(self.tmp.name, "custom")
        run("--preset", "room-small", d, "--dry-run", "--objects", "table:1,chair:3,sphere:5,torus:2",
            "--train", "7", "--test", "1", "--res", "64x48", "--lights", "point:2,spot:1", "--textures", "none")
        root = ET.parse(os.path.join(d, "truth.xml")).getroot()
        self.assertEqual(len(root.findall("sensor")), 8)
        self.assertEqual([e.get("type") for e in root.findall("emitter")], ["point", "point", "spot"])
        self.assertFalse(list(root.iter("texture")))
        ids = [s.get("id") for s in root.findall("shape")]
        self.assertEqual(sum(i.startswith("sphere_") for i in ids), 5)
        self.assertEqual(root.find("sensor/film/integer").get("value"), "64")

    def test_mitsuba_loads(self):
        try:
            import mitsuba as mi

            mi.set_variant("scalar_rgb")
        except Exception:  # noqa: BLE001
            self.skipTest("Mitsuba not installed")
        for p, d in self.dirs.items():
            if p == "room":
                continue
            for w in ("truth", "relit", "input"):
                with self.subTest(preset=p, file=w):
                    sc = mi.load_file(os.path.join(d, f"{w}.xml"), optimize=False)
                    self.assertEqual(len(sc.shapes()), len(ET.parse(os.path.join(d, f"{w}.xml")).getroot().findall("shape")))


class Builders(unittest.TestCase):
    def test_areas(self):
        s = gs.uv_sphere((0, 0, 0), 2.0, 20000)
        self.assertAlmostEqual(s.area(), 4 * math.pi * 4, delta=0.01 * 16 * math.pi)
        t = gs.torus((0, 0, 0), 1.0, 0.25, 20000)
        self.assertAlmostEqual(t.area(), 4 * math.pi ** 2 * 0.25, delta=0.01 * math.pi ** 2)
        c = gs.cylinder((0, 0, 0), 0.5, 2.0, 20000, ("top", "bottom"))
        self.assertAlmostEqual(c.area(), 2 * math.pi * 0.5 * 2 + 2 * math.pi * 0.25, delta=0.05)
        b = gs.box((0, 0, 0), (1, 2, 3), 0.5)
        self.assertAlmostEqual(b.area(), 2 * (2 + 3 + 6), places=9)
        for m in (s, c, b):
            # outward: normals point away from the centre of the bounding box
            lo, hi = m.bbox()
            cen = m.v[m.f].mean(1)
            self.assertGreater(((cen - (lo + hi) / 2) * m.n[m.f].sum(1)).sum(1).min(), -1e-9)
        # the torus's normals point away from its core circle (radius 1 in the xz plane)
        cen = t.v[t.f].mean(1)
        core = cen * np.array([1.0, 0.0, 1.0])
        core /= np.linalg.norm(core, axis=1, keepdims=True)
        self.assertGreater(((cen - core) * t.n[t.f].sum(1)).sum(1).min(), 0)

    def test_triangle_budget(self):
        for n in (1000, 140000):
            for m in (gs.uv_sphere((0, 0, 0), 1, n), gs.torus((0, 0, 0), 1, 0.3, n), gs.cylinder((0, 0, 0), 1, 1, n)):
                self.assertLess(abs(len(m.f) - n) / n, 0.15)


if __name__ == "__main__":
    argv = [a for a in sys.argv if a != "--quick"]
    unittest.main(argv=argv, verbosity=2)
