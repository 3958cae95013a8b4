#!/usr/bin/env python3
"""Scaling of an MPI run on this machine: one process with T threads against R ranks of T/R
threads (`mpirun`), same scene and settings; prints a Markdown table of wall time, seconds per
stage (rank 0's `report.json` timings), rank 0's communication (bytes and seconds inside
collective operations, per stage, from `resources.communication`) and checks that the
textures, maps and renders are the same bits.

    cargo build --release --features mpi
    python3 tools/mpi_scaling.py tests/fixtures/cbox/input.xml cache/scenes/room-small/input.xml
    python3 tools/mpi_scaling.py --threads 2 --ranks 2 --repeat 3 --args "--method photons" SCENE

Runs alternate (1 process, then R ranks, repeated) so that a change of the machine's load
hits both; each row is the median over the repeats. Output directories go to
out/mpi-scaling/<scene>/<run>.
"""

import argparse
import filecmp
import json
import os
import shlex
import statistics
import subprocess
import sys
import time

STAGES = ["load", "atlas", "projection", "direct", "gather", "photons", "update", "output", "total"]


def run(cmd):
    t = time.monotonic()
    p = subprocess.run(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    if p.returncode != 0:
        sys.exit(f"failed ({p.returncode}): {shlex.join(cmd)}\n{p.stderr}")
    return time.monotonic() - t


def same_outputs(a, b):
    for sub in ["textures", "maps", "renders"]:
        names = sorted(os.listdir(os.path.join(a, sub)))
        if names != sorted(os.listdir(os.path.join(b, sub))):
            return False
        _, bad, err = filecmp.cmpfiles(os.path.join(a, sub), os.path.join(b, sub), names, shallow=False)
        if bad or err:
            return False
    return True


def comm_per_stage(report):
    """(stage, bytes, seconds) of each stage alone, from the cumulative figures."""
    out, (b0, s0) = [], (0, 0.0)
    for stage, b, s in report["resources"].get("communication", []):
        out.append((stage, b - b0, s - s0))
        b0, s0 = b, s
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("scenes", nargs="+")
    ap.add_argument("--threads", type=int, default=2, help="threads of the single process (default 2)")
    ap.add_argument("--ranks", type=int, default=2, help="MPI ranks, threads/ranks threads each (default 2)")
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--args", default="", help="more kdmap flags, e.g. '--method photons'")
    ap.add_argument("--kdmap", default="target/release/kdmap")
    ap.add_argument("--out", default="out/mpi-scaling")
    a = ap.parse_args()
    per_rank = max(1, a.threads // a.ranks)
    mpirun = ["mpirun", "--oversubscribe", "--bind-to", "none", "-np", str(a.ranks)]
    if os.geteuid() == 0:
        mpirun.insert(1, "--allow-run-as-root")
    print(f"load average at start: {os.getloadavg()[0]:.1f} ({os.cpu_count()} cores)")
    print()
    print("| scene | run | wall s | " + " | ".join(STAGES[2:-1]) + " | MB exchanged (rank 0) | s in collectives | same bits |")
    print("|---|---|---|" + "---|" * (len(STAGES) - 3) + "---|---|---|")
    notes = []
    for scene in a.scenes:
        name = os.path.basename(os.path.dirname(os.path.abspath(scene)))
        runs = {
            f"1 x {a.threads}": [],
            f"{a.ranks} x {per_rank}": mpirun,
        }
        walls = {k: [] for k in runs}
        reports = {}
        for _ in range(a.repeat):
            for label, launcher in runs.items():
                out = os.path.join(a.out, name, label.replace(" ", ""))
                threads = a.threads if not launcher else per_rank
                cmd = launcher + [a.kdmap, "reconstruct", scene, "--out", out, "--threads", str(threads),
                                  "--progress", "never"] + shlex.split(a.args)
                walls[label].append(run(cmd))
                with open(os.path.join(out, "report.json")) as f:
                    reports.setdefault(label, []).append(json.load(f))
        solo_out = os.path.join(a.out, name, f"1x{a.threads}")
        for label in runs:
            rs = reports[label]
            med = lambda k: statistics.median(r["timings"].get(k, 0.0) for r in rs)
            comm = rs[-1]["resources"].get("communication", [])
            mb = comm[-1][1] / 1e6 if comm else 0.0
            cs = comm[-1][2] if comm else 0.0
            out = os.path.join(a.out, name, label.replace(" ", ""))
            same = "yes" if same_outputs(solo_out, out) else "NO"
            cells = " | ".join(f"{med(k):.2f}" for k in STAGES[2:-1])
            print(f"| {name} | {label} | {statistics.median(walls[label]):.2f} | {cells} | {mb:.1f} | {cs:.2f} | {same} |")
        stages = comm_per_stage(reports[f"{a.ranks} x {per_rank}"][-1])
        notes.append(f"{name}, {a.ranks} ranks, rank 0 per stage: " + "; ".join(
            f"{stage} {b / 1e6:.2f} MB in {s:.2f} s" for stage, b, s in stages))
    print()
    for n in notes:
        print(n)
        print()
    print(f"load average at end: {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
