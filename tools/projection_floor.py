#!/usr/bin/env python3
"""The projection floor of a kdmap run on the held-out albedo judge.

    .venv/bin/python tools/projection_floor.py <out dir> <scene dir> [--config run.toml]
        [--spp 64] [--kdmap target/release/kdmap]

Splits a run's held-out albedo error into what the lighting (E_i) costs and what the photos'
resolution and the projection cost. The training photos are replaced by noise-free images of
the true albedo alone, as the same cameras see it (Mitsuba's `albedo` AOV,
`<scene>/albedo/<sensor>.exr`, rendered by `render_albedo_aov.py` when missing), and projected
by `kdmap project` with the run's own settings (`--config`, the run config; without it the
defaults). Where the light is known exactly (here: the albedo *is* the radiance) the projected
luminance is the recovered albedo, so those maps, put in place of the run's
`textures/<shape>_albedo.exr` in a copy `<out>-projfloor`, are scored by the held-out albedo
judge (`heldout.albedo_score`, as `heldout.py --albedo-only`): the error left by the photos'
resolution and the projection's deconvolution alone. Beside `repr_floor.py` (the atlas
holding the true texels: what the texel density costs), a run's figure splits three ways:
representational floor <= projection floor <= run.

The atlas must be the run's: the same scene and atlas settings (the tool checks that every
projected map has the size of the texture it replaces).
"""

import argparse
import glob
import json
import os
import shutil
import subprocess
import sys
import tomllib

TOOLS = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(TOOLS)


def toml_value(v):
    """A TOML literal for a string, bool, int or float (the values a run config holds)."""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float)):
        return repr(v)
    if isinstance(v, str):
        return json.dumps(v)  # a JSON string is a valid TOML basic string
    raise ValueError(f"unsupported config value {v!r}")


def floor_config(cfg, scene_xml, albedo):
    """The text of the run config `cfg` (parsed TOML, may be empty) with its scene set to
    `scene_xml` and its views to `albedo` ({sensor id: EXR path}): [`run_settings`], then
    [`views_table`]."""
    return run_settings(cfg, scene_xml) + views_table(albedo)


def run_settings(cfg, scene_xml):
    """The run config `cfg` as TOML text with its scene set to `scene_xml`. Only the flat
    tables of a kdmap run config are written; a config with its own `[views]` is refused (its
    photos are what the floor replaces), as are nested tables and values of other types
    (ValueError)."""
    if "views" in cfg:
        raise ValueError("the run config has its own [views]; give one without them")
    lines = [f"scene = {toml_value(scene_xml)}"]
    for k, v in cfg.items():
        if k != "scene" and not isinstance(v, dict):
            lines.append(f"{k} = {toml_value(v)}")
    for table, kv in cfg.items():
        if isinstance(kv, dict):
            lines.append(f"[{table}]")
            for k, v in kv.items():
                if isinstance(v, dict):
                    raise ValueError(f"[{table}.{k}]: nested tables are not supported")
                lines.append(f"{k} = {toml_value(v)}")
    return "\n".join(lines) + "\n"


def views_table(albedo):
    """A `[views]` table of {sensor id: EXR path}, as TOML text."""
    lines = ["[views]", 'exposure = "known"  # albedo images: nothing to calibrate']
    for sensor, path in sorted(albedo.items()):
        lines.append(f"{sensor} = {toml_value(path)}")
    return "\n".join(lines) + "\n"


def read_config(path):
    """The run config at `path` parsed ({} for None); a file that cannot be read or parsed ends
    the program with one line naming it."""
    if not path:
        return {}
    try:
        with open(path, "rb") as f:
            return tomllib.load(f)
    except (OSError, tomllib.TOMLDecodeError) as e:
        sys.exit(f"{path}: {e}")


class FloorError(Exception):
    """What stopped the measurement, one line naming the file or step."""


def last_line(text):
    lines = text.strip().splitlines()
    return lines[-1] if lines else "(no output)"


def albedo_images(scene_dir, spp):
    """{sensor id: path} of the noise-free training albedo images, rendered when missing."""
    found = sorted(glob.glob(os.path.join(scene_dir, "albedo", "cam_train_*.exr")))
    if not found:
        r = subprocess.run([sys.executable, os.path.join(TOOLS, "render_albedo_aov.py"),
                            scene_dir, "--spp", str(spp)], capture_output=True, text=True)
        if r.returncode != 0:
            raise FloorError(f"render_albedo_aov.py failed: {last_line(r.stderr)}")
        found = sorted(glob.glob(os.path.join(scene_dir, "albedo", "cam_train_*.exr")))
    if not found:
        raise FloorError(f"{scene_dir}/albedo: no cam_train_*.exr after rendering")
    return {os.path.basename(p)[: -len(".exr")]: os.path.abspath(p) for p in found}


def exr_size(path):
    """(height, width) of an EXR."""
    from exrio import read_exr_rgb

    return read_exr_rgb(path).shape[:2]


def swap_textures(out, proj, dst):
    """Copy run `out` to `dst` with each `textures/<shape>_albedo.exr` replaced by the
    projection's `maps/<shape>_luminance.exr`; fails when a map is missing or of another size."""
    shutil.rmtree(dst, ignore_errors=True)
    shutil.copytree(out, dst, ignore=shutil.ignore_patterns("heldout", "checkpoint"))
    for t in sorted(glob.glob(os.path.join(dst, "textures", "*_albedo.exr"))):
        shape = os.path.basename(t)[: -len("_albedo.exr")]
        m = os.path.join(proj, "maps", f"{shape}_luminance.exr")
        if not os.path.exists(m):
            raise FloorError(f"{m}: missing (the projection's scene differs from the run's)")
        got, want = exr_size(m), exr_size(t)
        if got != want:
            raise FloorError(f"{m}: {got} texels, the run's {shape} texture {want}: give the "
                             f"run's config (--config)")
        shutil.copyfile(m, t)


def measure(out, scene_dir, cfg=None, spp=64, kdmap=None, cfg_name="the run config"):
    """The projection floor of run `out` of the scene in `scene_dir` made with run config `cfg`
    (parsed TOML, None for the defaults): `heldout.py`'s albedo figures for `<out>-projfloor`
    (`albedo_mean_rel_error`, `albedo_rel_l1`, per shape under `shapes`). Raises FloorError."""
    scene_dir = os.path.abspath(scene_dir)
    kdmap = kdmap or os.path.join(ROOT, "target", "release", "kdmap")
    dst = out.rstrip("/") + "-projfloor"
    if not glob.glob(os.path.join(out, "textures", "*_albedo.exr")):
        raise FloorError(f"{out}/textures: no *_albedo.exr (not a finished kdmap run?)")
    try:
        text = run_settings(cfg or {}, os.path.join(scene_dir, "input.xml"))
    except ValueError as e:
        raise FloorError(f"{cfg_name}: {e}") from e
    text += views_table(albedo_images(scene_dir, 256))
    toml_path = dst + ".toml"
    with open(toml_path, "w") as f:
        f.write(text)
    proj = dst + "-proj"
    shutil.rmtree(proj, ignore_errors=True)
    r = subprocess.run([kdmap, "project", toml_path, "--out", proj, "--progress", "never"],
                       capture_output=True, text=True)
    if r.returncode != 0:
        raise FloorError(f"kdmap project failed: {last_line(r.stderr)}")
    swap_textures(out, proj, dst)
    import heldout  # numpy and Mitsuba, only once there is something to judge

    try:
        j = heldout.albedo_score(dst, scene_dir, spp, os.path.join(dst, "heldout"))
    except Exception as e:  # a Mitsuba failure: one line, as the other steps'
        raise FloorError(f"held-out albedo judge failed: {type(e).__name__}: {e}") from e
    j["dir"] = dst
    return j


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("out")
    ap.add_argument("scene_dir")
    ap.add_argument("--config", help="the run config (TOML) the run was made with")
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--kdmap", default=os.path.join(ROOT, "target", "release", "kdmap"))
    a = ap.parse_args()
    cfg = read_config(a.config)
    try:
        j = measure(a.out, a.scene_dir, cfg, a.spp, a.kdmap, a.config)
    except FloorError as e:
        sys.exit(str(e))
    shapes = ", ".join(f"{k} {100 * v['albedo_mean_rel_error']:.2f}%"
                       for k, v in sorted(j["shapes"].items()))
    print(f"projection floor (held-out albedo, noise-free albedo photos projected with the "
          f"run's settings): {100 * j['albedo_mean_rel_error']:.2f}% ({j['dir']}; {shapes})")


if __name__ == "__main__":
    main()
