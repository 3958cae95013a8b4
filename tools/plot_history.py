#!/usr/bin/env python3
"""Draw the nightly history (one JSON line per scene per run) as PNG plots.

    .venv/bin/python tools/plot_history.py [bench-history/history.jsonl] [--out DIR]

Writes into DIR (default: `plots/` beside the history file) per scene `<scene>.png`: albedo
error, re-render error, Mitsuba held-out error (images, and the held-out albedo judge's rel. L1),
reconstruction time by stage, photons per second and peak memory over runs; and `summary.png`:
albedo error and total time of every scene. Full runs are drawn with solid lines and circles,
`--quick` runs with dotted lines and crosses.
"""

import argparse
import json
import os
import sys


def load(path):
    runs = []
    with open(path) as f:
        for line in f:
            line = line.strip()
            if line:
                try:
                    runs.append(json.loads(line))
                except json.JSONDecodeError:
                    continue
    return runs


def _get(d, *keys):
    for k in keys:
        if not isinstance(d, dict) or k not in d:
            return None
        d = d[k]
    return d


def plot(history, out_dir):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    runs = load(history)
    os.makedirs(out_dir, exist_ok=True)
    scenes = sorted({r["scene"] for r in runs if "scene" in r})
    written = []
    styles = {False: dict(ls="-", marker="o"), True: dict(ls=":", marker="x")}

    def series(rs, f):
        xs, ys = [], []
        for i, r in enumerate(rs):
            v = f(r)
            if v is not None:
                xs.append(i)
                ys.append(v)
        return xs, ys

    for scene in scenes:
        rs = [r for r in runs if r.get("scene") == scene]
        fig, ax = plt.subplots(2, 3, figsize=(15, 8))
        fig.suptitle(f"kdmap nightly: {scene} ({len(rs)} runs; x = run number)")
        labels = [f"{r.get('date', '')[:10]}\n{str(r.get('commit', ''))[:7]}" for r in rs]
        panels = [
            (ax[0, 0], "albedo error vs truth (%)", [
                ("mean rel.", lambda r: _pct(_get(r, "accuracy", "mean_rel_error"))),
                ("rel. L1", lambda r: _pct(_get(r, "accuracy", "rel_l1_error")))]),
            (ax[0, 1], "re-render vs photos (%)", [
                ("RMS rel. texel error (last it.)", lambda r: _pct(_get(r, "rerender", "rms_rel_error"))),
                ("mean |dY|/Y over table rows", lambda r: _pct(_get(r, "rerender", "table_mean_rel_lum_diff")))]),
            (ax[0, 2], "Mitsuba held-out (rel. L1, %)", [
                ("original light", lambda r: _pct(_get(r, "mitsuba", "original", "rel_l1_error"))),
                ("relit", lambda r: _pct(_get(r, "mitsuba", "relit", "rel_l1_error"))),
                ("original, 8x8 blocks", lambda r: _pct(_get(r, "mitsuba", "original", "block8_rel_lum_error"))),
                ("relit, 8x8 blocks", lambda r: _pct(_get(r, "mitsuba", "relit", "block8_rel_lum_error"))),
                ("albedo (AOV, seen pixels)", lambda r: _pct(_get(r, "mitsuba", "albedo", "albedo_rel_l1")))]),
            (ax[1, 0], "time per stage (s)", [
                (k, (lambda k: lambda r: _get(r, "timings", k))(k))
                for k in ("total", "photons", "direct", "projection", "update", "output")]),
            (ax[1, 1], "photons per second (M)", [
                ("photon pass", lambda r: _m(_get(r, "photons_per_second")))]),
            (ax[1, 2], "peak RSS (MiB)", [
                ("reconstruct", lambda r: _get(r, "peak_rss_mib"))]),
        ]
        for a, title, lines in panels:
            for quick in (False, True):
                sub = [r if bool(r.get("quick")) == quick else {} for r in rs]
                for name, f in lines:
                    xs, ys = series(sub, f)
                    if xs:
                        a.plot(xs, ys, label=name + (" (quick)" if quick else ""), **styles[quick])
            a.set_title(title)
            a.grid(alpha=0.3)
            if a.lines:
                a.legend(fontsize=7)
            a.set_xticks(range(len(rs)))
            a.set_xticklabels(labels, fontsize=6, rotation=45 if len(rs) > 6 else 0)
        fig.tight_layout()
        p = os.path.join(out_dir, f"{scene}.png")
        fig.savefig(p, dpi=80)
        plt.close(fig)
        written.append(p)

    if scenes:
        fig, ax = plt.subplots(1, 2, figsize=(12, 4))
        for scene in scenes:
            rs = [r for r in runs if r.get("scene") == scene]
            for quick in (False, True):
                sub = [r if bool(r.get("quick")) == quick else {} for r in rs]
                tag = scene + (" (quick)" if quick else "")
                xs, ys = series(sub, lambda r: _pct(_get(r, "accuracy", "mean_rel_error")))
                if xs:
                    ax[0].plot(xs, ys, label=tag, **styles[quick])
                xs, ys = series(sub, lambda r: _get(r, "timings", "total"))
                if xs:
                    ax[1].plot(xs, ys, label=tag, **styles[quick])
        ax[0].set_title("mean relative albedo error (%)")
        ax[1].set_title("reconstruction time (s)")
        for a in ax:
            a.set_xlabel("run of the scene")
            a.grid(alpha=0.3)
            if a.lines:
                a.legend(fontsize=7)
        fig.tight_layout()
        p = os.path.join(out_dir, "summary.png")
        fig.savefig(p, dpi=80)
        plt.close(fig)
        written.append(p)
    return written


def _pct(v):
    return None if v is None else 100.0 * v


def _m(v):
    return None if v is None else v / 1e6


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("history", nargs="?", default="bench-history/history.jsonl")
    ap.add_argument("--out", help="plot directory (default: plots/ beside the history)")
    a = ap.parse_args()
    out = a.out or os.path.join(os.path.dirname(os.path.abspath(a.history)), "plots")
    for p in plot(a.history, out):
        print(p)
    return 0


if __name__ == "__main__":
    sys.exit(main())
