#!/usr/bin/env python3
"""kdmap cost curves: time per stage and peak RSS against texels, views and triangles.

    .venv/bin/python tools/cost_curves.py                     # all three curves
    .venv/bin/python tools/cost_curves.py --curves texels --texels 0.5e6,2e6,8e6
    .venv/bin/python tools/cost_curves.py --quick             # small points, a smoke run

Scenes come from tools/gen_scene.py (the `room` layout), generated on demand into
cache/scenes/curve-* (git-ignored) at low samples per pixel (photo noise does not change what a
stage costs): one scene for the texel curve (8 views of 256x192, the density set per point by a
run config), one with 64 training views for the view curve (runs take the first N), and one
per triangle count for the triangle curve (4 views). Every point is one `kdmap reconstruct`
run: wall time, peak RSS of the process (wait4), the stage times of report.json and the covered
texels it reports.

Writes <out>/curves.json and one PNG per curve (<out>/cost_<curve>.png: seconds per stage and
peak RSS against the size, log-log, with the fitted exponent of each series), and checks each
curve: the fitted exponent of the total time and of the peak RSS over the points must be at
most 1 + --slack (linear or better). Time is fitted on the process's CPU seconds (user +
system), which the other jobs of a shared machine disturb less than wall time; the stages'
wall times are plotted beside it. Exit code 1 (with one line per failed check) otherwise.
"""

import argparse
import json
import math
import os
import shutil
import subprocess
import sys
import time

TOOLS = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(TOOLS)
sys.path.insert(0, TOOLS)

STAGES = ["load", "atlas", "projection", "direct", "gather", "photons", "update", "output"]
TEXELS = [0.5e6, 1e6, 2e6, 5e6, 10e6, 20e6, 50e6]
VIEWS = [4, 8, 16, 32, 64]
# triangles per curved object (8 curved objects in the room) -> about 10k .. 4M in all
TRIS = [1_000, 4_000, 16_000, 64_000, 250_000, 500_000]
QUICK = {"texels": [0.25e6, 0.5e6, 1e6], "views": [2, 4, 8], "tris": [500, 2_000, 8_000]}
BASE = ["--preset", "room", "--res", "256x192", "--test", "0", "--spp", "8",
        "--texture-res", "256"]


def log(msg):
    print(f"[curves {time.strftime('%H:%M:%S')}] {msg}", flush=True)


def generate(name, extra, cache):
    """The scene `name` in `cache` (made by gen_scene.py unless already there); its scene.json."""
    out = os.path.join(cache, name)
    cmd = [sys.executable, os.path.join(TOOLS, "gen_scene.py"), out] + BASE + extra
    log(f"scene {name}: {' '.join(os.path.relpath(c, REPO) if os.path.isabs(c) else c for c in cmd)}")
    subprocess.check_call(cmd, stdout=subprocess.DEVNULL if not os.environ.get("CURVES_VERBOSE") else None)
    with open(os.path.join(out, "scene.json")) as f:
        return out, json.load(f)


def run_point(kdmap, scene_dir, toml_extra, views, out, threads):
    """One reconstruction with a run config; returns its measurements."""
    os.makedirs(out, exist_ok=True)
    run = os.path.join(out, "run.toml")
    with open(run, "w") as f:
        f.write(f'scene = "{os.path.join(scene_dir, "input.xml")}"\n')
        f.write(toml_extra)
        if views is not None:
            f.write("[views]\n")
            for v in views:
                f.write(f'{v} = "{os.path.join(scene_dir, "images", v + ".exr")}"\n')
    res = os.path.join(out, "result")
    if os.path.exists(res):
        shutil.rmtree(res)
    cmd = [kdmap, "reconstruct", run, "--out", res, "--progress", "never"]
    if threads:
        cmd += ["--threads", str(threads)]
    with open(os.path.join(out, "kdmap.log"), "w") as f:
        t0 = time.perf_counter()
        p = subprocess.Popen(cmd, stdout=f, stderr=subprocess.STDOUT)
        _, status, ru = os.wait4(p.pid, 0)
        wall = time.perf_counter() - t0
    code = os.waitstatus_to_exitcode(status)
    if code != 0:
        with open(os.path.join(out, "kdmap.log")) as f:
            raise SystemExit(f"{' '.join(cmd)} exited {code}: {f.read()[-500:]}")
    with open(os.path.join(res, "report.json")) as f:
        rep = json.load(f)
    disk = sum(os.path.getsize(os.path.join(d, n)) for d, _, ns in os.walk(res) for n in ns)
    point = {
        "wall_seconds": wall,
        # CPU seconds of the process: less sensitive than wall time to what else the shared
        # machine runs, so the curve's exponent is fitted on it
        "cpu_seconds": ru.ru_utime + ru.ru_stime,
        "peak_rss_mib": ru.ru_maxrss / 1024.0,
        "timings": rep["timings"],
        "covered_texels": rep["counts"]["covered_texels"],
        "triangles": rep["counts"]["triangles"],
        "views": rep["counts"]["views"],
        "store_bytes": rep["resources"].get("store_bytes"),
        "checkpoint_bytes": rep["resources"].get("checkpoint_bytes"),
        "output_dir_bytes": disk,
        "load1": os.getloadavg()[0],
    }
    shutil.rmtree(res)  # tens of GB at the large points: keep only the figures
    return point


def slope(xs, ys):
    """Least-squares exponent of y = c x^k over the points (log-log)."""
    pts = [(math.log(x), math.log(y)) for x, y in zip(xs, ys) if x > 0 and y > 0]
    if len(pts) < 2:
        return None
    mx = sum(p[0] for p in pts) / len(pts)
    my = sum(p[1] for p in pts) / len(pts)
    sxx = sum((p[0] - mx) ** 2 for p in pts)
    return sum((p[0] - mx) * (p[1] - my) for p in pts) / sxx if sxx > 0 else None


def texel_curve(a, kdmap, cache, out):
    scene, meta = generate("curve-texels", ["--tris", "20000", "--train", "8"], cache)
    area = meta["totals"]["diffuse_area_m2"]
    points = []
    for target in a.texels:
        d = math.sqrt(target / area)
        extra = (f"[atlas]\ntexels_per_unit = {d:.3f}\nmax_texture_size = 16384\n"
                 f"[run]\nmemory_budget_mib = {a.budget}\n")
        log(f"texels: {target:.3g} wanted, {d:.1f} texels per unit")
        pt = run_point(kdmap, scene, extra, None, os.path.join(out, f"texels-{target:.0f}"), a.threads)
        pt["x"] = pt["covered_texels"]
        points.append(pt)
        log(f"  {pt['covered_texels']} texels: {pt['wall_seconds']:.1f} s, {pt['peak_rss_mib']:.0f} MiB")
    return {"x": "covered texels", "scene": scene, "points": points}


def view_curve(a, kdmap, cache, out):
    n = max(a.views)
    scene, meta = generate("curve-views", ["--tris", "20000", "--train", str(n)], cache)
    ids = [s["id"] for s in meta["sensors"] if s["id"].startswith("cam_train_")]
    points = []
    for k in a.views:
        extra = f"[atlas]\ntexels_per_unit = 64\n[run]\nmemory_budget_mib = {a.budget}\n"
        log(f"views: {k}")
        pt = run_point(kdmap, scene, extra, ids[:k], os.path.join(out, f"views-{k}"), a.threads)
        pt["x"] = pt["views"]
        points.append(pt)
        log(f"  {k} views: {pt['wall_seconds']:.1f} s, {pt['peak_rss_mib']:.0f} MiB")
    return {"x": "views", "scene": scene, "points": points}


def triangle_curve(a, kdmap, cache, out):
    points = []
    for t in a.tris:
        scene, meta = generate(f"curve-tris-{t}", ["--tris", str(t), "--train", "4"], cache)
        extra = f"[atlas]\ntexels_per_unit = 64\n[run]\nmemory_budget_mib = {a.budget}\n"
        log(f"triangles: {meta['totals']['triangles']}")
        pt = run_point(kdmap, scene, extra, None, os.path.join(out, f"tris-{t}"), a.threads)
        pt["x"] = pt["triangles"]
        points.append(pt)
        log(f"  {pt['triangles']} triangles: {pt['wall_seconds']:.1f} s, {pt['peak_rss_mib']:.0f} MiB")
    return {"x": "triangles", "scene": "cache/scenes/curve-tris-*", "points": points}


def fit(curve):
    xs = [p["x"] for p in curve["points"]]
    f = {"total": slope(xs, [p["cpu_seconds"] for p in curve["points"]]),
         "wall": slope(xs, [p["wall_seconds"] for p in curve["points"]]),
         "peak_rss": slope(xs, [p["peak_rss_mib"] for p in curve["points"]])}
    for s in STAGES:
        ys = [p["timings"].get(s, 0.0) for p in curve["points"]]
        if min(ys) > 0.05:  # stages that cost something at every point
            f[s] = slope(xs, ys)
    return f


def plot(name, curve, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    pts = curve["points"]
    xs = [p["x"] for p in pts]
    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(12, 4.8))
    ks = curve["fit"]
    series = [("total CPU s", [p["cpu_seconds"] for p in pts], "total"),
              ("total wall s", [p["wall_seconds"] for p in pts], "wall")]
    series += [(s, [p["timings"].get(s, 0.0) for p in pts], s) for s in STAGES]
    for label, ys, key in series:
        if max(ys) <= 0:
            continue
        k = ks.get(key)
        style = {"total": dict(lw=2.5, color="k"), "wall": dict(lw=1.5, color="k", ls="--")}.get(
            key, dict(lw=1.2))
        ax.plot(xs, ys, marker="o", label=f"{label}" + (f" (x^{k:.2f})" if k is not None else ""), **style)
    ref = [pts[0]["cpu_seconds"] * x / xs[0] for x in xs]
    ax.plot(xs, ref, ls=":", color="gray", label="linear from the first point")
    ax.set_xscale("log"), ax.set_yscale("log")
    ax.set_xlabel(curve["x"]), ax.set_ylabel("seconds")
    ax.set_title(f"time per stage against {curve['x']}")
    ax.legend(fontsize=7)
    ax.grid(True, which="both", alpha=0.3)
    rss = [p["peak_rss_mib"] for p in pts]
    ax2.plot(xs, rss, marker="o", color="C3", label=f"peak RSS (x^{ks['peak_rss']:.2f})")
    ax2.axhline(curve.get("budget", 0), ls="--", color="gray", label="memory_budget_mib")
    ax2.set_xscale("log")
    ax2.set_xlabel(curve["x"]), ax2.set_ylabel("MiB")
    ax2.set_ylim(bottom=0)
    ax2.set_title("peak RSS")
    ax2.legend(fontsize=8)
    ax2.grid(True, which="both", alpha=0.3)
    fig.suptitle(f"kdmap cost curve: {name} ({time.strftime('%Y-%m-%d')})")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter,
                                 epilog="\n".join(__doc__.splitlines()[1:]))
    ap.add_argument("--curves", default="texels,views,triangles")
    ap.add_argument("--texels", help="covered-texel targets, comma-separated (e.g. 0.5e6,5e6)")
    ap.add_argument("--views", help="view counts, comma-separated")
    ap.add_argument("--tris", help="triangles per curved object, comma-separated")
    ap.add_argument("--quick", action="store_true", help="small points only (a smoke run)")
    ap.add_argument("--budget", type=int, default=1024, help="memory_budget_mib of every run")
    ap.add_argument("--threads", type=int, help="kdmap --threads")
    ap.add_argument("--slack", type=float, default=0.15,
                    help="allowed exponent above 1 for total time and peak RSS (default %(default)s)")
    ap.add_argument("--cache", default=os.path.join(REPO, "cache", "scenes"))
    ap.add_argument("--out", default=os.path.join(REPO, "cache", "curves"))
    ap.add_argument("--kdmap", default=os.path.join(REPO, "target", "release", "kdmap"))
    a = ap.parse_args()
    nums = lambda s, f: [f(float(x)) for x in s.split(",") if x]  # noqa: E731
    a.texels = nums(a.texels, float) if a.texels else (QUICK["texels"] if a.quick else TEXELS)
    a.views = nums(a.views, int) if a.views else (QUICK["views"] if a.quick else VIEWS)
    a.tris = nums(a.tris, int) if a.tris else (QUICK["tris"] if a.quick else TRIS)
    kdmap = os.path.abspath(a.kdmap)
    if not os.path.exists(kdmap):
        raise SystemExit(f"{kdmap}: no such binary (cargo build --release)")
    os.makedirs(a.out, exist_ok=True)
    jpath = os.path.join(a.out, "curves.json")
    results = {}
    if os.path.exists(jpath):
        with open(jpath) as f:
            results = json.load(f)
    makers = {"texels": texel_curve, "views": view_curve, "triangles": triangle_curve}
    failures = []
    for name in [c for c in a.curves.split(",") if c]:
        if name not in makers:
            raise SystemExit(f"unknown curve {name}: choose from {', '.join(makers)}")
        t0 = time.perf_counter()
        curve = makers[name](a, kdmap, a.cache, a.out)
        curve["budget"] = a.budget
        curve["seconds"] = time.perf_counter() - t0
        curve["date"] = time.strftime("%Y-%m-%dT%H:%M:%S")
        curve["commit"] = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=REPO,
                                         capture_output=True, text=True).stdout.strip()
        curve["fit"] = fit(curve)
        results[name] = curve
        with open(jpath, "w") as f:
            json.dump(results, f, indent=1)
        png = os.path.join(a.out, f"cost_{name}.png")
        plot(name, curve, png)
        log(f"{name}: exponents " + ", ".join(f"{k} {v:.2f}" for k, v in curve["fit"].items()
                                              if v is not None) + f"; plot {os.path.relpath(png, REPO)}")
        for key in ("total", "peak_rss"):
            k = curve["fit"].get(key)
            if k is not None and k > 1 + a.slack:
                failures.append(f"{name}: {key} grows as x^{k:.2f}, more than linear")
    for f in failures:
        print(f"cost curves: {f}", file=sys.stderr)
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
