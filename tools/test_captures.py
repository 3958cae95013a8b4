#!/usr/bin/env python3
"""Unit test of tools/captures.py: variant names, and the run config written for a capture
(8-bit: the first view's recorded gain pinned, the others listed; moved poses: refined; HDR:
the scene alone).
Standard library only; no rendering.

    .venv/bin/python tools/test_captures.py
"""

import json
import os
import sys
import tempfile
import tomllib
import unittest

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import captures  # noqa: E402


TO_WORLD = [[0.0, -2.0, 0.0, 1.5], [2.0, 0.0, 0.0, -0.25], [0.0, 0.0, 2.0, 3.0],
            [0.0, 0.0, 0.0, 1.0]]


def write_capture(d, ldr, colmap=False, pose=False):
    views = {f"cam_train_{i}": {"index": i, "image": f"images/cam_train_{i}.jpg",
                                "factor": [2.0 + i, 2.5, 3.0]} for i in (2, 0, 1)}
    cap = {"ldr": {"format": "jpg"} if ldr else None, "views": views,
           "options": {"pose_deg": 0.3 if pose else 0.0, "pose_dist": 0.005 if pose else 0.0}}
    if colmap:
        cap["colmap"] = {"dir": "sparse", "to_world": TO_WORLD}
    with open(os.path.join(d, "capture.json"), "w") as f:
        json.dump(cap, f)


class Captures(unittest.TestCase):
    def test_names(self):
        self.assertEqual(captures.split("cbox-tex-jpeg"), ("cbox-tex", "jpeg"))
        self.assertEqual(captures.split("cbox-all"), ("cbox", "all"))
        for bad in ("cbox", "cbox-tex-blur", "-jpeg"):
            with self.assertRaises(ValueError):
                captures.split(bad)
        for v in captures.DEFAULT:
            captures.split(v)

    def test_8bit_capture_pins_the_first_view(self):
        with tempfile.TemporaryDirectory() as d:
            write_capture(d, ldr=True)
            path, pinned = captures.run_config(d)
            self.assertEqual(pinned, "cam_train_0")
            with open(path, "rb") as f:
                cfg = tomllib.load(f)
            self.assertEqual(cfg["scene"], os.path.join(d, "input.xml"))
            v = cfg["views"]
            self.assertEqual(v["exposure"], "estimate")
            self.assertEqual(v["cam_train_0"]["exposure"], [2.0, 2.5, 3.0])
            self.assertEqual(v["cam_train_0"]["photo"], os.path.join(d, "images/cam_train_0.jpg"))
            self.assertEqual(v["cam_train_2"], os.path.join(d, "images/cam_train_2.jpg"))

    def test_a_colmap_capture_names_its_model_and_similarity(self):
        with tempfile.TemporaryDirectory() as d:
            write_capture(d, ldr=True, colmap=True)
            path, pinned = captures.run_config(d)
            with open(path, "rb") as f:
                v = tomllib.load(f)["views"]
            self.assertEqual(v["colmap"], os.path.join(d, "sparse"))
            self.assertEqual(v["to_world"], TO_WORLD)
            self.assertEqual(pinned, "cam_train_0")

    def test_moved_poses_are_refined(self):
        with tempfile.TemporaryDirectory() as d:
            write_capture(d, ldr=False, pose=True)
            path, _ = captures.run_config(d)
            with open(path, "rb") as f:
                self.assertIs(tomllib.load(f)["views"]["refine_pose"], True)

    def test_hdr_capture_is_the_scene_alone(self):
        with tempfile.TemporaryDirectory() as d:
            write_capture(d, ldr=False)
            path, pinned = captures.run_config(d)
            self.assertIsNone(pinned)
            with open(path, "rb") as f:
                self.assertEqual(tomllib.load(f), {"scene": os.path.join(d, "input.xml")})


if __name__ == "__main__":
    unittest.main()
