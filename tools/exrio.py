"""Small I/O helpers shared by the nightly harness scripts: EXR and PNG reading, Mitsuba setup."""

import os
import warnings

import numpy as np

_MI = None


def mitsuba(variant="scalar_rgb"):
    """Import Mitsuba 3 once and set `variant` (scalar_rgb needs no system libraries)."""
    global _MI
    if _MI is None:
        import mitsuba as mi

        mi.set_variant(variant)
        _MI = mi
    return _MI


def render_sensors(mi, xml, out_dir, prefix, spp, force, suffix=""):
    """Render every sensor of the scene `xml` whose id starts with `prefix` to
    `<out_dir>/<id><suffix>.exr` (seed: the sensor's index), skipping files already there
    unless `force`."""
    scene = mi.load_file(xml)
    os.makedirs(out_dir, exist_ok=True)
    for i, sensor in enumerate(scene.sensors()):
        sid = sensor.id()
        path = os.path.join(out_dir, f"{sid}{suffix}.exr")
        if not sid.startswith(prefix) or (os.path.exists(path) and not force):
            continue
        img = mi.render(scene, sensor=i, spp=spp, seed=i)
        mi.Bitmap(img).write(path)
        print(f"rendered {os.path.relpath(path)}", flush=True)


def read_exr_rgb(path):
    """Linear RGB of an OpenEXR file as a float32 array (h, w, 3); half-float files are widened
    exactly. Reads with Mitsuba's Bitmap, which takes the R, G, B channels as kdmap does."""
    mi = mitsuba()
    bmp = mi.Bitmap(str(path))
    if bmp.pixel_format() not in (mi.Bitmap.PixelFormat.RGB, mi.Bitmap.PixelFormat.RGBA):
        bmp = bmp.convert(mi.Bitmap.PixelFormat.RGB, mi.Struct.Type.Float32, srgb_gamma=False)
    a = np.array(bmp)
    if a.ndim == 2:
        a = a[..., None]
    return a[..., :3].astype(np.float32)


def read_png_channel0(path):
    """First channel of an 8-bit PNG as uint8 (h, w) (kdmap's masks have R = G = B)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        from PIL import Image

    with Image.open(path) as im:
        a = np.array(im)
    if a.ndim == 3:
        a = a[..., 0]
    return a.astype(np.uint8)


def quiet_colour():
    """Import colour-science without its warning about optional SciPy features."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        import colour
    colour.utilities.filter_warnings(colour_usage_warnings=True)
    return colour
