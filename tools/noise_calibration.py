#!/usr/bin/env python3
"""Is the per-texel standard error of K_d right about the noise? Measured with a second set of
photos and a second kdmap seed.

    .venv/bin/python tools/noise_calibration.py <scene dir> [--work DIR] [--config run.toml]
        [--seed 7] [--kdmap target/release/kdmap]

The scene's training photos (`images/`) and a second render of them (`truth.xml`'s training
cameras at their own sample count, Mitsuba seed `--seed`, cached in `<work>/photos-seed<k>/`)
are reconstructed alike (the run config, default settings without one, and the sigma filter
off: it is judged by its own noise estimate, and what is checked here is that estimate): run
a on the photos, run b on the second set (the two differ by the photos' noise alone), run c on
the photos with the next kdmap seed (a and c differ by kdmap's own Monte Carlo noise: the
gather's rays). Per shape, over texels the runs observe:

- measured: the robust spread (1.4826 x MAD) of `(K_a - K_b) / mean` over sqrt 2 (photos),
  of `(K_a - K_c) / mean` over sqrt 2 (gather), and their quadrature sum (total);
- predicted: the median of `kd_stderr / K_d` of run a (`maps/<shape>_kd_stderr.exr` over
  `textures/<shape>_albedo.exr`), which states both.

Prints total measured / predicted per shape (1 if calibrated) and writes
`<work>/noise_calibration.json`. Rendering a second set takes minutes (cbox-tex: about 4 min
on 2 cores with `scalar_rgb`).
"""

import argparse
import glob
import json
import os
import re
import subprocess
import sys

import numpy as np

TOOLS = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(TOOLS)
sys.path.insert(0, TOOLS)
from projection_floor import last_line, read_config, run_settings, views_table  # noqa: E402


class CalibrationError(Exception):
    """What stopped the measurement, one line naming the file or step."""


def luminance(rgb):
    return rgb @ np.array([0.2126, 0.7152, 0.0722], dtype=np.float64)


def noise_ratio(kd_a, kd_b, se_a):
    """(texels, measured, predicted) relative noise of K_d over the texels where both runs have
    a positive K_d and the first a positive standard error; arrays of luminances."""
    kd_a, kd_b, se_a = (np.asarray(x, dtype=np.float64) for x in (kd_a, kd_b, se_a))
    m = (kd_a > 0) & (kd_b > 0) & (se_a > 0)
    n = int(m.sum())
    if n < 2:
        return n, float("nan"), float("nan")
    d = (kd_a[m] - kd_b[m]) / (0.5 * (kd_a[m] + kd_b[m])) / np.sqrt(2.0)
    measured = 1.4826 * float(np.median(np.abs(d - np.median(d))))
    predicted = float(np.median(se_a[m] / kd_a[m]))
    return n, measured, predicted


def second_photos(scene_dir, dst, seed):
    """{sensor id: path} of the training photos rendered again with Mitsuba seed `seed` into
    `dst` (kept: rendered only when missing)."""
    truth = os.path.join(scene_dir, "truth.xml")
    ids = re.findall(r'<sensor[^>]*id="(cam_train_[^"]*)"', open(truth).read())
    if not ids:
        raise CalibrationError(f"{truth}: no cam_train_* sensors")
    want = {i: os.path.join(dst, f"{i}.exr") for i in ids}
    if not all(os.path.exists(p) for p in want.values()):
        from exrio import mitsuba

        mi = mitsuba()
        cwd = os.getcwd()
        os.chdir(scene_dir)  # relative mesh and texture paths
        try:
            scene = mi.load_file(truth)
        finally:
            os.chdir(cwd)
        os.makedirs(dst, exist_ok=True)
        for k, s in enumerate(scene.sensors()):
            if s.id() in want:
                img = np.array(mi.render(scene, sensor=k, seed=seed))[:, :, :3]
                bmp = mi.Bitmap(np.ascontiguousarray(img.astype(np.float32)),
                                mi.Bitmap.PixelFormat.RGB)
                bmp.convert(component_format=mi.Struct.Type.Float16).write(want[s.id()])
                print(f"{want[s.id()]}: rendered", flush=True)
    return want


def reconstruct(kdmap, cfg, scene_dir, views, out, seed_step=0):
    """A kdmap run of the scene with `views` ({id: path}, None: the scene's photos), the sigma
    filter off and the run's seed (default 1) plus `seed_step`, into `out`."""
    cfg = {k: (dict(v) if isinstance(v, dict) else v) for k, v in cfg.items()}
    cfg.setdefault("projection", {})["denoise_radius"] = 0
    run = cfg.setdefault("run", {})
    run["seed"] = run.get("seed", 1) + seed_step
    text = run_settings(cfg, os.path.join(scene_dir, "input.xml"))
    if views:
        text += views_table(views)
    toml_path = out + ".toml"
    with open(toml_path, "w") as f:
        f.write(text)
    r = subprocess.run([kdmap, "reconstruct", toml_path, "--out", out, "--progress", "never"],
                       capture_output=True, text=True)
    if r.returncode != 0:
        raise CalibrationError(f"kdmap reconstruct ({out}) failed: {last_line(r.stderr)}")


def per_shape(a, b, c):
    """{shape: {texels, photos, gather, measured, predicted, ratio}} of runs `a`, `b` (other
    photos) and `c` (other seed)."""
    from exrio import read_exr_rgb

    res = {}
    for t in sorted(glob.glob(os.path.join(a, "textures", "*_albedo.exr"))):
        shape = os.path.basename(t)[: -len("_albedo.exr")]
        se = os.path.join(a, "maps", f"{shape}_kd_stderr.exr")
        kb, kc = (os.path.join(r, "textures", f"{shape}_albedo.exr") for r in (b, c))
        if not all(os.path.exists(f) for f in (se, kb, kc)):
            continue
        ka, se = luminance(read_exr_rgb(t)), luminance(read_exr_rgb(se))
        n, photos, pred = noise_ratio(ka, luminance(read_exr_rgb(kb)), se)
        _, gather, _ = noise_ratio(ka, luminance(read_exr_rgb(kc)), se)
        meas = float(np.hypot(photos, gather))
        res[shape] = {"texels": n, "photos": photos, "gather": gather, "measured": meas,
                      "predicted": pred, "ratio": meas / pred if pred > 0 else float("nan")}
    return res


def measure(scene_dir, work, cfg, seed, kdmap):
    scene_dir = os.path.abspath(scene_dir)
    for f in ("truth.xml", "input.xml"):
        if not os.path.exists(os.path.join(scene_dir, f)):
            raise CalibrationError(f"{os.path.join(scene_dir, f)}: missing")
    if not glob.glob(os.path.join(scene_dir, "images", "cam_train_*.exr")):
        raise CalibrationError(f"{scene_dir}/images: no cam_train_*.exr photos")
    try:
        run_settings(cfg, "check.xml")  # refuses [views] (the tool sets them) and nested tables
    except ValueError as e:
        raise CalibrationError(str(e)) from e
    if not os.access(kdmap, os.X_OK):
        raise CalibrationError(f"{kdmap}: not an executable (cargo build --release)")
    work = os.path.abspath(work)  # the run configs name files by absolute path
    os.makedirs(work, exist_ok=True)
    photos = second_photos(scene_dir, os.path.join(work, f"photos-seed{seed}"), seed)
    a, b, c = (os.path.join(work, f"run-{k}") for k in "abc")
    reconstruct(kdmap, cfg, scene_dir, None, a)
    reconstruct(kdmap, cfg, scene_dir, photos, b)
    reconstruct(kdmap, cfg, scene_dir, None, c, seed_step=1)
    return per_shape(a, b, c)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("scene_dir")
    ap.add_argument("--work", help="working directory (default cache/noise-calibration/<scene>)")
    ap.add_argument("--config", help="the run config (TOML); its [views] are not allowed")
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--kdmap", default=os.path.join(ROOT, "target", "release", "kdmap"))
    a = ap.parse_args()
    name = os.path.basename(os.path.abspath(a.scene_dir))
    work = a.work or os.path.join(ROOT, "cache", "noise-calibration", name)
    cfg = read_config(a.config)
    try:
        res = measure(a.scene_dir, work, cfg, a.seed, a.kdmap)
    except CalibrationError as e:
        sys.exit(str(e))
    with open(os.path.join(work, "noise_calibration.json"), "w") as f:
        json.dump(res, f, indent=1)
    print(f"{name}: relative K_d noise (sigma filter off), measured (photos: two photo sets; "
          f"gather: two seeds) against predicted (kd_stderr)")
    for shape, r in res.items():
        print(f"  {shape:16s} {r['texels']:8d} texels  photos {100 * r['photos']:6.2f}%  "
              f"gather {100 * r['gather']:6.2f}%  total {100 * r['measured']:6.2f}%  "
              f"predicted {100 * r['predicted']:6.2f}%  ratio {r['ratio']:.2f}")


if __name__ == "__main__":
    main()
