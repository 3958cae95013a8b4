#!/usr/bin/env python3
"""Unit test of the generated pages (tools/docs_pages.py, `tools/nightly.py --pages-only`) on a
synthetic history: no kdmap run, no rendering, standard library only.

    .venv/bin/python tools/test_docs_pages.py

Per scene the newest full entry wins (over older full ones and over newer quick ones), a scene
with only quick entries shows its newest one marked "(quick)", a failed reconstruction is
passed over; columns that need the anchor, the Mitsuba floor or the projection floor appear
only when an entry has them; numbers are formatted as the pages state them.
"""

import copy
import os
import subprocess
import sys
import tempfile
import unittest

TOOLS = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, TOOLS)
import docs_pages as dp  # noqa: E402

MACHINE = {"cores": 2, "cpu": "Test CPU 9000", "mem_mib": 8000, "load1": 2.345}


def entry(scene, date, commit, quick=False, held=0.05, wall=10.0):
    """A history line as nightly.py writes it, cut down to what the pages read."""
    return {
        "scene": scene, "date": date, "commit": commit, "dirty": False, "machine": MACHINE,
        "quick": quick, "requested": {"photons": 200000 if quick else None,
                                      "iterations": 2 if quick else None, "spp": 64},
        "exit_code": 0, "wall_seconds": wall, "peak_rss_mib": 143.96,
        "timings": {"load": 0.0064, "projection": 6.18, "caustics": 7e-7, "photons": 0.0,
                    "gather": 1.76, "total": 12.4933},
        "photons_per_second": None,
        "iterations": [{"gather_rays": 10_000_000, "gather_seconds": 2.0},
                       {"gather_rays": 5_000_000, "gather_seconds": 1.0}],
        "accuracy": {"mean_rel_error": 0.0123456, "rel_l1_error": 0.009,
                     "calibration": {"within_one": 0.70, "within_two": 0.951},
                     "shapes": [{"shape": "floor", "texels": 300, "mean_rel_error": 0.01,
                                 "rel_l1_error": 0.008},
                                {"shape": "back", "texels": 100, "mean_rel_error": 0.02,
                                 "rel_l1_error": 0.015}]},
        "mitsuba": {"spp": 64,
                    "original": {"rel_l1_error": 0.03, "block8_rel_lum_error": 0.0226},
                    "relit": {"rel_l1_error": 0.111, "block8_rel_lum_error": 0.0301},
                    "albedo": {"albedo_mean_rel_error": held, "albedo_rel_l1": 0.0302,
                               "albedo_psnr_db": 31.456,
                               "masked_fraction": 0.92,
                               "shapes": {"floor": {"albedo_mean_rel_error": 0.021,
                                                    "albedo_rel_l1": 0.02,
                                                    "masked_pixels": 5000}}}},
        "failures": [], "ok": True,
    }


def section_table(page, title):
    """The first Markdown table under `## title`, as a list of {column: cell}."""
    lines = page.splitlines()
    i = lines.index(f"## {title}")
    rows = []
    for line in lines[i + 1:]:
        if line.startswith("## "):
            break
        if line.startswith("|"):
            rows.append([c.strip() for c in line.strip()[1:-1].split(" | ")])
        elif rows:
            break
    head, body = rows[0], rows[2:]
    return [dict(zip(head, r)) for r in body]


def by_scene(rows):
    return {r["scene"]: r for r in rows}


class Pages(unittest.TestCase):
    def setUp(self):
        old = entry("cbox", "2025-01-01T00:00:00+00:00", "a" * 40, held=0.09, wall=50.0)
        new = entry("cbox", "2025-02-01T00:00:00+00:00", "b" * 40, held=0.0067, wall=12.345)
        newer_quick = entry("cbox", "2025-03-01T00:00:00+00:00", "c" * 40, quick=True,
                            held=0.5, wall=1.0)
        failed = {"scene": "cbox", "date": "2025-04-01T00:00:00+00:00", "commit": "d" * 40,
                  "quick": False, "exit_code": 101, "wall_seconds": 0.1, "failures": ["x"]}
        only_quick = entry("lights", "2025-01-05T00:00:00+00:00", "e" * 40, quick=True,
                           held=0.0333)
        # file order is not date order: the newest date wins
        self.entries = [new, old, newer_quick, failed, only_quick]

    def test_newest_full_entry_wins(self):
        latest = dp.latest_per_scene(self.entries)
        self.assertEqual(latest["cbox"]["commit"], "b" * 40)
        self.assertTrue(latest["lights"]["quick"])
        page = dp.accuracy_page(self.entries)
        held = by_scene(section_table(page, "Held-out views (Mitsuba 3)"))
        self.assertEqual(held["cbox"]["albedo mean rel."], "0.67%")
        self.assertNotIn("9.00%", page)  # the older full run
        self.assertNotIn("50.00%", page)  # the newer quick run
        runs = by_scene(section_table(page, "Runs"))
        self.assertEqual(runs["cbox"]["commit"], "bbbbbbb")
        self.assertEqual(runs["cbox"]["date (UTC)"], "2025-02-01T00:00:00+00:00")
        self.assertEqual(runs["cbox"]["machine (load: 1-minute average at the start)"],
                         "2 cores, Test CPU 9000, load 2.3")
        perf = by_scene(section_table(dp.performance_page(self.entries), "Reconstruction"))
        self.assertEqual(perf["cbox"]["wall s"], "12.3")

    def test_quick_entries_are_marked(self):
        for page in (dp.accuracy_page(self.entries), dp.performance_page(self.entries)):
            runs = by_scene(section_table(page, "Runs"))
            self.assertEqual(set(runs), {"cbox", "lights (quick)"})
            self.assertEqual(runs["lights (quick)"]["kdmap settings"],
                             "photons 200000, 2 iterations")
            self.assertEqual(runs["cbox"]["kdmap settings"], "defaults")
        held = by_scene(section_table(dp.accuracy_page(self.entries), "Held-out views (Mitsuba 3)"))
        self.assertEqual(held["lights (quick)"]["albedo mean rel."], "3.33%")

    def test_numbers_formatted_as_given(self):
        page = dp.accuracy_page(self.entries)
        held = by_scene(section_table(page, "Held-out views (Mitsuba 3)"))["cbox"]
        self.assertEqual((held["spp"], held["albedo rel. L1"], held["albedo PSNR"],
                          held["pixels seen"], held["relit 8x8"], held["original 8x8"],
                          held["relit rel. L1"]),
                         ("64", "3.02%", "31.46 dB", "92.00%", "3.01%", "2.26%", "11.10%"))
        truth = by_scene(section_table(page, "Albedo against the truth (observed texels)"))["cbox"]
        self.assertEqual((truth["texels"], truth["mean rel."], truth["rel. L1"],
                          truth["within 1 std. err."], truth["within 2"]),
                         ("400", "1.23%", "0.90%", "70.00%", "95.10%"))
        shapes = [r for r in section_table(page, "Per shape") if r["scene"] == "cbox"]
        self.assertEqual([r["shape"] for r in shapes], ["floor", "back"])
        self.assertEqual((shapes[0]["held-out mean rel."], shapes[0]["held-out pixels"],
                          shapes[0]["texels"]), ("2.10%", "5000", "300"))
        self.assertEqual((shapes[1]["held-out mean rel."], shapes[1]["texels mean rel."]),
                         ("-", "2.00%"))
        perf_page = dp.performance_page(self.entries)
        perf = by_scene(section_table(perf_page, "Reconstruction"))["cbox"]
        self.assertEqual((perf["peak RSS MiB"], perf["M photons/s"], perf["M gather rays"],
                          perf["M rays/s"]), ("144", "-", "15.0", "5.00"))
        stages = section_table(perf_page, "Time per stage")
        # stages under 0.005 s everywhere (caustics, photons) are left out; total is last
        self.assertEqual(list(stages[0]), ["scene", "load", "projection", "gather", "total"])
        entries = copy.deepcopy(self.entries)
        entries[-1]["timings"]["caustics"] = 1.5  # kept, in report.json's order
        stages = section_table(dp.performance_page(entries), "Time per stage")
        self.assertEqual(list(stages[0]),
                         ["scene", "load", "projection", "caustics", "gather", "total"])
        self.assertEqual(by_scene(stages)["cbox"]["caustics"], "0.00")
        self.assertEqual(by_scene(stages)["cbox"]["total"], "12.49")

    def test_rays_per_stage_with_their_rate_per_core(self):
        self.assertNotIn("## Rays per stage", dp.performance_page(self.entries), "no rays: none")
        entries = copy.deepcopy(self.entries)
        # 12 M rays over 6.18 s on 2 cores: 0.97 M/s per core; the estimate over gather + photons
        entries[0]["rays"] = {"projection": 12_000_000, "estimate": 3_520_000, "direct": 0,
                              "cores": 2}
        rows = by_scene(section_table(dp.performance_page(entries), "Rays per stage"))
        self.assertEqual(list(rows["cbox"]), ["scene", "cores", "projection", "estimate"])
        self.assertEqual(rows["cbox"]["projection"], "12.00 (0.97)")
        self.assertEqual(rows["cbox"]["estimate"], "3.52 (1.00)")
        self.assertNotIn("lights", rows, "a scene without rays has no row")

    def test_anchor_columns_only_with_an_anchor(self):
        acc, perf = dp.accuracy_page(self.entries), dp.performance_page(self.entries)
        self.assertNotIn("anchor", acc)
        self.assertNotIn("anchor", perf)
        self.assertNotIn("floor", section_table(acc, "Held-out views (Mitsuba 3)")[0])

        entries = copy.deepcopy(self.entries)
        entries[0]["anchor"] = {
            "mode": "full", "iterations": 150, "seconds_per_iteration": 11.26,
            "compile_seconds": 2.6, "anchor_seconds": 1699.4, "peak_rss_mib": 900.0,
            "kdmap_wall_seconds": 12.345, "speedup": 137.66,
            "compare": {"albedo.albedo_mean_rel_error": {"kdmap": 0.0067, "anchor": 0.1234},
                        "relit.block8_rel_lum_error": {"kdmap": 0.0301, "anchor": None}}}
        entries[0]["mitsuba"]["floor"] = {"relit": {"block8_rel_lum_error": 0.004},
                                          "original": {"block8_rel_lum_error": 0.003}}
        acc, perf = dp.accuracy_page(entries), dp.performance_page(entries)
        rec = by_scene(section_table(perf, "Reconstruction"))
        self.assertEqual(rec["cbox"]["speed-up over the anchor"], "x137.7")
        self.assertEqual(rec["lights (quick)"]["speed-up over the anchor"], "-")
        anchor = by_scene(section_table(perf, "Mitsuba 3 inverse rendering (anchor)"))
        self.assertEqual(set(anchor), {"cbox"})
        self.assertEqual((anchor["cbox"]["anchor"], anchor["cbox"]["anchor s"],
                          anchor["cbox"]["s / iteration"]), ("150 iterations run", "1699", "11.26"))
        self.assertIn("kdmap / anchor", acc)
        self.assertNotIn("Timed only", acc)
        cmp_ = by_scene(section_table(acc, "Mitsuba 3 inverse rendering (anchor)"))["cbox"]
        self.assertEqual(cmp_["albedo mean rel."], "0.67% / 12.34%")
        self.assertEqual(cmp_["relit 8x8"], "3.01% / -")
        self.assertEqual(cmp_["original 8x8"], "-")
        held = by_scene(section_table(acc, "Held-out views (Mitsuba 3)"))
        self.assertEqual(held["cbox"]["floor: relit 8x8"], "0.40%")
        self.assertEqual(held["lights (quick)"]["floor: relit 8x8"], "-")

        # a timed-only anchor: a speed-up, no accuracy comparison
        del entries[0]["anchor"]["compare"]
        entries[0]["anchor"].update(mode="time_only", measured_iterations=4)
        acc = dp.accuracy_page(entries)
        self.assertIn("Timed only", acc)
        self.assertNotIn("kdmap / anchor", acc)
        anchor = by_scene(section_table(dp.performance_page(entries),
                                        "Mitsuba 3 inverse rendering (anchor)"))
        self.assertEqual(anchor["cbox"]["anchor"], "extrapolated from 3 iterations")

    def test_captures_are_scored_against_their_perfect_scene(self):
        page = dp.accuracy_page(self.entries)
        self.assertNotIn("## Degraded captures", page)  # no capture in the history
        cap = entry("cbox-jpeg", "2025-02-02T00:00:00+00:00", "b" * 40, held=0.01005)
        cap["capture"] = {"scene": "cbox", "preset": "jpeg", "pinned": "cam_train_0"}
        orphan = entry("box-pose", "2025-02-02T00:00:00+00:00", "b" * 40, held=0.2)
        orphan["capture"] = {"scene": "box", "preset": "pose", "pinned": None}
        page = dp.accuracy_page(self.entries + [cap, orphan])
        rows = {r["capture"]: r for r in section_table(page, "Degraded captures")}
        # 1.005% against the newest full cbox run's 0.67%
        self.assertEqual(rows["cbox-jpeg"]["ratio"], "1.50x")
        self.assertEqual(rows["cbox-jpeg"]["perfect photos"], "0.67%")
        self.assertEqual(rows["cbox-jpeg"]["pinned view"], "cam_train_0")
        self.assertEqual((rows["box-pose"]["ratio"], rows["box-pose"]["pinned view"]), ("-", "-"))

    def test_header_and_empty_history(self):
        for page in (dp.accuracy_page([]), dp.performance_page([])):
            self.assertIn("Generated by `python3 tools/nightly.py`", page)
            self.assertIn("`python3 tools/nightly.py --pages-only`", page)
            self.assertIn("Do not edit by hand.", page)
            self.assertIn("no finished run", page)

    def test_pages_only_writes_both_pages_from_the_history(self):
        import json

        with tempfile.TemporaryDirectory() as d:
            hist = os.path.join(d, "history.jsonl")
            with open(hist, "w") as f:
                for e in self.entries:
                    f.write(json.dumps(e) + "\n")
                f.write("not json\n")
            docs = os.path.join(d, "docs")
            # plain python3 (no venv needed), nothing run, no build
            subprocess.run([sys.executable, os.path.join(TOOLS, "nightly.py"), "--pages-only",
                            "--history", hist, "--docs", docs], check=True,
                           stdout=subprocess.DEVNULL)
            with open(os.path.join(docs, "accuracy.md")) as f:
                self.assertEqual(f.read(), dp.accuracy_page(self.entries).rstrip("\n") + "\n")
            with open(os.path.join(docs, "performance.md")) as f:
                self.assertIn("| cbox | 12.3 |", f.read())
            self.assertEqual(sorted(os.listdir(docs)), ["accuracy.md", "performance.md"])
            r = subprocess.run([sys.executable, os.path.join(TOOLS, "nightly.py"),
                                "--pages-only", "--history", os.path.join(d, "none.jsonl"),
                                "--docs", docs], stdout=subprocess.DEVNULL)
            self.assertEqual(r.returncode, 1)


if __name__ == "__main__":
    unittest.main()
