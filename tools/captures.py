"""The degraded captures the nightly harness scores beside the perfect photos: which variants,
where they live, and the run config each is reconstructed with.

A variant is `<scene>-<preset>` (presets of tools/degrade_capture.py: exposure, pose, jpeg, all,
control), made on demand into the ignored cache (`cache/capture/<scene>-<preset>`) and reused
while its `capture.json` is there. 8-bit variants carry no absolute scale (their emitters are
clipped), so their run config pins the first view's gain to what `capture.json` records, as a
user does with one metered photo or a grey card; the other views' gains are estimated.

    .venv/bin/python tools/captures.py cbox-tex-exposure cbox-tex-jpeg   # make, print configs
"""

import json
import os
import subprocess
import sys

TOOLS = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(TOOLS)
DEFAULT_CACHE = os.path.join(REPO, "cache", "capture")
# scored every night: the textured box under each degradation, the Cornell box's exposure
DEFAULT = ["cbox-tex-exposure", "cbox-tex-jpeg", "cbox-tex-pose", "cbox-tex-all",
           "cbox-exposure"]
PRESETS = ("exposure", "pose", "jpeg", "all", "control")


def split(variant):
    """`cbox-tex-jpeg` -> (`cbox-tex`, `jpeg`); ValueError for a name without a preset."""
    scene, _, preset = variant.rpartition("-")
    if not scene or preset not in PRESETS:
        raise ValueError(f"{variant}: not <scene>-<preset> with a preset of {', '.join(PRESETS)}")
    return scene, preset


def ensure(variant, fixtures, cache=DEFAULT_CACHE, log_path=None):
    """The variant's scene directory, made by tools/degrade_capture.py unless it is there."""
    scene, preset = split(variant)
    out = os.path.join(cache, variant)
    if os.path.exists(os.path.join(out, "capture.json")):
        return out
    cmd = [sys.executable, os.path.join(TOOLS, "degrade_capture.py"),
           os.path.join(fixtures, scene), "--preset", preset, "--out", out]
    with open(log_path or os.devnull, "w") as log:
        code = subprocess.call(cmd, stdout=log, stderr=subprocess.STDOUT, cwd=REPO)
    if code != 0:
        raise RuntimeError(f"{variant}: tools/degrade_capture.py exited {code}")
    return out


def run_config(scene_dir):
    """Write `<scene_dir>/run.toml`: the scene, its COLMAP model (with the similarity into the
    scene's frame) where the capture has one, pose refinement where its poses were moved, and
    for 8-bit photos the first view's gain pinned to the capture's recorded factor. Returns its
    path and the pinned view (or None)."""
    scene_dir = os.path.abspath(scene_dir)
    with open(os.path.join(scene_dir, "capture.json")) as f:
        cap = json.load(f)
    lines = [f"scene = {json.dumps(os.path.join(scene_dir, 'input.xml'))}"]
    views = []
    if cap.get("colmap"):
        rows = ", ".join("[" + ", ".join(f"{x:.17g}" for x in r) + "]"
                         for r in cap["colmap"]["to_world"])
        views += [f"colmap = {json.dumps(os.path.join(scene_dir, cap['colmap']['dir']))}",
                  f"to_world = [{rows}]"]
    opts = cap.get("options") or {}
    if opts.get("pose_deg") or opts.get("pose_dist"):
        views.append("refine_pose = true")
    pinned = None
    if cap.get("ldr"):
        views.append('exposure = "estimate"')
        for i, (vid, v) in enumerate(sorted(cap["views"].items(),
                                            key=lambda kv: kv[1]["index"])):
            photo = json.dumps(os.path.join(scene_dir, v["image"]))
            if i == 0:
                g = ", ".join(f"{x:.9g}" for x in v["factor"])
                views.append(f"{vid} = {{ photo = {photo}, exposure = [{g}] }}")
                pinned = vid
            else:
                views.append(f"{vid} = {photo}")
    if views:
        lines += ["[views]"] + views
    path = os.path.join(scene_dir, "run.toml")
    with open(path, "w") as f:
        f.write("\n".join(lines) + "\n")
    return path, pinned


def main(argv):
    fixtures = os.path.join(REPO, "tests", "fixtures")
    for v in argv or DEFAULT:
        d = ensure(v, fixtures)
        path, pinned = run_config(d)
        print(f"{v}: {path}" + (f" (gain of {pinned} pinned)" if pinned else ""))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
