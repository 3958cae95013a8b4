#!/usr/bin/env python3
"""Unit test of tools/mitsuba_inverse.py's parameter lookup (no Mitsuba, no rendering).

    .venv/bin/python tools/test_mitsuba_inverse.py

Each optimised shape's reflectance must be found whether its diffuse BSDF is bare or inside a
twosided wrapper (the generated open scene's ground: `ground.bsdf.brdf_0.reflectance.data`,
which the anchor used to refuse), and a shape with none or an ambiguous one is reported, not
silently optimised through the wrong parameter.
"""

import os
import sys
import unittest

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import mitsuba_inverse as mi_inv  # noqa: E402


class ReflectanceKey(unittest.TestCase):
    KEYS = [
        "box_0.bsdf.reflectance.data",
        "box_0.vertex_positions",
        "ground.bsdf.brdf_0.reflectance.data",
        "ground.vertex_positions",
        "groundling.bsdf.reflectance.data",
        "mixed.bsdf.bsdf_0.reflectance.data",
        "mixed.bsdf.bsdf_1.reflectance.data",
        "sensor.to_world",
    ]

    def test_bare_diffuse(self):
        self.assertEqual(mi_inv.reflectance_key(self.KEYS, "box_0"), "box_0.bsdf.reflectance.data")

    def test_twosided_wrapper(self):
        self.assertEqual(mi_inv.reflectance_key(self.KEYS, "ground"),
                         "ground.bsdf.brdf_0.reflectance.data")

    def test_missing_or_ambiguous(self):
        self.assertIsNone(mi_inv.reflectance_key(self.KEYS, "sensor"))
        self.assertIsNone(mi_inv.reflectance_key(self.KEYS, "mixed"))


if __name__ == "__main__":
    unittest.main()
