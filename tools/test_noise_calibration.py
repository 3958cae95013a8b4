#!/usr/bin/env python3
"""Unit test of tools/noise_calibration.py (no rendering, no kdmap run).

    .venv/bin/python tools/test_noise_calibration.py

The measured / predicted ratio is 1 for a standard error that states the noise the photos
put in, 2 for one that states half of it; texels either run misses are left out; bad input is
refused before anything is rendered.
"""

import os
import subprocess
import sys
import tempfile
import unittest

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import noise_calibration as nc  # noqa: E402


class Ratio(unittest.TestCase):
    def maps(self, sigma=0.04, n=200_000):
        rng = np.random.default_rng(3)
        k = rng.uniform(0.1, 0.8, n)
        a = k * (1 + sigma * rng.standard_normal(n))
        b = k * (1 + sigma * rng.standard_normal(n))
        return a, b

    def test_a_calibrated_standard_error_gives_one(self):
        a, b = self.maps()
        n, meas, pred = nc.noise_ratio(a, b, 0.04 * a)
        self.assertEqual(n, len(a))
        self.assertAlmostEqual(meas, 0.04, delta=0.002)
        self.assertAlmostEqual(meas / pred, 1.0, delta=0.05)

    def test_half_the_noise_gives_two_and_unobserved_texels_are_left_out(self):
        a, b = self.maps()
        b[:1000] = 0.0
        se = 0.02 * a
        se[1000:2000] = 0.0
        n, meas, pred = nc.noise_ratio(a, b, se)
        self.assertEqual(n, len(a) - 2000)
        self.assertAlmostEqual(meas / pred, 2.0, delta=0.1)

    def test_too_few_texels_give_nan(self):
        n, meas, _ = nc.noise_ratio([0.5], [0.5], [0.1])
        self.assertEqual(n, 1)
        self.assertTrue(np.isnan(meas))


class BadInput(unittest.TestCase):
    def run_tool(self, *args):
        return subprocess.run([sys.executable, os.path.join(os.path.dirname(nc.__file__),
                                                            "noise_calibration.py"), *args],
                              capture_output=True, text=True)

    def test_a_directory_without_a_scene_is_refused_in_one_line(self):
        with tempfile.TemporaryDirectory() as d:
            r = self.run_tool(d, "--work", os.path.join(d, "w"))
            self.assertNotEqual(r.returncode, 0)
            self.assertIn("truth.xml: missing", r.stderr)
            self.assertEqual(len(r.stderr.strip().splitlines()), 1, r.stderr)
            self.assertFalse(os.path.exists(os.path.join(d, "w")), "nothing made")

    def test_a_config_with_its_own_views_is_refused_before_rendering(self):
        with tempfile.TemporaryDirectory() as d:
            for f in ("truth.xml", "input.xml"):
                open(os.path.join(d, f), "w").write("<scene/>")
            os.makedirs(os.path.join(d, "images"))
            open(os.path.join(d, "images", "cam_train_0.exr"), "w").write("")
            cfg = os.path.join(d, "run.toml")
            open(cfg, "w").write('[views]\ncam_train_0 = "x.exr"\n')
            r = self.run_tool(d, "--work", os.path.join(d, "w"), "--config", cfg)
            self.assertNotEqual(r.returncode, 0)
            self.assertIn("[views]", r.stderr)
            self.assertFalse(os.path.exists(os.path.join(d, "w")), "nothing rendered")


if __name__ == "__main__":
    unittest.main()
