"""The generated pages docs/accuracy.md and docs/performance.md, from the nightly history.

`tools/nightly.py` calls `write_pages` at the end of every run (and alone with `--pages-only`).
Per scene the page shows one history entry: the newest full run whose reconstruction finished
(a `--quick` run only when the scene has no full one; it is then marked "(quick)"). Everything
but `load_history` and `write_pages` is a pure function of history entries (dicts as
`nightly.py` appends them), so the tables can be tested on synthetic entries (`tools/test_docs_pages.py`). Standard library
only: no Mitsuba, numpy or matplotlib needed.
"""

import json
import math
import os

REGENERATE = "python3 tools/nightly.py"
DEFAULT_HISTORY = "bench-history/history.jsonl"


# ---------------------------------------------------------------------------------------------
# History


def load_history(path):
    """The history's entries in file order (lines that are not JSON objects are skipped)."""
    entries = []
    with open(path) as f:
        for line in f:
            line = line.strip()
            if not line:
                continue
            try:
                e = json.loads(line)
            except json.JSONDecodeError:
                continue
            if isinstance(e, dict):
                entries.append(e)
    return entries


def reconstructed(e):
    """Whether the entry's reconstruction finished (a failed run has no figures to show)."""
    return e.get("exit_code", 0) == 0 and isinstance(e.get("timings"), dict)


def latest_per_scene(entries, order=()):
    """{scene: entry}: per scene the newest full entry that reconstructed, else the newest
    quick one; newest by `date` (ISO 8601, UTC), ties broken by position in the history.
    Scenes in `order` first, then the others alphabetically."""
    best = {}
    for i, e in enumerate(entries):
        scene = e.get("scene")
        if not scene or not reconstructed(e):
            continue
        key = (not e.get("quick"), str(e.get("date", "")), i)
        if scene not in best or key > best[scene][0]:
            best[scene] = (key, e)
    rank = {s: i for i, s in enumerate(order)}
    scenes = sorted(best, key=lambda s: (rank.get(s, len(rank)), s))
    return {s: best[s][1] for s in scenes}


# ---------------------------------------------------------------------------------------------
# Formatting


def get(d, *keys):
    for k in keys:
        if not isinstance(d, dict) or k not in d:
            return None
        d = d[k]
    return d


RAY_STAGES = [("atlas", ("atlas",)), ("projection", ("projection",)), ("direct", ("direct",)),
              ("caustics", ("caustics",)), ("estimate", ("gather", "photons")),
              ("output", ("output",))]


def rays_table(latest, label):
    """The rays each stage cast (`rays` of `report.json`) and their rate per core against the
    stage's wall time: near the ray-casting limit a stage is bound by its rays, far below it
    by other work."""
    have = {s: e for s, e in latest.items() if isinstance(e.get("rays"), dict)}
    if not have:
        return []
    used = [k for k, _ in RAY_STAGES if any(_num(e["rays"].get(k)) and e["rays"][k] > 0
                                             for e in have.values())]
    rows = []
    for s, e in have.items():
        cores = e["rays"].get("cores") or 1
        row = [label(s, e), str(cores)]
        for k, parts in RAY_STAGES:
            if k not in used:
                continue
            n = e["rays"].get(k) or 0
            secs = sum(e["timings"].get(p) or 0 for p in parts)
            row.append(f"{n / 1e6:.2f} ({n / 1e6 / (secs * cores):.2f})" if n and secs > 0
                       else "-")
        rows.append(row)
    return ["## Rays per stage\n",
            "Million rays each stage cast (`rays` of `report.json`), and in brackets million rays "
            "per second per core over the stage's wall time. obvhs casts about 5-10 M rays/s per "
            "core on small scenes: a stage near that is bound by its rays, one far below spends "
            "its time elsewhere.\n",
            table(["scene", "cores"] + used, rows) + "\n"]


def _num(v):
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def pct(v):
    """A fraction as a percentage with two decimals ("0.0123" -> "1.23%"); "-" if missing."""
    return f"{100 * v:.2f}%" if _num(v) else "-"


def db(v):
    return f"{v:.2f} dB" if _num(v) else "-"


def fixed(v, digits=1):
    return f"{v:.{digits}f}" if _num(v) else "-"


def mega(v, digits=2):
    return f"{v / 1e6:.{digits}f}" if _num(v) else "-"


def speedup(v):
    return f"x{v:.1f}" if _num(v) else "-"


def pair(a, b):
    """kdmap's and the anchor's figure side by side."""
    return "-" if not (_num(a) or _num(b)) else f"{pct(a)} / {pct(b)}"


def label(scene, e):
    return f"{scene} (quick)" if e.get("quick") else scene


def table(header, rows):
    out = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    out += ["| " + " | ".join(str(c).replace("|", "\\|") for c in r) + " |" for r in rows]
    return "\n".join(out)


def header(title, what):
    return (f"# {title}\n\n"
            f"Generated by `{REGENERATE}` at the end of every run, from the benchmark history "
            f"(`--history`, default `{DEFAULT_HISTORY}`); `{REGENERATE} --pages-only` rebuilds "
            "it from the history without running anything. Do not edit by hand.\n\n"
            f"{what} Per scene: its newest full run (kdmap's defaults unless the settings "
            "column says otherwise); a scene with only `--quick` runs shows the newest of "
            "those, marked (quick).\n")


def settings_text(e):
    req = e.get("requested") or {}
    parts = []
    if req.get("photons") is not None:
        parts.append(f"photons {req['photons']}")
    if req.get("iterations") is not None:
        parts.append(f"{req['iterations']} iterations")
    return ", ".join(parts) if parts else "defaults"


def machine_text(m):
    m = m or {}
    parts = []
    if m.get("cores") is not None:
        parts.append(f"{m['cores']} cores")
    if m.get("cpu"):
        parts.append(str(m["cpu"]))
    if _num(m.get("load1")):
        parts.append(f"load {m['load1']:.1f}")
    return ", ".join(parts) or "-"


def runs_table(latest):
    rows = []
    for s, e in latest.items():
        commit = str(e.get("commit") or "-")[:7] + (" (dirty)" if e.get("dirty") else "")
        checks = "ok" if e.get("ok", not e.get("failures")) else \
            f"{len(e.get('failures') or [])} failed"
        rows.append([label(s, e), str(e.get("date") or "-"), commit, settings_text(e),
                     machine_text(e.get("machine")), checks])
    return table(["scene", "date (UTC)", "commit", "kdmap settings", "machine (load: 1-minute "
                  "average at the start)", "harness checks"], rows)


# ---------------------------------------------------------------------------------------------
# Pages


def accuracy_page(entries, order=()):
    latest = latest_per_scene(entries, order)
    out = [header("Accuracy", "Albedo and image errors of kdmap's reconstructions, scored by "
                  "`tools/nightly.py` (held-out figures by Mitsuba 3, `tools/heldout.py`).")]
    if not latest:
        out.append("The history holds no finished run.\n")
        return "\n".join(out)
    out.append("## Runs\n")
    out.append(runs_table(latest) + "\n")

    # Held-out views, Mitsuba 3
    out.append("## Held-out views (Mitsuba 3)\n")
    out.append("The recovered scene rendered from the held-out cameras `cam_test_*`. Albedo: "
               "the albedo AOV against the true one over the pixels some training camera saw, "
               "mean relative error per pixel, relative L1 and PSNR (peak 1, the k_d PSNR "
               "inverse-rendering papers report). Images: relative error of the "
               "8x8-block mean luminance (`8x8`) and relative L1 of the image, under the "
               "original light and under the other light of `relit.xml`.\n")
    floors = any(get(e, "mitsuba", "floor") for e in latest.values())
    head = ["scene", "spp", "albedo mean rel.", "albedo rel. L1", "albedo PSNR", "pixels seen",
            "relit 8x8", "relit rel. L1", "original 8x8", "original rel. L1"]
    if floors:
        head += ["floor: relit 8x8", "floor: original 8x8"]
    rows = []
    for s, e in latest.items():
        m = e.get("mitsuba")
        if not isinstance(m, dict):
            continue
        seen = get(m, "albedo", "masked_fraction")
        r = [label(s, e), str(m.get("spp", "-")), pct(get(m, "albedo", "albedo_mean_rel_error")),
             pct(get(m, "albedo", "albedo_rel_l1")), db(get(m, "albedo", "albedo_psnr_db")),
             pct(seen),
             pct(get(m, "relit", "block8_rel_lum_error")), pct(get(m, "relit", "rel_l1_error")),
             pct(get(m, "original", "block8_rel_lum_error")),
             pct(get(m, "original", "rel_l1_error"))]
        if floors:
            r += [pct(get(m, "floor", "relit", "block8_rel_lum_error")),
                  pct(get(m, "floor", "original", "block8_rel_lum_error"))]
        rows.append(r)
    if rows:
        out.append(table(head, rows) + "\n")
        if floors:
            out.append("Floor: the true scene rendered at the same spp and scored the same way "
                       "(Monte Carlo noise alone); `-` where the run did not render it "
                       "(`--floor`).\n")
    else:
        out.append("No run was scored by Mitsuba (`--no-mitsuba`).\n")

    # Against the truth, texel by texel
    out.append("## Albedo against the truth (observed texels)\n")
    out.append("`kdmap accuracy`: the recovered K_d of every texel a training camera observed "
               "against the true albedo averaged over the texel; mean relative error per texel "
               "and relative L1, and the share of texels whose luminance error lies within one "
               "and two of the run's predicted standard errors (68% and 95% if calibrated).\n")
    proj = any(_num(get(e, "projection_floor", "albedo_mean_rel_error")) for e in latest.values())
    noise = any(_num(get(e, "noise_calibration", "median_ratio")) for e in latest.values())
    head = ["scene", "texels", "mean rel.", "rel. L1", "within 1 std. err.", "within 2"]
    if proj:
        head.append("projection floor (held-out albedo)")
    if noise:
        head.append("K_d noise measured / predicted (median, worst)")
    rows = []
    for s, e in latest.items():
        a = e.get("accuracy")
        if not isinstance(a, dict):
            continue
        texels = sum(sh.get("texels", 0) for sh in a.get("shapes", []))
        r = [label(s, e), str(texels), pct(a.get("mean_rel_error")), pct(a.get("rel_l1_error")),
             pct(get(a, "calibration", "within_one")), pct(get(a, "calibration", "within_two"))]
        if proj:
            r.append(pct(get(e, "projection_floor", "albedo_mean_rel_error")))
        if noise:
            nc = e.get("noise_calibration") or {}
            r.append(f"{fixed(nc.get('median_ratio'), 2)}, {fixed(nc.get('worst_ratio'), 2)}"
                     if _num(nc.get("median_ratio")) else "-")
        rows.append(r)
    out.append(table(head, rows) + "\n" if rows else "No run was scored against the truth.\n")

    # Per shape
    rows = []
    for s, e in latest.items():
        held = get(e, "mitsuba", "albedo", "shapes") or {}
        acc = {sh.get("shape"): sh for sh in get(e, "accuracy", "shapes") or []}
        for shape in list(held) + [k for k in acc if k not in held]:
            h, a = held.get(shape) or {}, acc.get(shape) or {}
            rows.append([label(s, e), str(shape), pct(h.get("albedo_mean_rel_error")),
                         pct(h.get("albedo_rel_l1")), fixed(h.get("masked_pixels"), 0),
                         fixed(a.get("texels"), 0), pct(a.get("mean_rel_error")),
                         pct(a.get("rel_l1_error"))])
    if rows:
        out.append("## Per shape\n")
        out.append("Held-out albedo by the shape a pixel's ray first hits (pixels seen in "
                   "training), and the texel figures against the truth.\n")
        out.append(table(["scene", "shape", "held-out mean rel.", "held-out rel. L1",
                          "held-out pixels", "texels", "texels mean rel.", "texels rel. L1"],
                         rows) + "\n")

    out += captures_section(latest)

    # The competitor anchor
    anchored = {s: e for s, e in latest.items() if isinstance(e.get("anchor"), dict)}
    scored = {s: e for s, e in anchored.items() if get(e, "anchor", "compare")}
    if anchored:
        out.append("## Mitsuba 3 inverse rendering (anchor)\n")
        out.append("`tools/mitsuba_inverse.py`: Mitsuba 3's `prb` integrator and Adam on "
                   "256x256 textures, 150 iterations, scored by the same held-out judge.\n")
        if scored:
            out.append("Held-out figures as above, kdmap / anchor (the same run).\n")
            rows = []
            for s, e in scored.items():
                c = get(e, "anchor", "compare")

                def both(k):
                    return pair(get(c, k, "kdmap"), get(c, k, "anchor"))

                rows.append([label(s, e), str(get(e, "anchor", "iterations") or "-"),
                             both("albedo.albedo_mean_rel_error"), both("albedo.albedo_rel_l1"),
                             both("relit.block8_rel_lum_error"),
                             both("original.block8_rel_lum_error"),
                             both("relit.rel_l1_error"), both("original.rel_l1_error")])
            out.append(table(["scene", "anchor iterations", "albedo mean rel.",
                              "albedo rel. L1", "relit 8x8", "original 8x8", "relit rel. L1",
                              "original rel. L1"], rows) + "\n")
        timed = [label(s, e) for s, e in anchored.items() if s not in scored]
        if timed:
            out.append("Timed only (its time extrapolated from a few iterations, nothing to "
                       "score; `--anchor-full` runs and scores the 150 iterations): "
                       + ", ".join(timed) + ". Times: [performance](performance.md).\n")
    return "\n".join(out)


def captures_section(latest):
    """Degraded captures (tools/captures.py) beside the same scene's perfect photos: held-out
    albedo of each and their ratio, the figure the capture targets are stated in."""
    rows = []
    for s, e in latest.items():
        cap = e.get("capture")
        if not isinstance(cap, dict):
            continue
        base = latest.get(cap.get("scene"))
        mine = get(e, "mitsuba", "albedo", "albedo_mean_rel_error")
        theirs = get(base, "mitsuba", "albedo", "albedo_mean_rel_error")
        ratio = f"{mine / theirs:.2f}x" if _num(mine) and _num(theirs) and theirs else "-"
        rows.append([label(s, e), str(cap.get("preset")), str(cap.get("pinned") or "-"),
                     pct(mine), pct(theirs), ratio])
    if not rows:
        return []
    return ["## Degraded captures\n",
            "The training photos changed as a real camera changes them (`tools/captures.py`, "
            "`tools/degrade_capture.py`): per-photo exposure and white balance, poses a pixel or "
            "two off, 8-bit JPEG, all of them; held-out albedo against the same scene's perfect "
            "photos. 8-bit captures have one view's gain pinned (their emitters are clipped, "
            "so nothing else fixes the absolute scale).\n",
            table(["capture", "degradation", "pinned view", "held-out albedo",
                   "perfect photos", "ratio"], rows) + "\n"]


def performance_page(entries, order=()):
    latest = latest_per_scene(entries, order)
    out = [header("Performance", "Time and memory of `kdmap reconstruct` as "
                  "`tools/nightly.py` measures them (one process per scene, all cores unless "
                  "`--threads`; the machine is the one of each run, its load included).")]
    if not latest:
        out.append("The history holds no finished run.\n")
        return "\n".join(out)
    out.append("## Runs\n")
    out.append(runs_table(latest) + "\n")

    anchored = {s: e for s, e in latest.items() if isinstance(e.get("anchor"), dict)}
    out.append("## Reconstruction\n")
    out.append("Wall time and peak RSS of the process (`wait4`), photons traced per second of "
               "photon pass (`-`: the run traced none), and the gather's rays (all iterations) "
               "with their rate.\n")
    head = ["scene", "wall s", "peak RSS MiB", "M photons/s", "M gather rays", "M rays/s"]
    if anchored:
        head.append("speed-up over the anchor")
    rows = []
    for s, e in latest.items():
        its = [i for i in e.get("iterations") or [] if isinstance(i, dict)]
        rays = sum(i.get("gather_rays") or 0 for i in its)
        rsec = sum(i.get("gather_seconds") or 0 for i in its)
        r = [label(s, e), fixed(e.get("wall_seconds")), fixed(e.get("peak_rss_mib"), 0),
             mega(e.get("photons_per_second")), mega(rays if its else None, 1),
             mega(rays / rsec if rsec > 0 else None)]
        if anchored:
            r.append(speedup(get(e, "anchor", "speedup")))
        rows.append(r)
    out.append(table(head, rows) + "\n")

    stages = []  # in report.json's order, those of 0.005 s or more in some scene
    for e in latest.values():
        stages += [k for k in e["timings"] if k != "total" and k not in stages]
    stages = [k for k in stages if any(_num(e["timings"].get(k)) and e["timings"][k] >= 0.005
                                       for e in latest.values())]
    out.append("## Time per stage\n")
    out.append("Seconds per stage (`timings` of `report.json`); stages under 0.005 s in every "
               "scene are left out.\n")
    rows = [[label(s, e)] + [fixed(e["timings"].get(k), 2) for k in stages]
            + [fixed(e["timings"].get("total"), 2)] for s, e in latest.items()]
    out.append(table(["scene"] + stages + ["total"], rows) + "\n")
    out += rays_table(latest, label)

    if anchored:
        out.append("## Mitsuba 3 inverse rendering (anchor)\n")
        out.append("`tools/mitsuba_inverse.py` on the same scene in the same run: `prb` and "
                   "Adam, 150 iterations, timed as its optimisation (Dr.Jit's kernel "
                   "compilation included) or, when timed only, as a warm-up plus a few "
                   "iterations extrapolated to 150. Speed-up = anchor seconds / kdmap wall "
                   "seconds.\n")
        rows = []
        for s, e in anchored.items():
            a = e["anchor"]
            if a.get("mode") == "full":
                mode = f"{a.get('iterations')} iterations run"
            else:
                timed = get(a, "settings", "time_only_iterations")
                if timed is None and _num(a.get("measured_iterations")):
                    timed = a["measured_iterations"] - 1  # after the warm-up
                mode = f"extrapolated from {timed if timed is not None else '-'} iterations"
            rows.append([label(s, e), mode, fixed(a.get("seconds_per_iteration"), 2),
                         fixed(a.get("compile_seconds")), fixed(a.get("anchor_seconds"), 0),
                         fixed(a.get("peak_rss_mib"), 0), fixed(a.get("kdmap_wall_seconds")),
                         speedup(a.get("speedup"))])
        out.append(table(["scene", "anchor", "s / iteration", "compile s", "anchor s",
                          "anchor peak RSS MiB", "kdmap wall s", "speed-up"], rows) + "\n")
    return "\n".join(out)


def write_pages(history, docs_dir, order=()):
    """Write `<docs_dir>/accuracy.md` and `performance.md` from the history file; returns
    their paths."""
    entries = load_history(history)
    os.makedirs(docs_dir, exist_ok=True)
    written = []
    for name, page in (("accuracy.md", accuracy_page), ("performance.md", performance_page)):
        p = os.path.join(docs_dir, name)
        text = page(entries, order)
        with open(p + ".tmp", "w") as f:
            f.write(text.rstrip("\n") + "\n")
        os.replace(p + ".tmp", p)
        written.append(p)
    return written
