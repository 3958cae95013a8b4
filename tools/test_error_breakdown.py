#!/usr/bin/env python3
"""Unit test of tools/error_breakdown.py's numpy parts on synthetic arrays whose breakdown is
known (no rendering; Mitsuba is imported only because heldout.py's EXR reader is).

    .venv/bin/python tools/test_error_breakdown.py

An error placed only in filled texels shows up 100% in that class; a global per-channel scale
error is 100% removed by the global colour correction, per-shape scales by the per-shape one;
an error that alternates pixel by pixel is high-frequency, a smooth one is not; edges, creases,
chart borders and the bilinear observed share on hand-made cases.
"""

import math
import os
import sys
import unittest

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import error_breakdown as eb  # noqa: E402


def synthetic(a_img, t_img, shape_img, obs_img=None, known=None):
    """One view and its meta as collect() returns them, every pixel judged, no edges."""
    h, w, _ = t_img.shape
    judged = np.ones((h, w), bool)
    obs = np.ones(h * w) if obs_img is None else obs_img.reshape(-1).astype(np.float64)
    e, _ = eb.rel_error(a_img, t_img)
    flat = judged.reshape(-1)
    v = dict(a=a_img[judged], t=t_img[judged], e=e[judged], a_img=a_img, t_img=t_img,
             judged=judged, shape_img=shape_img, shape=shape_img[judged], obs=obs[flat],
             fill_dist=np.where(obs[flat] > 0, 0, 5),
             border=np.zeros(h * w, bool), boundary=np.zeros(h * w, bool),
             crease=np.zeros(h * w, bool), via_hemi=np.zeros(h * w), via_emit=np.zeros(h * w))
    nshape = int(shape_img.max()) + 1
    meta = dict(shape_ids=[f"s{k}" for k in range(nshape)], kinds=["diffuse"] * nshape,
                known=np.zeros(nshape, bool) if known is None else known, observed={},
                covered={}, cov_texels={})
    return {"v0": v}, meta


def smooth_truth(h=32, w=32):
    y, x = np.mgrid[0:h, 0:w]
    t = np.stack([0.3 + 0.2 * x / w, 0.4 + 0.1 * y / h, 0.5 + 0.0 * x], -1)
    return t


class Classes(unittest.TestCase):
    def test_error_only_in_filled_texels(self):
        t = smooth_truth()
        obs = np.ones(t.shape[:2])
        obs[5:12, 7:20] = 0.0  # filled
        a = t.copy()
        a[obs == 0] *= 1.3
        views, meta = synthetic(a, t, np.zeros(t.shape[:2], np.int64), obs)
        res = eb.analyse(views, meta, sigma=1.0)
        self.assertAlmostEqual(res["classes"]["filled"]["share_of_e2"], 1.0, places=12)
        self.assertAlmostEqual(res["classes"]["filled"]["share_of_e"], 1.0, places=12)
        self.assertAlmostEqual(res["classes"]["filled"]["mean"], 0.3, places=12)
        self.assertEqual(res["classes"]["observed"]["share_of_e2"], 0.0)
        self.assertAlmostEqual(res["classes"]["filled, 3-8 tx"]["share_of_e2"], 1.0, places=12)
        self.assertAlmostEqual(res["classes"]["filled"]["share_of_pixels"], 7 * 13 / 1024)
        self.assertAlmostEqual(res["exclusive"]["filled"]["share_of_e2"], 1.0, places=12)
        self.assertAlmostEqual(res["classes"]["filled"]["share_of_l1"], 1.0, places=12)
        self.assertAlmostEqual(res["classes"]["filled"]["rel_l1"], 0.3, places=12)
        # the exclusive classes partition the pixels and the error
        self.assertAlmostEqual(sum(s["share_of_pixels"] for s in res["exclusive"].values()), 1.0)
        self.assertAlmostEqual(sum(s["share_of_e2"] for s in res["exclusive"].values()), 1.0)
        # the judge's figures
        self.assertAlmostEqual(res["judge"]["albedo_mean_rel_error"], 0.3 * 7 * 13 / 1024)

    def test_exclusive_order(self):
        c = {"x": np.array([1, 1, 0, 0], bool), "y": np.array([0, 1, 1, 0], bool),
             "rest": np.ones(4, bool)}
        np.testing.assert_array_equal(eb.exclusive(["x", "y", "rest"], c, 4), [0, 0, 1, 2])

    def test_known_material_and_light_via_known(self):
        t = smooth_truth(8, 8)
        shape = np.zeros((8, 8), np.int64)
        shape[:, 4:] = 1
        a = t * 1.1
        views, meta = synthetic(a, t, shape, known=np.array([False, True]))
        v = views["v0"]
        v["via_emit"][:8] = 0.125  # first row of shape 0 lit through known (and row 0 of shape 1)
        c, ex = eb.classes_of(v, meta["known"])
        self.assertEqual(int(c["known material"].sum()), 32)
        self.assertEqual(int(c["lit through known"].sum()), 4)  # only the diffuse shape's pixels
        lab = eb.exclusive(eb.CLASS_ORDER, ex, 64)
        self.assertEqual(int((lab == 0).sum()), 32)
        self.assertEqual(int((lab == 1).sum()), 4)


class ColourBias(unittest.TestCase):
    def test_global_scale_is_removed(self):
        t = smooth_truth()
        a = t * np.array([1.2, 0.9, 1.05])
        views, meta = synthetic(a, t, np.zeros(t.shape[:2], np.int64))
        res = eb.analyse(views, meta, sigma=1.0)
        cb = res["colour_bias"]
        np.testing.assert_allclose(cb["global_scale"], [1 / 1.2, 1 / 0.9, 1 / 1.05], rtol=1e-12)
        self.assertAlmostEqual(cb["global_removes_share_of_e2"], 1.0, places=12)
        self.assertAlmostEqual(cb["global_mean_after"], 0.0, places=12)
        np.testing.assert_allclose(cb["global_scale_l1"], cb["global_scale"], rtol=1e-12)
        self.assertAlmostEqual(cb["global_rel_l1_after"], 0.0, places=12)
        self.assertGreater(res["judge"]["albedo_rel_l1"], 0.05)
        self.assertGreater(res["judge"]["albedo_mean_rel_error"], 0.05)

    def test_per_shape_scales_are_removed_by_the_per_shape_correction_only(self):
        t = smooth_truth()
        shape = np.zeros(t.shape[:2], np.int64)
        shape[16:] = 1
        a = t.copy()
        a[:16] *= np.array([1.3, 1.0, 0.8])
        a[16:] *= np.array([0.7, 1.1, 1.2])
        views, meta = synthetic(a, t, shape)
        res = eb.analyse(views, meta, sigma=1.0)
        cb = res["colour_bias"]
        self.assertAlmostEqual(cb["per_shape_removes_share_of_e2"], 1.0, places=12)
        self.assertAlmostEqual(cb["per_shape_rel_l1_after"], 0.0, places=12)
        self.assertGreater(cb["global_rel_l1_after"], 0.05)
        self.assertLess(cb["global_removes_share_of_e2"], 0.5)
        for s in res["shapes"]:
            self.assertAlmostEqual(s["mean_after_scale"], 0.0, places=12)
        self.assertAlmostEqual(sum(s["share_of_l1"] for s in res["shapes"]), 1.0)

    def test_scale_minimises_the_mean(self):
        rng = np.random.default_rng(3)
        t = rng.uniform(0.05, 0.9, (500, 3))
        a = t * rng.uniform(0.7, 1.4, (500, 3))
        s = eb.channel_scale(a, t)

        def mean_err(sc):
            return (np.abs(a * sc - t).sum(-1) / t.sum(-1)).mean()

        best = mean_err(s)
        for c in range(3):
            for d in (-1e-3, 1e-3):
                s2 = s.copy()
                s2[c] += d
                self.assertGreaterEqual(mean_err(s2), best - 1e-15)


class TextureDetail(unittest.TestCase):
    def test_alternating_error_is_high_frequency_smooth_error_is_not(self):
        t = smooth_truth()
        y, x = np.mgrid[0:32, 0:32]
        sign = np.where((x + y) % 2 == 0, 1.0, -1.0)[..., None]
        views, meta = synthetic(t * (1 + 0.2 * sign), t, np.zeros((32, 32), np.int64))
        res = eb.analyse(views, meta, sigma=2.0)
        self.assertGreater(res["texture_detail"]["high_frequency_share_of_e2"], 0.97)
        views, meta = synthetic(t * 1.2, t, np.zeros((32, 32), np.int64))
        res = eb.analyse(views, meta, sigma=2.0)
        self.assertLess(abs(res["texture_detail"]["high_frequency_share_of_e2"]), 1e-9)

    def test_lowpass_stays_within_a_shape(self):
        img = np.zeros((10, 10, 3))
        img[:, 5:] = 1.0
        lab = np.zeros((10, 10), np.int64)
        lab[:, 5:] = 1
        out = eb.lowpass_within(img, lab, np.ones((10, 10), bool), 2.0)
        np.testing.assert_allclose(out, img, atol=1e-12)


class Geometry(unittest.TestCase):
    def test_bilinear_observed(self):
        obs = np.zeros((4, 4), bool)
        obs[:, :2] = True
        # texel centres
        uv = np.array([[0.5 / 4, 0.5 / 4], [2.5 / 4, 1.5 / 4], [2.0 / 4, 2.5 / 4]])
        np.testing.assert_allclose(eb.bilinear_observed(obs, uv), [1.0, 0.0, 0.5])

    def test_fill_distance(self):
        obs = np.zeros((1, 12), bool)
        obs[0, 2] = True
        np.testing.assert_array_equal(eb.fill_distance(obs, 8)[0],
                                      [2, 1, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9])

    def test_border_texels(self):
        cov = np.zeros((10, 10), bool)
        cov[2:8, 2:8] = True
        b = eb.border_texels(cov, 1)
        self.assertTrue(b[2, 4] and b[7, 7] and not b[3, 3] and not b[0, 0])
        self.assertEqual(int(b.sum()), 36 - 16)
        self.assertTrue(eb.border_texels(np.ones((3, 3), bool), 1)[0, 0])  # texture edge

    def test_boundary_pixels(self):
        s = np.zeros((6, 6), np.int64)
        s[:, 3:] = 1
        b = eb.boundary_pixels(s, 1)
        np.testing.assert_array_equal(np.flatnonzero(b[0]), [2, 3])
        np.testing.assert_array_equal(np.flatnonzero(eb.boundary_pixels(s, 2)[0]), [1, 2, 3, 4])

    def test_crease_and_step(self):
        h, w = 6, 8
        y, x = np.mgrid[0:h, 0:w].astype(np.float64)
        # a plane z = 0 seen from above (distance 10), then a step up by 1 at x >= 4
        p = np.stack([x * 0.1, y * 0.1, np.where(x >= 4, 1.0, 0.0)], -1)
        n = np.zeros((h, w, 3))
        n[..., 2] = 1.0
        t = np.full((h, w), 10.0)
        valid = np.ones((h, w), bool)
        c = eb.crease_pixels(p, n, t, valid, 1)
        np.testing.assert_array_equal(np.flatnonzero(c[0]), [3, 4])
        # a slanted plane alone is no step
        p2 = np.stack([x * 0.1, y * 0.1, x * 0.05], -1)  # z = 0.5 X
        n2 = np.zeros((h, w, 3))
        n2[..., 0], n2[..., 2] = -0.5 / math.sqrt(1.25), 1 / math.sqrt(1.25)
        self.assertFalse(eb.crease_pixels(p2, n2, t, valid, 1).any())
        # a normal turning by 90 degrees is a crease
        n3 = n.copy()
        n3[:, 6:] = [1.0, 0.0, 0.0]
        p3 = np.stack([x * 0.1, y * 0.1, 0 * x], -1)
        np.testing.assert_array_equal(np.flatnonzero(eb.crease_pixels(p3, n3, t, valid, 1)[0]),
                                      [5, 6])


if __name__ == "__main__":
    unittest.main()
