#!/usr/bin/env python3
"""kdmap nightly accuracy and performance harness (one command).

    python3 tools/nightly.py                      # full settings, every shipped scene
    python3 tools/nightly.py --quick              # smoke run (small settings)
    python3 tools/nightly.py --scenes cbox --photons 2e6 --iterations 4 --spp 32
    python3 tools/nightly.py --pages-only         # rewrite docs/accuracy.md, performance.md

Creates (or reuses) the virtual environment `.venv/` in the repository root with
tools/requirements.txt, and re-runs itself in it. Then:

1. `cargo build --release`;
1b. makes the published interiors (staircase, living-room: tools/bitterli_scene.py, from
   cache/bitterli-src/<name>, cloned from GitHub when missing) into the cache, photos and
   held-out views rendered by Mitsuba 3 once;
2. per scene of tests/fixtures (cbox, cbox-tex, lights, envmap) and the interiors: `target/
   release/kdmap reconstruct <scene>/input.xml --out <out>/<scene>` (kdmap's defaults, 1e7 photons x 6 iterations,
   unless --photons / --iterations / --quick), with its wall time and peak RSS (the child's
   max RSS from wait4); `kdmap accuracy <out>/<scene> <scene>/truth.xml` (albedo error);
3. checks report.json's re-render table against a recomputation from the EXRs with
   colour-science (tools/validate_table.py); a disagreement fails the run;
4. renders the held-out views with Mitsuba 3 from the recovered scene.xml, under the
   original and the relit lighting, against truth/*.exr, and judges the recovered albedo on
   them (albedo AOV vs the true one over pixels a training camera saw) (tools/heldout.py);
4b. with --anchor, runs the competitor anchor (tools/mitsuba_inverse.py: Mitsuba 3 `prb` +
   Adam on 256x256 textures, 150 iterations) on the same scene: by default a warm-up and
   --anchor-iterations timed iterations extrapolated to 150, with --anchor-full the real
   150 iterations, scored by the same held-out judge; records the speed-up (anchor seconds /
   kdmap wall seconds, both from this run) under the history key "anchor";
5. appends one JSON line per scene to the history (default bench-history/history.jsonl,
   git-ignored; --history or $KDMAP_BENCH_HISTORY to keep it elsewhere) and redraws the
   PNG plots beside it (tools/plot_history.py);
6. rewrites docs/accuracy.md and docs/performance.md from the whole history (per scene its
   newest full run; tools/docs_pages.py). `--pages-only` does only this, running nothing;
7. opens cbox's report.html in headless Chromium (tools/test_report_browser.py: no console
   error, every image loads, the 3D view draws, every section non-blank), installing Debian's
   `chromium` when missing; a failure fails the run (`--no-browser` skips it).

Exit code 0 when every scene ran and its table checked out; 1 otherwise (the reasons are
printed at the end and stored in the history line's `failures`).
"""

import argparse
import datetime
import json
import os
import platform
import shutil
import subprocess
import sys
import time

TOOLS = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(TOOLS)
VENV = os.path.join(REPO, ".venv")
VENV_PY = os.path.join(VENV, "bin", "python")
REQUIREMENTS = os.path.join(TOOLS, "requirements.txt")
SCENES = ["cbox", "cbox-tex", "lights", "mirror-cbox", "envmap", "open", "open-b"]
# published interiors (Bitterli's rendering resources, tools/bitterli_scene.py), made into
# --cache from their Mitsuba 0.6 form in cache/bitterli-src/<name>, cloned when missing
INTERIORS = ["staircase", "living-room"]
INTERIORS_REPO = "https://github.com/jgarciapueyo/mitsuba2-transient-scenes"
ANCHOR_TIMED_ITERATIONS = 3  # --anchor without --anchor-full: warm-up + this many, extrapolated
QUICK = {"photons": 200_000, "iterations": 2, "spp": 8}
DEFAULT_SPP = 64


def log(msg):
    print(f"[nightly {datetime.datetime.now(datetime.timezone.utc):%H:%M:%S}] {msg}", flush=True)


def ensure_venv():
    """Re-run this script inside .venv (created and filled from requirements.txt if needed)."""
    if os.path.realpath(sys.prefix) == os.path.realpath(VENV):
        return
    if not os.path.exists(VENV_PY):
        log(f"creating {VENV}")
        subprocess.check_call([sys.executable, "-m", "venv", VENV])
    probe = "import mitsuba, numpy, colour, matplotlib, playwright"
    if subprocess.call([VENV_PY, "-c", probe], stderr=subprocess.DEVNULL) != 0:
        log(f"installing {REQUIREMENTS} into {VENV}")
        subprocess.check_call([VENV_PY, "-m", "pip", "install", "-q", "-r", REQUIREMENTS])
    os.execv(VENV_PY, [VENV_PY, os.path.abspath(__file__)] + sys.argv[1:])


def run_measured(cmd, log_path, cwd=REPO):
    """Run `cmd` with stdout+stderr to `log_path`; return (exit code, wall s, peak RSS MiB of
    the child and its waited-for descendants, from wait4). Not RUSAGE_CHILDREN: that is the
    maximum over every child so far, the compiler of `cargo build` included."""
    with open(log_path, "w") as f:
        t0 = time.perf_counter()
        p = subprocess.Popen(cmd, cwd=cwd, stdout=f, stderr=subprocess.STDOUT)
        _, status, ru = os.wait4(p.pid, 0)
        wall = time.perf_counter() - t0
        p.returncode = os.waitstatus_to_exitcode(status)
    return p.returncode, wall, ru.ru_maxrss / 1024.0


def tail(path, n=5):
    try:
        with open(path) as f:
            return " | ".join(line.rstrip() for line in f.readlines()[-n:])
    except OSError:
        return ""


def git(*args):
    try:
        return subprocess.check_output(["git", *args], cwd=REPO, text=True,
                                       stderr=subprocess.DEVNULL).strip()
    except (OSError, subprocess.CalledProcessError):
        return ""


def machine():
    cpu = ""
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    mem = None
    try:
        with open("/proc/meminfo") as f:
            mem = int(f.readline().split()[1]) // 1024
    except (OSError, ValueError, IndexError):
        pass
    return {"cores": os.cpu_count(), "cpu": cpu, "mem_mib": mem, "host": platform.node(),
            "os": platform.platform(), "load1": os.getloadavg()[0]}


def rerender_summary(report):
    its = report.get("iterations", [])
    table = report.get("table", [])
    diffs = [abs(r["mean_luminance"][1] - r["mean_luminance"][0]) / r["mean_luminance"][0]
             for r in table if r["mean_luminance"][0] > 0]
    xy = [max(abs(r["xy"][1][k] - r["xy"][0][k]) for k in range(2)) for r in table]
    last = its[-1] if its else {}
    return {
        "rms_rel_error": last.get("rms_rel_error"),
        "mean_rel_error": last.get("mean_rel_error"),
        "max_rel_error": last.get("max_rel_error"),
        "rms_rel_error_per_iteration": [i["rms_rel_error"] for i in its],
        "table_rows": len(table),
        "table_mean_rel_lum_diff": sum(diffs) / len(diffs) if diffs else None,
        "table_max_rel_lum_diff": max(diffs) if diffs else None,
        "table_max_xy_diff": max(xy) if xy else None,
        "table": table,
    }


def scene_dir_of(scene, args):
    """A shipped fixture, a degraded capture (tools/captures.py) or a scene generated by
    tools/gen_scene.py into the cache."""
    if scene in args.capture_dirs:
        return args.capture_dirs[scene]
    if scene in args.generated or scene in INTERIORS:
        return os.path.join(args.cache, scene)
    return os.path.join(args.fixtures, scene)


def generate(scene, args, logs):
    """Generate the preset `scene` into the cache unless it is there with the same parameters
    (gen_scene.py reuses a complete directory); returns an error string or None."""
    return run_maker(scene, "gen_scene.py", ["--preset", scene, os.path.join(args.cache, scene)],
                     logs)


def run_maker(scene, tool, tool_args, logs):
    """Run the scene maker `tools/<tool>` with `tool_args`, logged to
    `<logs>/<scene>-generate.log`; returns an error string or None."""
    cmd = [sys.executable, os.path.join(TOOLS, tool)] + tool_args
    log(f"{scene}: {' '.join(os.path.relpath(c, REPO) if os.path.isabs(c) else c for c in cmd)}")
    log_path = os.path.join(logs, f"{scene}-generate.log")
    code, wall, _ = run_measured(cmd, log_path)
    if code != 0:
        return f"{scene}: tools/{tool} exited {code}: {tail(log_path)}"
    log(f"{scene}: scene ready ({wall:.0f} s)")
    return None


def interior_source(scene, logs):
    """cache/bitterli-src/<scene> (the published scene in Mitsuba 0.6 form), cloned from
    INTERIORS_REPO when missing; returns (path, error string or None)."""
    root = os.path.join(REPO, "cache", "bitterli-src")
    src = os.path.join(root, scene)
    if os.path.isfile(os.path.join(src, "scene.xml")):
        return src, None
    clone = os.path.join(root, "repo")
    log_path = os.path.join(logs, f"{scene}-source.log")
    cmds = [["git", "clone", "--depth", "1", "--filter=blob:none", "--sparse", INTERIORS_REPO,
             clone]] if not os.path.isdir(clone) else []
    cmds.append(["git", "-C", clone, "sparse-checkout", "add", scene])
    for cmd in cmds:
        code, _, _ = run_measured(cmd, log_path)
        if code != 0:
            return src, (f"{scene}: no {os.path.relpath(src, REPO)}/scene.xml and `git clone "
                         f"{INTERIORS_REPO}` failed ({tail(log_path, 1)}); extract its "
                         f"{scene}/ there (tools/bitterli_scene.py)")
    if not os.path.exists(src):
        os.symlink(os.path.join(clone, scene), src)
    return src, None


def generate_interior(scene, args, logs):
    """Make the interior `scene` into the cache with tools/bitterli_scene.py (photos already
    rendered are kept); returns an error string or None."""
    src, err = interior_source(scene, logs)
    if err:
        return err
    return run_maker(scene, "bitterli_scene.py", ["--src", src, os.path.join(args.cache, scene)],
                     logs)


def prepare_captures(args, logs, failures):
    """Make the degraded captures (tools/captures.py) and their run configs; returns their
    names, to run after the scenes whose perfect photos they are compared with."""
    import captures

    names = captures.DEFAULT if args.captures is None else [
        c for c in args.captures.split(",") if c]
    made = []
    for name in names:
        try:
            scene, preset = captures.split(name)
            log(f"{name}: degraded capture (tools/captures.py)")
            d = captures.ensure(name, args.fixtures, os.path.join(os.path.dirname(args.cache),
                                "capture"), os.path.join(logs, f"{name}-degrade.log"))
            _, pinned = captures.run_config(d)
        except (ValueError, RuntimeError, OSError) as e:
            failures.append(str(e))
            continue
        args.capture_dirs[name] = d
        args.capture_info[name] = {"scene": scene, "preset": preset, "pinned": pinned}
        made.append(name)
    return made


def dir_bytes(path):
    return sum(os.path.getsize(os.path.join(d, n)) for d, _, ns in os.walk(path) for n in ns)


def run_scene(scene, args, kdmap, logs):
    """Reconstruct, score and check one scene; return its history record."""
    scene_dir = scene_dir_of(scene, args)
    out = os.path.join(args.out, scene)
    rec = {"scene": scene, "failures": []}
    if os.path.exists(out):
        shutil.rmtree(out)
    run_toml = os.path.join(scene_dir, "run.toml")
    entry = run_toml if scene in args.capture_dirs else os.path.join(scene_dir, "input.xml")
    cmd = [kdmap, "reconstruct", entry, "--out", out]
    if args.photons is not None:
        cmd += ["--photons", str(int(float(args.photons)))]
    if args.iterations is not None:
        cmd += ["--iterations", str(args.iterations)]
    if args.threads is not None:
        cmd += ["--threads", str(args.threads)]
    rec["command"] = " ".join(os.path.relpath(c, REPO) if os.path.isabs(c) else c for c in cmd)
    log(f"{scene}: {rec['command']}")
    log_path = os.path.join(logs, f"{scene}-reconstruct.log")
    code, wall, rss = run_measured(cmd, log_path)
    rec.update(wall_seconds=wall, peak_rss_mib=rss, exit_code=code)
    if code != 0:
        rec["failures"].append(f"{scene}: kdmap reconstruct exited {code}: {tail(log_path)}")
        return rec
    with open(os.path.join(out, "report.json")) as f:
        report = json.load(f)
    s = report["settings"]
    rec["settings"] = {k: s.get(k) for k in ("photons", "iterations", "seed", "threads",
                                             "update", "smoothing_radius", "refine_passes")}
    rec["settings"]["texels_per_unit"] = s.get("atlas", {}).get("texels_per_unit")
    rec["timings"] = report["timings"]
    rec["rays"] = report.get("rays")
    rec["counts"] = report["counts"]
    res = report.get("resources", {})
    # what the run wrote to disk: its working tile stores (geometry + state, scratch
    # excluded), every checkpoint snapshot, and the outputs left in its directory
    rec["disk"] = {"store_bytes": res.get("store_bytes"),
                   "checkpoint_bytes_written": res.get("checkpoint_bytes"),
                   "output_dir_bytes": dir_bytes(out)}
    rec["peak_rss_by_stage_mib"] = res.get("peak_rss_mib")
    rec["stopped_by"] = report.get("stopped_by")
    its = report.get("iterations", [])
    photons = sum(i["photons"] for i in its)
    psec = sum(i["photon_seconds"] for i in its)
    rec["photons_traced"] = photons
    rec["photons_per_second"] = photons / psec if psec > 0 else None
    rec["iterations"] = its
    rec["rerender"] = rerender_summary(report)
    log(f"{scene}: {wall:.1f} s, peak RSS {rss:.0f} MiB, "
        f"{(rec['photons_per_second'] or 0) / 1e6:.2f} M photons/s, disk: checkpoints "
        f"{(rec['disk']['checkpoint_bytes_written'] or 0) / 1e6:.0f} MB written, "
        f"output directory {rec['disk']['output_dir_bytes'] / 1e6:.0f} MB; stages (s): "
        + ", ".join(f"{k} {v:.1f}" for k, v in rec["timings"].items() if v))

    acc_log = os.path.join(logs, f"{scene}-accuracy.log")
    code, awall, _ = run_measured([kdmap, "accuracy", out, os.path.join(scene_dir, "truth.xml")],
                                  acc_log)
    acc_json = os.path.join(out, "accuracy", "accuracy.json")
    if code == 0 and os.path.exists(acc_json):
        with open(acc_json) as f:
            rec["accuracy"] = json.load(f)
        rec["accuracy"]["seconds"] = awall
        log(f"{scene}: albedo error mean {100 * rec['accuracy']['mean_rel_error']:.2f}%, "
            f"rel. L1 {100 * rec['accuracy']['rel_l1_error']:.2f}%")
        cal = rec["accuracy"].get("calibration") or {}
        if cal.get("texels"):
            # is the predicted standard error of K_d (maps/*_kd_stderr) calibrated?
            log(f"{scene}: {100 * cal['within_one']:.0f}% of texels within one predicted "
                f"standard error (68% if calibrated), {100 * cal['within_two']:.0f}% within two")
    else:
        rec["failures"].append(f"{scene}: kdmap accuracy exited {code}: {tail(acc_log)}")

    import validate_table

    t0 = time.perf_counter()
    chk = validate_table.validate(out, scene_dir)
    chk["seconds"] = time.perf_counter() - t0
    rec["table_check"] = chk
    if chk.get("skipped"):
        log(f"{scene}: table check skipped ({chk['skipped']})")
    elif chk["ok"]:
        log(f"{scene}: table check OK ({chk['rows']} rows within {validate_table.RTOL:.0e}; "
            + ", ".join(f"{k} {v:.1e}" for k, v in chk["worst"].items()) + ")")
    else:
        for e in chk["errors"]:
            rec["failures"].append(f"{scene}: re-render table disagrees with colour-science: {e}")

    if not args.no_mitsuba:
        import heldout

        t0 = time.perf_counter()
        try:
            m = heldout.score(out, scene_dir, spp=args.spp, floor=args.floor,
                              llvm=scene in INTERIORS)
            m["seconds"] = time.perf_counter() - t0
            rec["mitsuba"] = m
            def seen(k):
                v = m[k].get("block8_rel_lum_error_seen")
                return "" if v is None else f", 8x8 where seen {100 * v:.2f}%"

            parts = [f"{k} rel. L1 {100 * m[k]['rel_l1_error']:.2f}% "
                     f"(pixel {100 * m[k]['mean_rel_lum_error']:.2f}%, "
                     f"8x8 {100 * m[k]['block8_rel_lum_error']:.2f}%{seen(k)})"
                     for k in ("original", "relit") if k in m]
            log(f"{scene}: Mitsuba held-out at {args.spp} spp: " + "; ".join(parts)
                + f" [{m['seconds']:.0f} s]")
            alb = m.get("albedo", {})
            if "error" in alb:
                rec["failures"].append(f"{scene}: held-out albedo judge failed: {alb['error']}")
            elif alb:
                log(f"{scene}: held-out albedo over {alb['masked_pixels']} pixels seen in "
                    f"training ({100 * alb['masked_fraction']:.1f}%): mean rel. "
                    f"{100 * alb['albedo_mean_rel_error']:.2f}%, rel. L1 "
                    f"{100 * alb['albedo_rel_l1']:.2f}%, PSNR "
                    f"{alb.get('albedo_psnr_db', float('nan')):.2f} dB")
        except Exception as e:  # a Mitsuba failure is a finding, not a crash of the harness
            rec["failures"].append(f"{scene}: Mitsuba held-out scoring failed: "
                                   f"{type(e).__name__}: {e}")
    if args.projection_floor and not args.no_mitsuba:
        rec["projection_floor"] = run_projection_floor(scene, scene_dir, out, args, kdmap, rec)
    if args.noise_calibration:
        rec["noise_calibration"] = run_noise_calibration(scene, scene_dir, args, kdmap, rec)
    if args.anchor:
        rec["anchor"] = run_anchor(scene, scene_dir, args, rec, logs)
    return rec


def run_projection_floor(scene, scene_dir, out, args, kdmap, rec):
    """The run's held-out albedo against its projection floor (noise-free albedo
    photos projected with the same settings, `projection_floor.py`), or None. Fixtures without
    `albedo/` images are skipped rather than written into."""
    import projection_floor

    in_cache = os.path.abspath(scene_dir).startswith(os.path.abspath(args.cache))
    if not in_cache and not os.path.isdir(os.path.join(scene_dir, "albedo")):
        log(f"{scene}: projection floor skipped (no albedo/ images; "
            f"tools/render_albedo_aov.py makes them)")
        return None
    t0 = time.perf_counter()
    try:
        j = projection_floor.measure(out, scene_dir, None, args.spp or DEFAULT_SPP, kdmap)
    except projection_floor.FloorError as e:
        rec["failures"].append(f"{scene}: projection floor failed: {e}")
        return None
    f = {"albedo_mean_rel_error": j["albedo_mean_rel_error"],
         "albedo_rel_l1": j["albedo_rel_l1"], "seconds": time.perf_counter() - t0}
    log(f"{scene}: projection floor (held-out albedo of noise-free albedo photos) "
        f"{100 * f['albedo_mean_rel_error']:.2f}% [{f['seconds']:.0f} s]")
    return f


def run_noise_calibration(scene, scene_dir, args, kdmap, rec):
    """Per shape, the K_d noise measured with a second set of photos and a second
    seed over the predicted standard error (`noise_calibration.py`; its runs and photos in
    `cache/noise-calibration/<scene>`, beside the scene cache), with the median and the worst ratio, or None."""
    import noise_calibration

    t0 = time.perf_counter()
    work = os.path.join(os.path.dirname(os.path.abspath(args.cache)), "noise-calibration", scene)
    try:
        shapes = noise_calibration.measure(scene_dir, work, {}, 7, kdmap)
    except noise_calibration.CalibrationError as e:
        rec["failures"].append(f"{scene}: noise calibration failed: {e}")
        return None
    ratios = sorted(r["ratio"] for r in shapes.values() if r["ratio"] == r["ratio"])
    if not ratios:
        rec["failures"].append(f"{scene}: noise calibration: no shape with a ratio")
        return None
    f = {"shapes": shapes, "median_ratio": ratios[len(ratios) // 2],
         "worst_ratio": max(ratios, key=lambda r: max(r, 1 / r) if r > 0 else float("inf")),
         "seconds": time.perf_counter() - t0}
    log(f"{scene}: K_d noise measured / predicted (1 if calibrated): median "
        f"{f['median_ratio']:.2f}, worst {f['worst_ratio']:.2f} over {len(ratios)} shapes "
        f"[{f['seconds']:.0f} s]")
    return f


HELDOUT_FIGURES = [("albedo", "albedo_mean_rel_error"), ("albedo", "albedo_rel_l1"),
                   ("original", "rel_l1_error"), ("original", "mean_rel_lum_error"),
                   ("original", "block8_rel_lum_error"), ("relit", "rel_l1_error"),
                   ("relit", "mean_rel_lum_error"), ("relit", "block8_rel_lum_error"),
                   ("original", "block8_rel_lum_error_seen"),
                   ("relit", "block8_rel_lum_error_seen")]


def run_anchor(scene, scene_dir, args, rec, logs):
    """The competitor anchor on `scene` (a subprocess: its own Mitsuba variant and Dr.Jit
    threads); returns the history record's "anchor" entry."""
    out = os.path.join(args.out, "anchor", scene)
    if os.path.exists(out):
        shutil.rmtree(out)
    cmd = [sys.executable, os.path.join(TOOLS, "mitsuba_inverse.py"), scene_dir, "--out", out]
    if args.anchor_full:
        cmd += ["--iterations", str(args.anchor_full)]
    else:
        cmd += ["--time-only", str(args.anchor_iterations)]
    if args.threads is not None:
        cmd += ["--threads", str(args.threads)]
    a = {"mode": "full" if args.anchor_full else "time_only",
         "iterations": args.anchor_full or 150,
         "command": " ".join(os.path.relpath(c, REPO) if os.path.isabs(c) else c for c in cmd)}
    log(f"{scene}: anchor: {a['command']}")
    log_path = os.path.join(logs, f"{scene}-anchor.log")
    code, wall, rss = run_measured(cmd, log_path)
    a.update(exit_code=code, wall_seconds=wall, peak_rss_mib=rss)
    js = os.path.join(out, "anchor.json")
    if code != 0 or not os.path.exists(js):
        rec["failures"].append(f"{scene}: anchor (tools/mitsuba_inverse.py) exited {code}: "
                               f"{tail(log_path)}")
        return a
    with open(js) as f:
        aj = json.load(f)
    for k in ("settings", "shapes", "skipped", "views", "load_seconds", "warmup_seconds",
              "compile_seconds", "seconds_per_iteration", "extrapolated_iterations",
              "extrapolated_seconds", "optimize_seconds", "measured_iterations",
              "iteration_seconds", "loss", "machine"):
        a[k] = aj.get(k)
    kd = rec.get("wall_seconds") if rec.get("exit_code") == 0 else None
    a["kdmap_wall_seconds"] = kd
    # The anchor's time: its measured optimisation (every iteration, the JIT warm-up included)
    # in a full run, else warm-up + K iterations extrapolated to 150. Scene loading (~0.1 s)
    # and Python start-up are left out, in the anchor's favour.
    a["anchor_seconds"] = aj["optimize_seconds"] if args.anchor_full else aj["extrapolated_seconds"]
    a["speedup"] = a["anchor_seconds"] / kd if kd else None
    a["speedup_extrapolated"] = aj["extrapolated_seconds"] / kd if kd else None
    msg = (f"{scene}: anchor {aj['seconds_per_iteration']:.2f} s/iteration, compile "
           f"{aj['compile_seconds']:.1f} s, {aj['extrapolated_iterations']} iterations "
           f"extrapolated {aj['extrapolated_seconds']:.0f} s")
    if args.anchor_full:
        msg += f" (measured: {aj['optimize_seconds']:.0f} s optimising, {wall:.0f} s process)"
    if kd:
        msg += f"; kdmap {kd:.1f} s: speed-up x{a['speedup']:.1f}"
    log(msg)
    if args.anchor_full and not args.no_mitsuba:
        import heldout

        t0 = time.perf_counter()
        try:
            m = heldout.score(out, scene_dir, spp=args.spp)
            m["seconds"] = time.perf_counter() - t0
            a["mitsuba"] = m
            a["compare"] = {}
            for part, key in HELDOUT_FIGURES:
                a["compare"][f"{part}.{key}"] = {
                    "kdmap": (rec.get("mitsuba") or {}).get(part, {}).get(key),
                    "anchor": m.get(part, {}).get(key)}
            log(f"{scene}: held-out, kdmap vs anchor: " + "; ".join(
                f"{k} {_pct(v['kdmap'])} vs {_pct(v['anchor'])}"
                for k, v in a["compare"].items()))
            if "error" in m.get("albedo", {}):
                rec["failures"].append(f"{scene}: held-out albedo judge failed on the anchor: "
                                       f"{m['albedo']['error']}")
        except Exception as e:
            rec["failures"].append(f"{scene}: Mitsuba held-out scoring of the anchor failed: "
                                   f"{type(e).__name__}: {e}")
    return a


def _pct(v):
    return "-" if v is None else f"{100 * v:.2f}%"


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter,
                                 epilog="\n".join(__doc__.splitlines()[1:]))
    ap.add_argument("--scenes", default=",".join(SCENES + INTERIORS),
                    help="comma-separated scenes of --fixtures, tools/gen_scene.py presets "
                    "(e.g. room: 1.1M triangles, 16 views) or published interiors ("
                    + ", ".join(INTERIORS) + ": tools/bitterli_scene.py), made into --cache "
                    "unless there (default: %(default)s)")
    ap.add_argument("--photons", help="photons per iteration (default: kdmap's, 1e7)")
    ap.add_argument("--iterations", type=int, help="iterations (default: kdmap's, 6)")
    ap.add_argument("--threads", type=int, help="kdmap --threads (default: all cores)")
    ap.add_argument("--quick", action="store_true",
                    help=f"smoke run: {QUICK['photons']} photons, {QUICK['iterations']} "
                         f"iterations, {QUICK['spp']} spp (unless given)")
    ap.add_argument("--out", default=os.path.join(REPO, "out", "nightly"),
                    help="directory for the runs' outputs (default: out/nightly, replaced)")
    ap.add_argument("--history", default=os.environ.get(
        "KDMAP_BENCH_HISTORY", os.path.join(REPO, "bench-history", "history.jsonl")),
                    help="JSON-lines history file (default: bench-history/history.jsonl)")
    ap.add_argument("--plots", help="plot directory (default: plots/ beside the history)")
    ap.add_argument("--docs", default=os.path.join(REPO, "docs"),
                    help="where the generated pages accuracy.md and performance.md go "
                    "(default: docs/)")
    ap.add_argument("--no-pages", action="store_true",
                    help="do not rewrite the pages (e.g. for a trial history)")
    ap.add_argument("--pages-only", action="store_true",
                    help="only rewrite the pages from the existing history; runs nothing")
    ap.add_argument("--spp", type=int, help=f"Mitsuba samples per pixel (default {DEFAULT_SPP})")
    ap.add_argument("--floor", action="store_true",
                    help="also render the true scenes in Mitsuba (noise floor of the held-out error)")
    ap.add_argument("--no-mitsuba", action="store_true", help="skip the held-out renders")
    ap.add_argument("--projection-floor", action="store_true",
                    help="also score the projection floor (tools/projection_floor.py: the "
                    "held-out albedo of noise-free albedo photos projected with the same "
                    "settings; scenes with albedo/ images or generated ones)")
    ap.add_argument("--noise-calibration", action="store_true",
                    help="also check the predicted standard error of K_d against noise measured "
                    "with a second render of the photos and a second seed "
                    "(tools/noise_calibration.py; minutes of Mitsuba per scene)")
    ap.add_argument("--captures", default=None,
                    help="degraded captures to score, <scene>-<preset> comma-separated "
                         "(default: tools/captures.py's list; '' for none)")
    ap.add_argument("--no-build", action="store_true", help="use the existing release binary")
    ap.add_argument("--no-browser", action="store_true",
                    help="skip the check of cbox's report.html in headless Chromium")
    ap.add_argument("--kdmap", help="kdmap binary to measure (default: target/release/kdmap; "
                    "implies --no-build)")
    ap.add_argument("--fixtures", default=os.path.join(REPO, "tests", "fixtures"))
    ap.add_argument("--cache", default=os.path.join(REPO, "cache", "scenes"),
                    help="where generated scenes live (default: cache/scenes, git-ignored)")
    ap.add_argument("--anchor", action="store_true",
                    help="also run the competitor anchor (tools/mitsuba_inverse.py, Mitsuba 3 "
                    "prb + Adam) per scene and record the speed-up")
    ap.add_argument("--anchor-iterations", type=int, default=ANCHOR_TIMED_ITERATIONS,
                    metavar="K", help="anchor: timed iterations after the warm-up, "
                    "extrapolated to 150 (default %(default)s)")
    ap.add_argument("--anchor-full", nargs="?", type=int, const=150, metavar="N",
                    help="anchor: really run the 150 iterations (N: another count, for trying "
                    "the harness; not the anchor's definition) and score the result with the "
                    "held-out judge (implies --anchor)")
    args = ap.parse_args()
    if args.anchor_full is not None and args.anchor_full < 1:
        ap.error("--anchor-full N needs N >= 1")
    if args.anchor_full:
        args.anchor = True
    if args.anchor_iterations < 1:
        ap.error("--anchor-iterations must be >= 1")

    if args.pages_only:  # the standard library suffices: no venv, no build, no run
        sys.path.insert(0, TOOLS)
        return write_pages(args)
    ensure_venv()
    sys.path.insert(0, TOOLS)
    if args.quick:
        args.photons = args.photons or QUICK["photons"]
        args.iterations = args.iterations or QUICK["iterations"]
        args.spp = args.spp or QUICK["spp"]
    args.spp = args.spp or DEFAULT_SPP
    args.out = os.path.abspath(args.out)
    import gen_scene

    args.generated = []
    scenes = [s for s in args.scenes.split(",") if s]
    for s in scenes:
        if os.path.exists(os.path.join(args.fixtures, s, "input.xml")) or s in INTERIORS:
            continue
        if s not in gen_scene.PRESETS:
            ap.error(f"no scene {s} in {args.fixtures}, nor a tools/gen_scene.py preset "
                     f"({', '.join(gen_scene.PRESETS)})")
        args.generated.append(s)
    t_start = time.perf_counter()
    logs = os.path.join(args.out, "logs")
    os.makedirs(logs, exist_ok=True)

    build = {"skipped": True}
    if not args.no_build and not args.kdmap:
        log("cargo build --release")
        code, wall, _ = run_measured(["cargo", "build", "--release"],
                                     os.path.join(logs, "build.log"))
        build = {"seconds": wall, "exit_code": code}
        if code != 0:
            print(f"nightly: cargo build --release failed ({tail(os.path.join(logs, 'build.log'))})",
                  file=sys.stderr)
            return 1
    kdmap = os.path.abspath(args.kdmap or os.path.join(REPO, "target", "release", "kdmap"))

    commit = git("rev-parse", "HEAD")
    dirty = bool(git("status", "--porcelain", "--untracked-files=no"))
    common = {
        "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "commit": commit,
        "dirty": dirty,
        "branch": git("rev-parse", "--abbrev-ref", "HEAD"),
        "machine": machine(),
        "quick": bool(args.quick),
        "requested": {"photons": args.photons, "iterations": args.iterations, "spp": args.spp},
        "build": build,
    }
    records, failures = [], []
    args.capture_dirs, args.capture_info = {}, {}
    for scene in args.generated + [s for s in scenes if s in INTERIORS]:
        err = (generate_interior if scene in INTERIORS else generate)(scene, args, logs)
        if err:
            failures.append(err)
            scenes.remove(scene)
    scenes += prepare_captures(args, logs, failures)
    for scene in scenes:
        rec = dict(common)
        rec.update(run_scene(scene, args, kdmap, logs))
        if scene in args.capture_dirs:
            rec["capture"] = args.capture_info[scene]
        rec["ok"] = not rec["failures"]
        failures += rec["failures"]
        records.append(rec)
        os.makedirs(os.path.dirname(os.path.abspath(args.history)), exist_ok=True)
        with open(args.history, "a") as f:
            f.write(json.dumps(rec, separators=(",", ":")) + "\n")

    if "cbox" in scenes and not args.no_browser:
        err = check_report_page(os.path.join(args.out, "cbox"), logs)
        if err:
            failures.append(err)

    import plot_history

    plots = args.plots or os.path.join(os.path.dirname(os.path.abspath(args.history)), "plots")
    try:
        written = plot_history.plot(args.history, plots)
        log(f"plots: {', '.join(os.path.relpath(p) for p in written)}")
    except Exception as e:
        failures.append(f"plotting failed: {type(e).__name__}: {e}")

    if not args.no_pages and write_pages(args) != 0:
        failures.append("writing the pages failed (see above)")
    print_summary(records)
    log(f"history: {args.history}; harness took {time.perf_counter() - t_start:.0f} s")
    if failures:
        print("\nnightly FAILED:", file=sys.stderr)
        for f in failures:
            print(f"  {f}", file=sys.stderr)
        return 1
    return 0


def check_report_page(out, logs):
    """tools/test_report_browser.py on a finished run's page; a failure line, or None."""
    if shutil.which("chromium") is None:
        log("installing chromium (apt-get)")
        env = dict(os.environ, DEBIAN_FRONTEND="noninteractive")
        for cmd in (["apt-get", "update", "-qq"], ["apt-get", "install", "-y", "-qq", "chromium"]):
            if subprocess.call(cmd, env=env, stdout=subprocess.DEVNULL) != 0:
                return "report page: chromium is missing and apt-get could not install it"
    log_path = os.path.join(logs, "report-browser.log")
    cmd = [sys.executable, os.path.join(TOOLS, "test_report_browser.py"), "--out", out]
    code, wall, _ = run_measured(cmd, log_path)
    log(f"report page in Chromium: {tail(log_path, 2)} ({wall:.0f} s)")
    return None if code == 0 else f"report page in Chromium failed: {tail(log_path)}"


def write_pages(args):
    """docs/accuracy.md and docs/performance.md from the history (tools/docs_pages.py)."""
    import docs_pages

    try:
        written = docs_pages.write_pages(args.history, args.docs, SCENES + INTERIORS)
    except Exception as e:
        log(f"pages from {args.history}: {type(e).__name__}: {e}")
        return 1
    log(f"pages: {', '.join(os.path.relpath(p) for p in written)} (from {args.history})")
    return 0


def print_summary(records):
    def pct(v):
        return "-" if v is None else f"{100 * v:.2f}%"

    def g(d, *ks):
        for k in ks:
            d = d.get(k) if isinstance(d, dict) else None
        return d

    print("\n| scene | albedo mean rel. | albedo rel. L1 | re-render RMS | total s | photons s | "
          "M photons/s | peak RSS MiB | Mitsuba orig. L1 | Mitsuba relit L1 | "
          "held-out albedo mean rel. | held-out albedo rel. L1 | table check |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r in records:
        pps = r.get("photons_per_second")
        print(f"| {r['scene']} | {pct(g(r, 'accuracy', 'mean_rel_error'))} | "
              f"{pct(g(r, 'accuracy', 'rel_l1_error'))} | {pct(g(r, 'rerender', 'rms_rel_error'))} | "
              f"{g(r, 'timings', 'total') or 0:.1f} | {g(r, 'timings', 'photons') or 0:.1f} | "
              f"{(pps or 0) / 1e6:.2f} | {r.get('peak_rss_mib', 0):.0f} | "
              f"{pct(g(r, 'mitsuba', 'original', 'rel_l1_error'))} | "
              f"{pct(g(r, 'mitsuba', 'relit', 'rel_l1_error'))} | "
              f"{pct(g(r, 'mitsuba', 'albedo', 'albedo_mean_rel_error'))} | "
              f"{pct(g(r, 'mitsuba', 'albedo', 'albedo_rel_l1'))} | "
              f"{'OK' if g(r, 'table_check', 'ok') else 'FAIL'} |")
    anchored = [r for r in records if r.get("anchor")]
    if anchored:
        print("\n| scene | anchor mode (iterations) | anchor s/it. | compile s | anchor s | "
              "kdmap s | speed-up | held-out albedo mean rel. kdmap / anchor | albedo rel. L1 | "
              "orig. L1 | relit L1 |")
        print("|---|---|---|---|---|---|---|---|---|---|---|")
        for r in anchored:
            a = r["anchor"]
            cmp_ = a.get("compare", {})

            def both(k):
                c = cmp_.get(k)
                return "-" if not c else f"{pct(c['kdmap'])} / {pct(c['anchor'])}"

            def num(v, f="{:.2f}"):
                return "-" if v is None else f.format(v)

            print(f"| {r['scene']} | {a.get('mode')} ({a.get('iterations')}) | "
                  f"{num(a.get('seconds_per_iteration'))} | "
                  f"{num(a.get('compile_seconds'), '{:.1f}')} | "
                  f"{num(a.get('anchor_seconds'), '{:.0f}')} | "
                  f"{num(a.get('kdmap_wall_seconds'), '{:.1f}')} | "
                  f"{num(a.get('speedup'), 'x{:.1f}')} | {both('albedo.albedo_mean_rel_error')} | "
                  f"{both('albedo.albedo_rel_l1')} | {both('original.rel_l1_error')} | "
                  f"{both('relit.rel_l1_error')} |")
    floored = [r for r in records if r.get("projection_floor")]
    if floored:
        print("\n| scene | held-out albedo mean rel. | projection floor | "
              "the rest (light, noise) |")
        print("|---|---|---|---|")
        for r in floored:
            run = g(r, "mitsuba", "albedo", "albedo_mean_rel_error")
            fl = r["projection_floor"]["albedo_mean_rel_error"]
            rest = None if run is None else run - fl
            print(f"| {r['scene']} | {pct(run)} | {pct(fl)} | {pct(rest)} |")
    for r in records:
        acc = r.get("accuracy")
        if not acc:
            continue
        print(f"\n{r['scene']}: per shape (albedo mean rel. / rel. L1 / mean K_d vs truth)")
        for s in acc.get("shapes", []):
            kd = " ".join(f"{v:.4f}" for v in s["mean_kd"])
            tr = " ".join(f"{v:.4f}" for v in s["mean_truth"])
            print(f"  {s['shape']:<12} {s['texels']:>8} {pct(s['mean_rel_error']):>8} "
                  f"{pct(s['rel_l1_error']):>8}  {kd}  vs {tr}")


if __name__ == "__main__":
    sys.exit(main())
