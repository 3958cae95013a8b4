#!/usr/bin/env python3
"""Unit tests of tools/bitterli_scene.py's conversion and cameras (standard library only, no
rendering).

    python3 tools/test_bitterli_scene.py
"""

import math
import os
import sys
import unittest
import xml.etree.ElementTree as ET

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import bitterli_scene as bs  # noqa: E402

SRC = """<scene version="0.5.0">
  <integrator type="path"><integer name="maxDepth" value="65"/></integrator>
  <sensor type="perspective"><float name="fov" value="35"/>
    <transform name="toWorld"><matrix value="-1 0 0 0 0 1 0 1.5 0 0 -1 5 0 0 0 1"/></transform>
    <film type="hdrfilm"><integer name="width" value="720"/><integer name="height" value="1280"/>
      <string name="fileFormat" value="openexr"/></film></sensor>
  <bsdf type="twosided" id="Floor"><bsdf type="roughplastic">
    <float name="intIOR" value="1.5"/><boolean name="nonlinear" value="true"/>
    <texture name="diffuseReflectance" type="bitmap">
      <string name="filename" value="textures/Wood.jpg"/><string name="filterType" value="bilinear"/>
    </texture></bsdf></bsdf>
  <bsdf type="bumpmap"><texture name="map" type="bitmap">
      <string name="filename" value="textures/Bump.jpg"/></texture>
    <bsdf type="twosided" id="Metal"><bsdf type="roughconductor">
      <rgb name="specularReflectance" value="0.5, 0.5, 0.5"/></bsdf></bsdf></bsdf>
  <bsdf type="mask" id="Leaves"><texture name="opacity" type="bitmap">
      <string name="filename" value="textures/leaf.png"/></texture>
    <bsdf type="twosided"><bsdf type="diffuse"><rgb name="reflectance" value="0.1, 0.2, 0.3"/>
    </bsdf></bsdf></bsdf>
  <shape type="obj"><string name="filename" value="models/Mesh007.obj"/>
    <boolean name="faceNormals" value="true"/><ref id="Floor"/></shape>
  <shape type="obj"><string name="filename" value="models/Mesh008.obj"/><ref id="Metal"/></shape>
  <shape type="obj"><string name="filename" value="models/Mesh009.obj"/><ref id="Leaves"/></shape>
  <shape type="rectangle"><emitter type="area"><rgb name="radiance" value="30, 30, 30"/>
  </emitter></shape>
</scene>"""


def convert():
    return bs.upgrade(ET.fromstring(SRC), "/src")


class Convert(unittest.TestCase):
    def test_mitsuba3_names_and_absolute_paths(self):
        root = convert()
        self.assertEqual(root.get("version"), "3.0.0")
        self.assertEqual(root.findall("sensor") + root.findall("integrator"), [])
        names = {e.get("name") for e in root.iter() if e.get("name")}
        self.assertIn("int_ior", names)
        self.assertIn("face_normals", names)
        self.assertIn("filter_type", names)
        self.assertIn("diffuse_reflectance", names)
        self.assertNotIn("intIOR", names)
        files = [e.get("value") for e in root.iter() if e.get("name") == "filename"]
        self.assertIn("/src/textures/Wood.jpg", files)
        self.assertTrue(all(f.startswith("/src/") for f in files))

    def test_bumpmaps_and_masks_dropped_ids_kept(self):
        root = convert()
        types = [b.get("type") for b in root.iter("bsdf")]
        self.assertNotIn("bumpmap", types)
        self.assertNotIn("mask", types)
        ids = {b.get("id"): b.get("type") for b in root.findall("bsdf")}
        self.assertEqual(ids, {"Floor": "twosided", "Metal": "twosided", "Leaves": "twosided"})
        self.assertEqual([b.get("id") for b in root.findall("bsdf")], ["Floor", "Metal", "Leaves"])

    def test_plastics_linear_shapes_named(self):
        root = convert()
        self.assertIsNone(root.find(".//bsdf[@type='roughplastic']/boolean[@name='nonlinear']"))
        self.assertEqual([s.get("id") for s in root.findall("shape")],
                         ["Mesh007", "Mesh008", "Mesh009", "rect_0"])

    def test_input_has_every_diffuse_and_base_at_half_known_kept(self):
        root = convert()
        bs.to_unknown(root)
        base = root.findall(".//bsdf[@type='roughplastic']/*[@name='diffuse_reflectance']")
        self.assertEqual([(b.tag, b.get("value")) for b in base], [("rgb", "0.5, 0.5, 0.5")])
        refl = root.findall(".//bsdf[@type='diffuse']/*[@name='reflectance']")
        self.assertEqual([b.get("value") for b in refl], ["0.5, 0.5, 0.5"])
        spec = root.find(".//bsdf[@type='roughconductor']/rgb")
        self.assertEqual(spec.get("value"), "0.5, 0.5, 0.5")
        self.assertEqual(root.find(".//emitter/rgb").get("value"), "30, 30, 30")

    def test_relit_light_is_dimmer_and_warm(self):
        root = convert()
        bs.relight(root)
        v = [float(x) for x in root.find(".//emitter/rgb").get("value").split(",")]
        self.assertEqual(v, [14.4, 12.0, 9.0])


class Cameras(unittest.TestCase):
    def test_anchor_reads_mitsuba_frame(self):
        o, f, up, fov, aspect = bs.anchor(ET.fromstring(SRC).find("sensor"))
        self.assertEqual((o, f, up, fov), ((0.0, 1.5, 5.0), (0.0, 0.0, -1.0), (0.0, 1.0, 0.0), 35.0))
        self.assertAlmostEqual(aspect, 720 / 1280)

    def test_poses_symmetric_held_out_between_and_stopped_by_geometry(self):
        o, f, up = (0.0, 1.5, 5.0), (0.0, 0.0, -1.0), (0.0, 1.0, 0.0)
        cams = bs.poses(o, f, up, 4, 2, 20.0, 1.0, lambda a, b: 1.0)
        train = [c for c in cams if "train" in c[0]]
        test = [c for c in cams if "test" in c[0]]
        self.assertEqual([c[0] for c in cams],
                         ["cam_train_0", "cam_train_1", "cam_train_2", "cam_train_3",
                          "cam_test_0", "cam_test_1"])
        for a, b in zip(train, reversed(train)):  # mirror images in x
            self.assertAlmostEqual(a[1][0], -b[1][0], places=12)
            self.assertAlmostEqual(a[2][0], -b[2][0], places=12)
        xs = sorted(c[1][0] for c in train)
        self.assertTrue(all(xs[0] < c[1][0] < xs[-1] for c in test))
        yaw = math.degrees(math.atan2(-train[0][2][0], -train[0][2][2]))
        self.assertAlmostEqual(abs(yaw), 20.0, places=9)
        for _, p, d in cams:  # level held-out views, every camera at the anchor's height
            self.assertAlmostEqual(p[1], 1.5, places=12)
        self.assertTrue(all(abs(d[1]) < 1e-12 for _, _, d in test))
        blocked = bs.poses(o, f, up, 4, 2, 20.0, 1.0, lambda a, b: 0.0)
        self.assertTrue(all(p == o for _, p, _ in blocked))


if __name__ == "__main__":
    unittest.main()
