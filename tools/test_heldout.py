#!/usr/bin/env python3
"""Unit test of tools/heldout.py's image figures (no rendering; needs numpy, and Mitsuba only
because heldout.py imports its EXR reader lazily).

    .venv/bin/python tools/test_heldout.py

Checks block_error_seen against hand-computed values: only 8x8 blocks seen throughout count,
black blocks are skipped, a block's error is that of its mean luminance.
"""

import os
import sys
import unittest

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import heldout  # noqa: E402


class BlockErrorSeen(unittest.TestCase):
    def test_only_blocks_seen_throughout_count(self):
        truth = np.ones((16, 16, 3))
        render = truth.copy()
        render[:8, :8] *= 1.1  # block (0, 0): 10% off
        render[:8, 8:] *= 1.5  # block (0, 1): 50% off, one pixel unseen
        render[8:, :8, :] = 1.0  # block (1, 0): exact
        seen = np.ones((16, 16), bool)
        seen[3, 12] = False
        # blocks (0, 0), (1, 0), (1, 1): (0.1 + 0 + 0) / 3
        self.assertAlmostEqual(heldout.block_error_seen(render, truth, seen), 0.1 / 3, places=9)
        # everything seen: (0.1 + 0.5) / 4
        self.assertAlmostEqual(heldout.block_error_seen(render, truth, seen | True), 0.15, places=9)

    def test_errors_of_block_means_and_black_blocks_skipped(self):
        truth = np.ones((8, 16, 3))
        truth[:, 8:] = 0.0  # a black block: skipped
        render = truth.copy()
        render[:4, :8] *= 1.2
        render[4:, :8] *= 0.8  # +20% and -20% cancel in the block mean
        seen = np.ones((8, 16), bool)
        self.assertAlmostEqual(heldout.block_error_seen(render, truth, seen), 0.0, places=12)
        self.assertTrue(np.isnan(heldout.block_error_seen(render, truth, ~seen)))

    def test_albedo_psnr_is_the_closed_form_over_the_mask(self):
        truth = np.full((4, 4, 3), 0.5)
        rec = truth.copy()
        rec[:2] += 0.1  # half the pixels off by 0.1 in every channel: MSE 0.005
        rec[3, 3] = 9.0  # outside the mask: ignored
        mask = np.ones((4, 4), bool)
        mask[3, 3] = False
        e = heldout.albedo_errors(rec, truth, mask)
        mse = (8 * 3 * 0.01) / (15 * 3)
        self.assertAlmostEqual(e["albedo_psnr_db"], 10 * np.log10(1 / mse), places=9)
        self.assertEqual(heldout.albedo_errors(truth, truth, mask)["albedo_psnr_db"], float("inf"))
        self.assertTrue(np.isnan(heldout.albedo_errors(rec, truth, ~mask & False)["albedo_psnr_db"]))


if __name__ == "__main__":
    unittest.main()
