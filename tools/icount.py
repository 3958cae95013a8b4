#!/usr/bin/env python3
"""Instruction-count guard of each pipeline stage (`benches/icount_budget.toml`).

One `target/release/kdmap reconstruct` of a tiny run of `tests/fixtures/cbox` (the run config
`RUN_TOML` below, written to a temporary directory; `--threads 1`) under
`valgrind --tool=callgrind`; each stage's count is the INCLUSIVE instruction count (Ir) of the
function(s) the pipeline calls for it (`STAGES`: one per key of report.json's `timings`, and
a few sub-stages), read from the callgrind output file by `parse_callgrind` (no
callgrind_annotate needed). Instruction counts do not depend on the machine's load, so a
budget can be checked in CI where wall times cannot.

    python3 tools/icount.py                      # measure, print the table against the budget
    python3 tools/icount.py --check              # exit 1 if a stage is > 10% over its budget
    python3 tools/icount.py --update --reason "why the counts moved"
    python3 tools/icount.py --repeat 3           # measure 3 times, show the spread
    python3 tools/icount.py --callgrind FILE     # the stages of an existing callgrind.out

`--check` fails (exit 1) naming every stage whose count exceeds its budget by more than
`tolerance` (10%), every budgeted stage not measured and every measured stage without a
budget; a stage more than 10% UNDER its budget is a hint to lower the budget (not a failure).
`--update --reason` rewrites the budget file with the measured counts; a stage whose count
moved by more than 1% gets the new reason, the others keep theirs.

The counts are near-deterministic with one worker thread: the whole run is inside the rayon pool's
`install`, so with one thread every stage runs on that thread's stack and its inclusive count
holds all its work (with more threads the workers' share would land outside the stage
function). exr decodes and encodes on that thread too in a one-thread run. What still varies
between runs (up to 0.25% of a stage: glibc's realloc growing a vector in place or by a copy,
as the heap's layout falls) is far below the tolerance; see tools/README.md.

The binary is built first (`cargo build --release`, no features: an MPI build compiles the
collectives differently; `--no-build` to skip, `--kdmap PATH` for another binary). The stage
functions carry `#[inline(never)]` so that a release build (symbols only, no debug info)
keeps them as functions callgrind sees.

Python standard library only; needs `valgrind` on PATH.
"""

import argparse
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
BUDGET = ROOT / "benches" / "icount_budget.toml"
TOLERANCE = 0.10
# a stage whose count moved by more than this gets the new reason on --update
REASON_THRESHOLD = 0.01

# The tiny run: coarse atlas (12 texels per unit: ~3.7k covered texels in 7 tiles), 2
# refinement passes, few shadow and gather rays, 2 iterations. About 1 s of CPU natively,
# about a minute under callgrind.
RUN_TOML = """\
# written by tools/icount.py: the instruction-count guard's run
scene = "{scene}"

[atlas]
texels_per_unit = 12

[projection]
refine_passes = 2
refine_gated_from = 1

[direct]
area_samples = 4

[gather]
rays = 64

[solver]
iterations = 2

[run]
threads = 1
seed = 1
"""

# stage -> the functions whose inclusive counts add up to it, and what it is. The keys of
# report.json's `timings` (`projection` includes `calibration` and `noise_probe`, as there;
# `update` is every K_d step, the final one included, and the E_i updates) and sub-stages
# (`refinement`, `denoise`, `fill`). `photons` and `caustics` do not run on this scene (the
# default method is the gather; cbox has no mirror or glass).
STAGES = [
    ("load", ["kdmap::atlas::context::prepare::prepare"],
     "scene, meshes, photos decoded, densities, unwraps, layout"),
    ("atlas", ["kdmap::atlas::context::geometry::build_geometry",
               "kdmap::atlas::uv::charts::Charts::new",
               "kdmap::atlas::context::prepare::RunContext::texel_report"],
     "geometry store, charts, texel report"),
    ("projection", ["kdmap::stages::project::run_shard", "kdmap::pipeline::denoise"],
     "photos onto the atlas: all below, and the weighted mean"),
    ("calibration", ["kdmap::stages::project::exposure::estimate"],
     "  per-view gains (part of projection)"),
    ("refinement", ["kdmap::stages::project::refine::Refine::run"],
     "  back-projection passes, the probe's too (part of projection)"),
    ("noise_probe", ["kdmap::stages::project::probe_noise"],
     "  perturbed photos projected again (part of projection)"),
    ("denoise", ["kdmap::stages::denoise::denoise_luminance"],
     "  sigma filter (part of projection)"),
    ("direct", ["kdmap::pipeline::Run::direct"], "E_d from the area light"),
    ("gather", ["kdmap::pipeline::Run::gather_estimate"], "E_i gathered, 2 iterations"),
    ("update", ["kdmap::pipeline::Run::kd_step", "kdmap::stages::solve::update_step"],
     "K_d steps (3, with their fills) and E_i updates"),
    ("fill", ["kdmap::stages::solve::fill::fill_unobserved_all"],
     "  K_d of unobserved texels (part of update)"),
    ("uniform", ["kdmap::pipeline::Run::one_colour"], "one-colour shapes"),
    ("output", ["kdmap::output::write_outputs"], "textures, maps, meshes, renders, report"),
    ("total", ["kdmap::pipeline::reconstruct_resumable"], "the whole reconstruction"),
]


class IcountError(Exception):
    """A measurement or budget that cannot be used (exit 2)."""


# ---------------------------------------------------------------------------------------------
# callgrind output

_NAME = re.compile(r"^\((\d+)\)(?:\s(.*))?$")


def _name(table, value):
    """A compressed name `(id) name` / `(id)`, or a plain name; `table` maps the ids."""
    m = _NAME.match(value)
    if not m:
        return value
    if m.group(2) is not None:
        table[m.group(1)] = m.group(2)
        return m.group(2)
    if m.group(1) not in table:
        raise IcountError(f"callgrind output: name id ({m.group(1)}) used before defined")
    return table[m.group(1)]


def parse_callgrind(text, event="Ir"):
    """Inclusive and self counts of `event` per function name in a callgrind output file
    (any number of parts; name compression and position compression understood).

    Inclusive = the function's own cost lines + the costs of its calls; a call of a function
    to itself is left out (its cost is already there; callgrind's `--separate-recs` names the
    deeper levels `f'2`, which are functions of their own). Functions of the same name (in
    several objects or files) are added up. Returns `(inclusive, self, total)`."""
    inclusive, own = {}, {}
    fn_names = {}
    npos, idx, total = 1, None, 0
    fn = None
    cfn = None  # the callee named by the last `cfn=`
    call_to = None  # the callee when the next cost line is a call's cost
    for lineno, raw in enumerate(text.splitlines(), 1):
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        c = line[0]
        if c.isdigit() or c in "+-*":
            if idx is None:
                raise IcountError(f"callgrind output line {lineno}: cost before `events:`")
            fields = line.split()
            costs = fields[npos:]
            v = int(costs[idx]) if idx < len(costs) else 0
            if fn is None:
                raise IcountError(f"callgrind output line {lineno}: cost outside a function")
            if call_to is not None:
                if call_to != fn:
                    inclusive[fn] = inclusive.get(fn, 0) + v
                call_to = None
            else:
                own[fn] = own.get(fn, 0) + v
                inclusive[fn] = inclusive.get(fn, 0) + v
            continue
        key, sep, value = line.partition("=")
        if sep and re.fullmatch(r"[a-z]+", key):
            if key == "fn":
                fn = _name(fn_names, value.strip())
                inclusive.setdefault(fn, 0)
                own.setdefault(fn, 0)
                call_to = None
            elif key == "cfn":
                cfn = _name(fn_names, value.strip())
            elif key == "calls":
                if cfn is None:
                    raise IcountError(f"callgrind output line {lineno}: calls= without cfn=")
                call_to = cfn
            # ob, fl, fi, fe, cob, cfi, cfl, jump, jcnd: not needed for the counts
            continue
        key, sep, value = line.partition(":")
        if sep:
            key = key.strip()
            if key == "positions":
                npos = len(value.split())
            elif key == "events":
                names = value.split()
                if event not in names:
                    raise IcountError(f"callgrind output: no {event} among events {names}")
                idx = names.index(event)
            elif key == "summary" and idx is not None:
                vals = value.split()
                total += int(vals[idx]) if idx < len(vals) else 0
    return inclusive, own, total


def stage_counts(inclusive, stages=None):
    """Per stage the sum of its functions' inclusive counts (`STAGES` by default). A function
    missing from the output (renamed, or inlined into its caller) is an error naming it."""
    counts, missing = {}, []
    stages = STAGES if stages is None else stages
    for stage, functions, _ in stages:
        n = 0
        for f in functions:
            if f not in inclusive:
                missing.append(f"{stage}: {f}")
            else:
                n += inclusive[f]
        counts[stage] = n
    if missing:
        raise IcountError(
            "stage functions not in the callgrind output (renamed, or inlined: mark them "
            "#[inline(never)]):\n  " + "\n  ".join(missing))
    return counts


# ---------------------------------------------------------------------------------------------
# budget file

def _toml_string(s):
    return '"' + s.replace("\\", "\\\\").replace('"', '\\"').replace("\n", "\\n") + '"'


def _parse_budget_text(text):
    """The budget file's own small subset of TOML (top-level `tolerance`, tables
    `[stages.<name>]` with `instructions` and `reason`); tomllib where there is one."""
    try:
        import tomllib  # Python 3.11+
        return tomllib.loads(text)
    except ImportError:
        pass
    data_root = {}
    table = data_root
    for lineno, raw in enumerate(text.splitlines(), 1):
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        m = re.fullmatch(r"\[([A-Za-z0-9_.\-]+)\]", line)
        if m:
            table = data_root
            for part in m.group(1).split("."):
                table = table.setdefault(part, {})
            continue
        m = re.fullmatch(r'([A-Za-z0-9_\-]+)\s*=\s*(.+?)\s*(#[^"]*)?', line)
        if not m:
            raise IcountError(f"budget file line {lineno}: cannot read {line!r}")
        k, v = m.group(1), m.group(2)
        if v.startswith('"'):
            v = bytes(v[1:-1], "utf-8").decode("unicode_escape")
        elif re.fullmatch(r"[0-9_]+", v):
            v = int(v.replace("_", ""))
        else:
            v = float(v)
        table[k] = v
    return data_root


def read_budget(path):
    """`(tolerance, {stage: (instructions, reason)})` of a budget file."""
    data = _parse_budget_text(Path(path).read_text())
    stages = {}
    for name, entry in data.get("stages", {}).items():
        if "instructions" not in entry:
            raise IcountError(f"{path}: stage {name} has no `instructions`")
        stages[name] = (int(entry["instructions"]), str(entry.get("reason", "")))
    return float(data.get("tolerance", TOLERANCE)), stages


def budget_text(counts, reasons, tolerance=TOLERANCE, stages=None):
    """The budget file for `counts` (stage -> instructions) and `reasons` (stage -> text)."""
    stages = STAGES if stages is None else stages
    lines = [
        "# Instruction counts of each pipeline stage on the tiny cbox run of tools/icount.py",
        "# (inclusive Ir of the stage's functions under callgrind, --threads 1). Checked in CI by",
        "# `python3 tools/icount.py --check`: a stage more than `tolerance` over its count fails.",
        "# Rewrite with `python3 tools/icount.py --update --reason \"...\"`, in the commit that",
        "# changes the counts; `reason` is why the stage's count last moved.",
        "",
        f"tolerance = {tolerance}",
    ]
    order = [s for s, _, _ in stages] + sorted(set(counts) - {s for s, _, _ in stages})
    for s in order:
        if s not in counts:
            continue
        lines += ["", f"[stages.{s}]", f"instructions = {counts[s]}",
                  f"reason = {_toml_string(reasons.get(s, ''))}"]
    return "\n".join(lines) + "\n"


def updated_reasons(old, counts, reason):
    """The reasons of an update: `reason` where a stage is new or moved by more than
    REASON_THRESHOLD, the old one elsewhere."""
    out = {}
    for s, n in counts.items():
        if s in old and old[s][0] > 0 and abs(n - old[s][0]) / old[s][0] <= REASON_THRESHOLD:
            out[s] = old[s][1]
        else:
            out[s] = reason
    return out


# ---------------------------------------------------------------------------------------------
# comparison

def compare(measured, budget, tolerance=TOLERANCE):
    """Measured counts against the budget. Returns `(rows, failures, hints)`: rows
    `(stage, budget or None, measured or None, change or None, status)`; failures name each
    stage over budget by more than `tolerance`, budgeted but not measured, or measured
    without a budget; hints name each stage more than `tolerance` under its budget."""
    rows, failures, hints = [], [], []
    names = list(measured) + [s for s in budget if s not in measured]
    for s in names:
        b = budget.get(s, (None, ""))[0]
        m = measured.get(s)
        if m is None:
            rows.append((s, b, None, None, "MISSING"))
            failures.append(f"{s}: in the budget ({b:,}) but not measured")
            continue
        if b is None:
            rows.append((s, None, m, None, "NO BUDGET"))
            failures.append(f"{s}: measured {m:,} instructions but has no budget "
                            "(add it with --update --reason)")
            continue
        change = (m - b) / b if b else (0.0 if m == 0 else float("inf"))
        if change > tolerance:
            status = "OVER"
            failures.append(f"{s}: {m:,} instructions, {100 * change:+.1f}% over its budget "
                            f"of {b:,} (tolerance {100 * tolerance:.0f}%)")
        elif change < -tolerance:
            status = "under: lower it"
            hints.append(f"{s}: {m:,} instructions, {100 * change:+.1f}% under its budget of "
                         f"{b:,}: lower the budget (--update --reason)")
        else:
            status = "ok"
        rows.append((s, b, m, change, status))
    return rows, failures, hints


def format_table(rows):
    def num(v):
        return "-" if v is None else f"{v:,}"
    out = [f"{'stage':<12} {'budget':>16} {'measured':>16} {'change':>8}  status"]
    for s, b, m, c, st in rows:
        cs = "-" if c is None else f"{100 * c:+.2f}%"
        out.append(f"{s:<12} {num(b):>16} {num(m):>16} {cs:>8}  {st}")
    return "\n".join(out)


# ---------------------------------------------------------------------------------------------
# measuring

def build():
    print("icount: cargo build --release", file=sys.stderr, flush=True)
    subprocess.run(["cargo", "build", "--release", "--quiet"], cwd=ROOT, check=True)


def is_mpi_build(binary):
    """Whether `binary` links the MPI library (a `--features mpi` build)."""
    with open(binary, "rb") as f:
        return b"libmpi.so" in f.read()


def measure(kdmap, scene, keep=None):
    """One callgrind run of the tiny reconstruction: `(stage counts, total Ir, seconds)`."""
    if shutil.which("valgrind") is None:
        raise IcountError("valgrind is not installed (apt-get install valgrind)")
    work = Path(keep) if keep else Path(tempfile.mkdtemp(prefix="kdmap-icount-"))
    work.mkdir(parents=True, exist_ok=True)
    try:
        run = work / "run.toml"
        run.write_text(RUN_TOML.format(scene=str(Path(scene).resolve())))
        out_file = work / "callgrind.out"
        cmd = ["valgrind", "--tool=callgrind", f"--callgrind-out-file={out_file}",
               "--dump-instr=no", "--dump-line=no", "--separate-threads=no",
               str(kdmap), "reconstruct", str(run), "--out", str(work / "out"),
               "--threads", "1", "--quiet"]
        t = time.monotonic()
        res = subprocess.run(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        seconds = time.monotonic() - t
        if res.returncode != 0:
            raise IcountError(f"the callgrind run failed (exit {res.returncode}):\n"
                              + res.stderr[-3000:])
        inclusive, _, total = parse_callgrind(out_file.read_text())
        return stage_counts(inclusive), total, seconds
    finally:
        if not keep:
            shutil.rmtree(work, ignore_errors=True)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    mode = ap.add_mutually_exclusive_group()
    mode.add_argument("--check", action="store_true",
                      help="exit 1 if a stage exceeds its budget by more than the tolerance")
    mode.add_argument("--update", action="store_true", help="rewrite the budget file")
    ap.add_argument("--reason", help="why the counts changed (with --update)")
    ap.add_argument("--budget", default=str(BUDGET), help="budget file (%(default)s)")
    ap.add_argument("--kdmap", help="the binary to measure (default target/release/kdmap, "
                                    "built first)")
    ap.add_argument("--no-build", action="store_true", help="do not run cargo build")
    ap.add_argument("--scene", default=str(ROOT / "tests" / "fixtures" / "cbox" / "input.xml"))
    ap.add_argument("--callgrind", help="read this callgrind output instead of running")
    ap.add_argument("--keep", help="work in this directory and keep it (run config, output, "
                                   "callgrind.out)")
    ap.add_argument("--repeat", type=int, default=1,
                    help="measure N times and show the spread (the counts must agree)")
    args = ap.parse_args(argv)
    if args.update and not args.reason:
        ap.error("--update needs --reason")
    try:
        t0 = time.monotonic()
        if args.callgrind:
            inclusive, _, _ = parse_callgrind(Path(args.callgrind).read_text())
            runs = [stage_counts(inclusive)]
        else:
            kdmap = Path(args.kdmap) if args.kdmap else ROOT / "target" / "release" / "kdmap"
            if not args.kdmap and not args.no_build:
                build()
            if not kdmap.exists():
                raise IcountError(f"{kdmap} does not exist (cargo build --release)")
            if is_mpi_build(kdmap):
                # run alone it never starts MPI: its counts were within 0.3% of the plain
                # build's per stage when measured, so CI checks the binary its tests built
                print(f"icount: {kdmap} is an MPI build (--features mpi); the budget is of a "
                      "plain `cargo build --release` (the two agree within 0.3% per stage)",
                      file=sys.stderr)
            runs = []
            for i in range(max(1, args.repeat)):
                counts, total, seconds = measure(kdmap, args.scene, args.keep)
                print(f"icount: run {i + 1}: {total:,} instructions in all, callgrind "
                      f"{seconds:.1f} s", file=sys.stderr, flush=True)
                runs.append(counts)
        measured = runs[-1]
        if len(runs) > 1:
            print("spread over the runs (max - min) / min:")
            for s in measured:
                vals = [r[s] for r in runs]
                spread = (max(vals) - min(vals)) / max(1, min(vals))
                print(f"  {s:<12} {min(vals):>16,} .. {max(vals):>16,}  {100 * spread:.4f}%")
        budget_path = Path(args.budget)
        tolerance, budget = TOLERANCE, {}
        if budget_path.exists():
            tolerance, budget = read_budget(budget_path)
        elif args.check:
            raise IcountError(f"no budget file {budget_path} (make it with --update --reason)")
        if args.update:
            reasons = updated_reasons(budget, measured, args.reason)
            budget_path.write_text(budget_text(measured, reasons, tolerance))
            print(f"icount: wrote {budget_path}")
            budget = {s: (n, reasons[s]) for s, n in measured.items()}
        rows, failures, hints = compare(measured, budget, tolerance)
        print(format_table(rows))
        for h in hints:
            print(f"hint: {h}")
        print(f"icount: {time.monotonic() - t0:.1f} s", file=sys.stderr)
        if failures and args.check:
            print(f"icount: FAILED: {len(failures)} stage(s) outside the budget "
                  f"{budget_path}:", file=sys.stderr)
            for f in failures:
                print(f"  {f}", file=sys.stderr)
            print("If the change is intended, update the budget in the same commit: "
                  "python3 tools/icount.py --update --reason \"...\"", file=sys.stderr)
            return 1
        for f in failures:
            print(f"note: {f}")
        return 0
    except IcountError as e:
        print(f"icount: error: {e}", file=sys.stderr)
        return 2
    except subprocess.CalledProcessError as e:
        print(f"icount: error: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
