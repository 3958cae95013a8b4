#!/usr/bin/env python3
"""Recompute kdmap's re-render table (report.json `table`) from the EXRs with colour-science.

    .venv/bin/python tools/validate_table.py <out dir> <scene dir>

Independently of the Rust code, per view and shape: the pixels counted are those of
`<out>/renders/<view>_mask.png` equal to 1 + the shape's index in `<out>/renders/masks.json`;
over them, for the photo (`<scene>/images/<view>.exr`, or the run's `views` mapping, divided by
its gain in report.json's `capture`, as kdmap divides it) and the
re-render (`<out>/renders/<view>.exr`): mean luminance Y = 0.2126 R + 0.7152 G + 0.0722 B, its
population standard deviation, the mean RGB, and the CIE 1931 xy of the mean RGB through
colour-science's sRGB (D65) RGB -> XYZ and XYZ_to_xy (black: the D65 white point, as kdmap).

Tolerance, relative, RTOL = 1e-5 of the value compared (plus ATOL = 1e-9 absolute for values
near 0; for the standard deviation, plus 1e-6 of the region's mean luminance). Both sides read
the same float32 pixels and sum in float64, so means and mean RGB agree to ~1e-12; kdmap
computes each pixel's Y in float32 (relative rounding <= 2^-22 ~ 2.4e-7), which moves the mean
luminance by at most ~2.4e-7 relative and the standard deviation by at most ~2.4e-7 of the
largest Y in the region; xy is a ratio of the mean RGB and inherits ~1e-12. RTOL leaves a margin
of >= 40x over all of that, while the mistakes it is there to catch are far larger: a pixel more
or less in a region of n pixels moves its mean by ~1/n (>= 1e-4 for the regions here), sample
instead of population std by ~1/(2n), another RGB -> XYZ matrix or luminance weights by >= 1e-4.
Pixel counts must match exactly. Exit code 1 with one line per disagreement.
"""

import argparse
import json
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from exrio import quiet_colour, read_exr_rgb, read_png_channel0  # noqa: E402

RTOL = 1e-5
ATOL = 1e-9
STD_ATOL_OF_MEAN = 1e-6
LUMA = np.array([0.2126, 0.7152, 0.0722])


def xy_of(rgb, colour):
    """CIE 1931 xy of a linear sRGB colour via colour-science; black -> D65 white point."""
    cs = colour.RGB_COLOURSPACES["sRGB"]
    xyz = colour.RGB_to_XYZ(np.asarray(rgb, dtype=np.float64), cs)
    if not np.isfinite(xyz).all() or abs(float(np.sum(xyz))) <= 1e-300:
        return [float(v) for v in cs.whitepoint]
    return [float(v) for v in colour.XYZ_to_xy(xyz)]


def region_stats(px, colour):
    """(mean Y, population std of Y, mean RGB, xy of mean RGB) of float32 pixels (n, 3)."""
    p = px.astype(np.float64)
    y = p @ LUMA
    rgb = p.mean(axis=0)
    return float(y.mean()), float(y.std()), [float(v) for v in rgb], xy_of(rgb, colour), float(
        np.abs(y).max()
    )


def photo_path(report, out, scene_dir, view):
    views = report.get("settings", {}).get("views") or {}
    if view in views:
        p = views[view]
        for base in ("", os.path.dirname(report["settings"].get("scene", "")), scene_dir):
            q = os.path.join(base, p)
            if os.path.exists(q):
                return q
        return p
    return os.path.join(scene_dir, "images", f"{view}.exr")


# The most shapes kdmap's 8-bit table masks name (src/output/renders.rs, MASK_MAX_SHAPES).
MASK_MAX_SHAPES = 255


def validate(out, scene_dir):
    """Compare report.json's table with the recomputation. Returns a dict with `ok`, `rows`
    checked, the largest relative difference per quantity and the list of `errors`."""
    colour = quiet_colour()
    with open(os.path.join(out, "report.json")) as f:
        report = json.load(f)
    renders = os.path.join(out, "renders")
    masks_json = os.path.join(renders, "masks.json")
    errors = []
    worst = {"mean_luminance": 0.0, "std_luminance": 0.0, "mean_rgb": 0.0, "xy": 0.0}
    shapes_in_scene = report.get("counts", {}).get("shapes", 0)
    if not os.path.exists(masks_json) and shapes_in_scene > MASK_MAX_SHAPES:
        # kdmap's masks are 8-bit (1 + shape index): it writes none for larger scenes
        return {"ok": True, "rows": 0, "worst": worst, "errors": [],
                "skipped": f"{shapes_in_scene} shapes: more than an 8-bit mask names "
                           f"({MASK_MAX_SHAPES}), kdmap writes no table masks"}
    if not os.path.exists(masks_json):
        return {"ok": False, "rows": 0, "worst": worst,
                "errors": [f"{masks_json} is missing (kdmap too old to write table masks?)"]}
    with open(masks_json) as f:
        shapes = json.load(f)["shapes"]
    table = report.get("table", [])
    views = sorted({r["view"] for r in table})
    # Views re-rendered but without any table row still have a mask; check those too.
    for name in sorted(os.listdir(renders)):
        if name.endswith("_mask.png"):
            v = name[: -len("_mask.png")]
            if v not in views:
                views.append(v)
    rows = {(r["view"], r["shape"]): r for r in table}
    gains = {c["view"]: c["gain"] for c in report.get("capture") or [] if "gain" in c}
    checked = 0

    def close(name, a, b, atol):
        d = abs(a - b)
        rel = d / max(abs(a), abs(b), 1e-300)
        worst[name] = max(worst[name], rel if max(abs(a), abs(b)) > 0 else 0.0)
        return d <= RTOL * max(abs(a), abs(b)) + atol

    for view in views:
        mask = read_png_channel0(os.path.join(renders, f"{view}_mask.png"))
        render = read_exr_rgb(os.path.join(renders, f"{view}.exr"))
        photo = read_exr_rgb(photo_path(report, out, scene_dir, view))
        # the table reads each photo divided by its estimated gain (exposure, white balance)
        photo = photo / np.asarray(gains.get(view, (1.0, 1.0, 1.0)), dtype=np.float32)
        if mask.shape != render.shape[:2] or photo.shape != render.shape:
            errors.append(f"{view}: mask {mask.shape}, render {render.shape[:2]}, "
                          f"photo {photo.shape[:2]} differ in size")
            continue
        mask = mask.reshape(-1)
        render = render.reshape(-1, 3)
        photo = photo.reshape(-1, 3)
        present = sorted(int(v) for v in np.unique(mask) if v > 0)
        seen = set()
        for v in present:
            if v - 1 >= len(shapes):
                errors.append(f"{view}: mask value {v} names no shape of masks.json")
                continue
            shape = shapes[v - 1]
            seen.add(shape)
            idx = mask == v
            row = rows.get((view, shape))
            if row is None:
                errors.append(f"{view}/{shape}: {int(idx.sum())} masked pixels but no table row")
                continue
            checked += 1
            if int(row["pixels"]) != int(idx.sum()):
                errors.append(f"{view}/{shape}: pixels {row['pixels']} in the table, "
                              f"{int(idx.sum())} in the mask")
                continue
            for k, px in enumerate((photo[idx], render[idx])):
                side = ("photo", "render")[k]
                my, sy, rgb, xy, ymax = region_stats(px, colour)
                checks = [("mean_luminance", row["mean_luminance"][k], my, ATOL),
                          ("std_luminance", row["std_luminance"][k], sy,
                           ATOL + STD_ATOL_OF_MEAN * max(abs(my), ymax))]
                checks += [("mean_rgb", row["mean_rgb"][k][c], rgb[c], ATOL) for c in range(3)]
                checks += [("xy", row["xy"][k][c], xy[c], ATOL) for c in range(2)]
                for name, a, b, atol in checks:
                    if not close(name, a, b, atol):
                        errors.append(f"{view}/{shape} {side} {name}: report.json {a!r}, "
                                      f"recomputed {b!r} (rel. diff {abs(a - b) / max(abs(b), 1e-300):.2e}"
                                      f" > {RTOL:.0e})")
        for (rv, rs) in rows:
            if rv == view and rs not in seen:
                errors.append(f"{view}/{rs}: table row but no pixel of the mask")
    return {"ok": not errors, "rows": checked, "worst": worst, "errors": errors}


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", help="kdmap output directory")
    ap.add_argument("scene_dir", help="the scene's directory (holds images/<view>.exr)")
    a = ap.parse_args()
    res = validate(a.out, a.scene_dir)
    w = ", ".join(f"{k} {v:.1e}" for k, v in res["worst"].items())
    if res["ok"]:
        print(f"table OK: {res['rows']} rows agree within {RTOL:.0e} (largest rel. diff: {w})")
        return 0
    for e in res["errors"]:
        print(f"table MISMATCH: {e}", file=sys.stderr)
    return 1


if __name__ == "__main__":
    sys.exit(main())
