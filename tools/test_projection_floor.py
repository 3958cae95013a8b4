#!/usr/bin/env python3
"""Unit test of tools/projection_floor.py's run config (no rendering, no kdmap run).

    .venv/bin/python tools/test_projection_floor.py

The config it writes must parse as TOML to the run's settings with the scene and the views
replaced; configs it cannot carry over faithfully (their own views, nested tables, values of
other types) are refused, not silently changed.
"""

import os
import sys
import tempfile
import tomllib
import unittest

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import projection_floor as pf  # noqa: E402


class FloorConfig(unittest.TestCase):
    def test_settings_survive_with_scene_and_views_replaced(self):
        cfg = tomllib.loads(
            'scene = "rel/input.xml"\nseed = 7\n[projection]\nrefine_passes = 8\n'
            'refine_step = 1.5\n[atlas]\ntexels_per_unit = "auto"\n[solver]\nfoo = true\n'
        )
        views = {"cam_train_1": "/a/b 1.exr", "cam_train_0": '/q"x/c0.exr'}
        got = tomllib.loads(pf.floor_config(cfg, "/s/input.xml", views))
        self.assertEqual(got["scene"], "/s/input.xml")
        self.assertEqual(got["seed"], 7)
        self.assertEqual(got["projection"], {"refine_passes": 8, "refine_step": 1.5})
        self.assertEqual(got["atlas"], {"texels_per_unit": "auto"})
        self.assertIs(got["solver"]["foo"], True)
        # albedo images are read as they are: no exposure estimate
        self.assertEqual(got["views"], {"exposure": "known", **views})

    def test_no_config_gives_scene_and_views_only(self):
        got = tomllib.loads(pf.floor_config({}, "/s/in.xml", {"c": "/c.exr"}))
        want = {"scene": "/s/in.xml", "views": {"exposure": "known", "c": "/c.exr"}}
        self.assertEqual(got, want)

    def test_configs_it_cannot_carry_are_refused(self):
        with self.assertRaisesRegex(ValueError, r"\[views\]"):
            pf.floor_config({"views": {"c": "x.exr"}}, "/s.xml", {})
        with self.assertRaisesRegex(ValueError, "nested"):
            pf.floor_config({"a": {"b": {"c": 1}}}, "/s.xml", {})
        with self.assertRaisesRegex(ValueError, "unsupported"):
            pf.floor_config({"a": [1, 2]}, "/s.xml", {})


class Measure(unittest.TestCase):
    """Bad input is refused before any rendering or projection."""

    def test_a_directory_that_is_not_a_run_is_refused(self):
        with tempfile.TemporaryDirectory() as d:
            with self.assertRaisesRegex(pf.FloorError, "textures: no"):
                pf.measure(d, d, kdmap="/nonexistent/kdmap")

    def test_a_config_with_views_is_refused_before_rendering(self):
        with tempfile.TemporaryDirectory() as d:
            os.makedirs(os.path.join(d, "textures"))
            open(os.path.join(d, "textures", "a_albedo.exr"), "w").close()
            with self.assertRaisesRegex(pf.FloorError, r"run.toml: .*\[views\]"):
                pf.measure(d, d, {"views": {"c": "x.exr"}}, kdmap="/nonexistent/kdmap",
                           cfg_name="run.toml")
            self.assertFalse(os.path.exists(os.path.join(d, "albedo")), "nothing rendered")


if __name__ == "__main__":
    unittest.main()
