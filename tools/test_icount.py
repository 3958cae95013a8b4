#!/usr/bin/env python3
"""Tests of tools/icount.py without valgrind: the callgrind parser on a small synthetic
output, the stage sums, the budget file and the comparison.

    python3 tools/test_icount.py
"""

import contextlib
import io
import sys
import tempfile
import unittest
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import icount  # noqa: E402

# main -> stage_a (self 100) -> helper (self 50, called twice: 20 + 30)
#      -> stage_b (self 10) -> stage_b'2 (recursion level 2, self 5), and stage_b -> stage_b
# Costs are "position Ir Dr": Ir is the second column of two events, positions "line".
# Name compression, position compression (+N, -N, *) and two parts (dumps) are used.
SYNTHETIC = """\
# callgrind format
version: 1
creator: callgrind-3.19.0
pid: 1234
cmd: kdmap reconstruct run.toml

part: 1
desc: I1 cache:
positions: line
events: Dr Ir
summary: 7 200

ob=(1) /x/kdmap
fl=(1) ???
fn=(1) main
0 1 5
cfn=(2) stage_a
calls=1 0
0 3 120
cfn=(3) kdmap::stage_b
calls=1 0
0 1 15

fn=(2)
+2 1 60
* 0 40
cfn=(4) helper
calls=2 0
-1 2 20

fn=(4)
0 1 20

fn=(3)
0 1 10
cfn=(5) kdmap::stage_b'2
calls=1 0
0 0 5
cfn=(3)
calls=1 0
0 0 999

fn=(5)
0 0 5

part: 2
positions: line
events: Dr Ir
summary: 0 40

ob=(1)
fl=(1)
fn=(4)
0 0 30
fn=(2)
0 0 0
cfn=(4)
calls=1 0
0 0 30
fn=(1)
0 0 0
cfn=(2)
calls=1 0
0 0 30
jump=1 +3
"""

STAGES = [
    ("a", ["stage_a"], ""),
    ("b", ["kdmap::stage_b"], ""),
    ("ab", ["stage_a", "kdmap::stage_b"], ""),
]


class Parse(unittest.TestCase):
    def setUp(self):
        self.inc, self.own, self.total = icount.parse_callgrind(SYNTHETIC)

    def test_inclusive(self):
        # stage_a: self 60 + 40, helper 20 (part 1) + 30 (part 2)
        self.assertEqual(self.inc["stage_a"], 150)
        self.assertEqual(self.own["stage_a"], 100)
        self.assertEqual(self.inc["helper"], 50)
        # the call of stage_b to itself is not added again; stage_b'2 is
        self.assertEqual(self.inc["kdmap::stage_b"], 15)
        self.assertEqual(self.inc["kdmap::stage_b'2"], 5)
        self.assertEqual(self.inc["main"], 5 + 120 + 15 + 30)

    def test_summary_over_parts(self):
        self.assertEqual(self.total, 240)

    def test_other_event(self):
        inc, _, _ = icount.parse_callgrind(SYNTHETIC, event="Dr")
        self.assertEqual(inc["stage_a"], 1 + 0 + 2)

    def test_stage_counts(self):
        counts = icount.stage_counts(self.inc, STAGES)
        self.assertEqual(counts, {"a": 150, "b": 15, "ab": 165})

    def test_missing_function_is_an_error(self):
        with self.assertRaises(icount.IcountError) as e:
            icount.stage_counts(self.inc, STAGES + [("c", ["kdmap::inlined_away"], "")])
        self.assertIn("kdmap::inlined_away", str(e.exception))

    def test_undefined_name_id(self):
        with self.assertRaises(icount.IcountError):
            icount.parse_callgrind("events: Ir\nfn=(9)\n0 1\n")

    def test_no_such_event(self):
        with self.assertRaises(icount.IcountError):
            icount.parse_callgrind("events: Dr\nfn=(1) f\n0 1\n")


class Compare(unittest.TestCase):
    budget = {"load": (1000, "first"), "gather": (2000, "first"), "output": (500, "")}

    def test_twelve_percent_more_fails_naming_the_stage(self):
        m = {"load": 1000, "gather": 2240, "output": 500}
        rows, failures, hints = icount.compare(m, self.budget)
        self.assertEqual(len(failures), 1)
        self.assertIn("gather", failures[0])
        self.assertIn("2,240", failures[0])
        self.assertIn("+12.0%", failures[0])
        self.assertEqual(hints, [])
        self.assertEqual([r[4] for r in rows], ["ok", "OVER", "ok"])

    def test_five_percent_more_passes(self):
        m = {"load": 1050, "gather": 2100, "output": 525}
        rows, failures, hints = icount.compare(m, self.budget)
        self.assertEqual((failures, hints), ([], []))

    def test_exactly_ten_percent_passes(self):
        _, failures, _ = icount.compare({"load": 1100, "gather": 2000, "output": 500},
                                        self.budget)
        self.assertEqual(failures, [])

    def test_missing_stage_is_an_error(self):
        m = {"load": 1000, "gather": 2000}
        rows, failures, _ = icount.compare(m, self.budget)
        self.assertEqual(len(failures), 1)
        self.assertIn("output", failures[0])
        self.assertIn(("output", 500, None, None, "MISSING"), rows)

    def test_stage_without_budget_is_an_error(self):
        m = {"load": 1000, "gather": 2000, "output": 500, "new": 7}
        _, failures, _ = icount.compare(m, self.budget)
        self.assertEqual(len(failures), 1)
        self.assertIn("new", failures[0])

    def test_a_drop_is_a_hint_not_a_failure(self):
        m = {"load": 850, "gather": 2000, "output": 500}
        rows, failures, hints = icount.compare(m, self.budget)
        self.assertEqual(failures, [])
        self.assertEqual(len(hints), 1)
        self.assertIn("load", hints[0])
        self.assertIn("-15.0%", hints[0])

    def test_table(self):
        rows, _, _ = icount.compare({"load": 1120, "gather": 2000}, self.budget)
        text = icount.format_table(rows)
        self.assertIn("+12.00%", text)
        self.assertIn("MISSING", text)
        self.assertTrue(text.splitlines()[0].startswith("stage"))


class BudgetFile(unittest.TestCase):
    def test_round_trip_and_reasons(self):
        counts = {"load": 1000, "gather": 2000}
        reasons = {"load": 'first "quoted" \\ reason', "gather": "first"}
        with tempfile.TemporaryDirectory() as d:
            p = Path(d) / "b.toml"
            p.write_text(icount.budget_text(counts, reasons, 0.1, STAGES))
            tol, budget = icount.read_budget(p)
            self.assertEqual(tol, 0.1)
            self.assertEqual(budget, {"load": (1000, reasons["load"]), "gather": (2000, "first")})
        new = icount.updated_reasons(budget, {"load": 1005, "gather": 2500, "x": 1}, "faster")
        self.assertEqual(new, {"load": reasons["load"], "gather": "faster", "x": "faster"})

    def test_fallback_parser(self):
        text = icount.budget_text({"load": 12}, {"load": 'a "b"'}, 0.1, STAGES)
        real = sys.modules.get("tomllib")
        sys.modules["tomllib"] = None  # import fails: the fallback reads it
        try:
            data = icount._parse_budget_text(text)
        finally:
            if real is None:
                del sys.modules["tomllib"]
            else:
                sys.modules["tomllib"] = real
        self.assertEqual(data, {"tolerance": 0.1,
                                "stages": {"load": {"instructions": 12, "reason": 'a "b"'}}})


class Main(unittest.TestCase):
    def test_check_of_a_callgrind_file(self):
        """--check on an existing callgrind output: exit 1 over budget, 0 within; --update."""
        with tempfile.TemporaryDirectory() as d:
            cg = Path(d) / "callgrind.out"
            cg.write_text(SYNTHETIC)
            budget = Path(d) / "b.toml"
            saved = icount.STAGES
            icount.STAGES = STAGES
            out, err = io.StringIO(), io.StringIO()
            args = ["--callgrind", str(cg), "--budget", str(budget)]
            try:
                with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
                    budget.write_text(icount.budget_text({"a": 130, "b": 15, "ab": 165}, {}))
                    self.assertEqual(icount.main(["--check"] + args), 1)
                    self.assertIn("a: 150 instructions, +15.4% over", err.getvalue())
                    budget.write_text(icount.budget_text({"a": 145, "b": 15, "ab": 165}, {}))
                    self.assertEqual(icount.main(["--check"] + args), 0)
                    budget.write_text(icount.budget_text({"a": 145, "b": 15}, {}))
                    self.assertEqual(icount.main(["--check"] + args), 1)
                    self.assertIn("ab: measured 165 instructions but has no budget",
                                  err.getvalue())
                    self.assertEqual(icount.main(["--update", "--reason", "r"] + args), 0)
            finally:
                icount.STAGES = saved
            _, b = icount.read_budget(budget)
            self.assertEqual(b, {"a": (150, "r"), "b": (15, ""), "ab": (165, "r")})
            self.assertIn("+3.45%", out.getvalue())


if __name__ == "__main__":
    unittest.main()
