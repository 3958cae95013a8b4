#!/usr/bin/env python3
"""The competitor anchor: Mitsuba 3's own inverse rendering of the same albedo textures.

Why it exists: a kdmap user would otherwise recover the albedo with Mitsuba 3's differentiable
renderer, so the project measures its speed-up (and accuracy) against exactly this recipe (the
project issue's definition of the anchor; change it only together with that definition):

- Mitsuba 3.9.1, variant `llvm_ad_rgb` (autodiff needs an AD variant; the LLVM backend needs
  libLLVM: `apt-get install libllvm19`; DRJIT_LIBLLVM_PATH is set here when unset);
- integrator `prb` (path replay backpropagation; max_depth / rr_depth from the input's
  integrator);
- every reconstructed shape (each `shape` of input.xml without an `emitter`; emitter shapes are
  not optimised) gets its diffuse reflectance replaced by its own 256x256 RGB `bitmap` texture
  (raw, i.e. linear) initialised to 0.5 over the mesh's own UVs (a shape without UVs is skipped
  and reported); optimised parameter `<shape>.bsdf.reflectance.data` (`<shape>.bsdf.brdf_0.
  reflectance.data` inside a twosided BSDF);
- Adam, learning rate 0.03; values clamped to [0, 1] after each step;
- 8 spp per view and iteration (seed = iteration * views + view), the training views
  (`cam_train_*`, every sensor with a photo `images/<sensor id>.exr`) against their photos;
- loss = sum over the views of the mean squared error of the render against the photo
  (backpropagated view by view, the same gradient); 150 iterations.

    .venv/bin/python tools/mitsuba_inverse.py tests/fixtures/cbox-tex --out out/anchor-cbox-tex
    .venv/bin/python tools/mitsuba_inverse.py tests/fixtures/cbox-tex --out /tmp/a --time-only 3

A full run writes a recovered scene directory like kdmap's (scoreable by tools/heldout.py):
`<out>/scene.xml` (the input's sensors, emitters and shapes; per optimised shape
`<bsdf type="diffuse"><texture type="bitmap" name="reflectance"><string name="filename"
value="textures/<id>_albedo.exr"/><boolean name="raw" value="true"/></texture></bsdf>`; meshes
copied to `<out>/meshes/`), `<out>/textures/<id>_albedo.exr` (float32) and `<out>/anchor.json`
(settings, loss per iteration, seconds).

`--time-only K` measures instead: one warm-up iteration (it includes the JIT compilation of
the kernels; timed separately), then K timed iterations; `seconds_per_iteration` = their
mean, `compile_seconds` = the warm-up's kernel compilation as Dr.Jit counts it (KernelHistory:
codegen + LLVM backend time; `jit` lists it per iteration, later iterations reuse the
kernels), `extrapolated_seconds` = seconds_per_iteration * 150 + compile_seconds (also given
for a full run, next to the measured `optimize_seconds`). Only anchor.json is written.

Dr.Jit caches compiled kernels on disk (~/.drjit); by default this script compiles cold (a
fresh temporary DRJIT_CACHE_DIR, removed at the end) so the compile time is what a first run
on a new scene pays and does not depend on earlier runs; `--warm-cache` keeps the user's
cache. `--threads N` limits Dr.Jit's worker threads (default: all cores, as kdmap).
"""

import argparse
import datetime
import json
import os
import platform
import shutil
import sys
import tempfile
import time
import xml.etree.ElementTree as ET

import numpy as np

TOOLS = os.path.dirname(os.path.abspath(__file__))
VARIANT = "llvm_ad_rgb"
DEFAULTS = {"iterations": 150, "lr": 0.03, "spp": 8, "resolution": 256, "init": 0.5}


def _scene_paths(arg):
    """(scene dir, input.xml) from a scene directory or an input.xml path."""
    if os.path.isdir(arg):
        return os.path.abspath(arg), os.path.join(os.path.abspath(arg), "input.xml")
    return os.path.dirname(os.path.abspath(arg)), os.path.abspath(arg)


def _abs(path, base):
    return path if os.path.isabs(path) else os.path.normpath(os.path.join(base, path))


def _diffuse_of(shape_el):
    """The diffuse BSDF element directly in `shape_el` (or inside a wrapper BSDF such as
    twosided), or None."""
    for b in shape_el.iter("bsdf"):
        if b.get("type") == "diffuse":
            return b
    return None


def reflectance_key(keys, sid):
    """The parameter of shape `sid`'s bitmap reflectance among `keys` (`mi.traverse` keys):
    `<sid>.bsdf.reflectance.data`, or inside a wrapper BSDF such as twosided
    (`<sid>.bsdf.brdf_0.reflectance.data`); None when there is none or more than one."""
    found = [k for k in keys
             if k.startswith(f"{sid}.bsdf.") and k.endswith(".reflectance.data")]
    return found[0] if len(found) == 1 else None


def _set_reflectance(bsdf_el, filename):
    """Replace the reflectance of a diffuse BSDF element by a raw bitmap texture."""
    for c in list(bsdf_el):
        if c.get("name") == "reflectance":
            bsdf_el.remove(c)
    tex = ET.SubElement(bsdf_el, "texture", {"type": "bitmap", "name": "reflectance"})
    ET.SubElement(tex, "string", {"name": "filename", "value": filename})
    ET.SubElement(tex, "boolean", {"name": "raw", "value": "true"})


def _inline_bsdf_refs(root):
    """Give every shape that references a top-level BSDF (`<ref id=...>`) its own copy, so each
    shape's reflectance is its own parameter (`<shape>.bsdf.reflectance.data`)."""
    import copy

    named = {b.get("id"): b for b in root.findall("bsdf") if b.get("id")}
    for sh in root.findall("shape"):
        for r in sh.findall("ref"):
            b = named.get(r.get("id"))
            if b is not None:
                c = copy.deepcopy(b)
                c.attrib.pop("id", None)
                idx = list(sh).index(r)
                sh.remove(r)
                sh.insert(idx, c)


def _integrator_settings(root):
    """max_depth and rr_depth of the input's integrator (the path tracer the photos came from)."""
    s = {"max_depth": -1, "rr_depth": 5}
    integ = root.find("integrator")
    if integ is not None:
        for el in integ.iter("integer"):
            if el.get("name") in s:
                s[el.get("name")] = int(el.get("value"))
    return s


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
    return {"cores": os.cpu_count(), "cpu": cpu, "host": platform.node(),
            "load1": os.getloadavg()[0], "nice": os.nice(0)}


def run(scene_arg, out, iterations=DEFAULTS["iterations"], time_only=None, lr=DEFAULTS["lr"],
        spp=DEFAULTS["spp"], res=DEFAULTS["resolution"], threads=None, warm_cache=False,
        log=print):
    """Run the anchor; returns the anchor.json record (also written to `<out>/anchor.json`)."""
    t_process = time.perf_counter()
    sys.path.insert(0, TOOLS)
    from heldout import ensure_libllvm

    libllvm = ensure_libllvm()
    cache_tmp = None
    if not warm_cache:
        cache_tmp = tempfile.mkdtemp(prefix="kdmap-anchor-drjit-")
        os.environ["DRJIT_CACHE_DIR"] = cache_tmp
    import drjit as dr
    import mitsuba as mi

    mi.set_variant(VARIANT)
    if threads:
        dr.set_thread_count(int(threads))
    scene_dir, input_xml = _scene_paths(scene_arg)
    os.makedirs(out, exist_ok=True)
    work = tempfile.mkdtemp(prefix="kdmap-anchor-")
    rec = {
        "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "scene": scene_dir,
        "input": input_xml,
        "mode": "time_only" if time_only else "full",
        "settings": {"mitsuba": mi.__version__, "drjit": dr.__version__, "variant": VARIANT,
                     "integrator": "prb", "optimizer": "Adam", "lr": lr, "spp": spp,
                     "texture_resolution": res, "init": DEFAULTS["init"], "clamp": [0.0, 1.0],
                     "iterations": iterations, "time_only_iterations": time_only,
                     "loss": "sum over views of mean squared error vs photo",
                     "threads": dr.thread_count(), "kernel_cache": "warm (~/.drjit or "
                     "$DRJIT_CACHE_DIR)" if warm_cache else "cold (fresh temporary dir)",
                     "libllvm": libllvm},
        "machine": machine(),
    }
    try:
        root = ET.parse(input_xml).getroot()
        _inline_bsdf_refs(root)
        integ = _integrator_settings(root)
        rec["settings"].update(integ)

        # Which shapes to optimise: non-emitters with a diffuse BSDF and UVs.
        fr = mi.file_resolver()
        fr.prepend(scene_dir)
        probe = mi.load_string(ET.tostring(root, encoding="unicode"), optimize=False)
        has_uv = {s.id(): (not s.is_mesh()) or bool(s.has_vertex_texcoords())
                  for s in probe.shapes()}
        del probe
        optimised, skipped = [], {}
        init = np.full((res, res, 3), DEFAULTS["init"], dtype=np.float32)
        for sh in root.findall("shape"):
            sid = sh.get("id")
            if sh.find("emitter") is not None:
                continue
            b = _diffuse_of(sh)
            if not sid:
                skipped[f"<unnamed {sh.get('type')}>"] = "no id"
            elif b is None:
                skipped[sid] = "no diffuse BSDF"
            elif not has_uv.get(sid, False):
                skipped[sid] = "mesh has no UVs"
            else:
                path = os.path.join(work, f"{sid}_init.exr")
                mi.Bitmap(init).write(path)  # one file per shape: never merged or shared
                _set_reflectance(b, path)
                optimised.append(sid)
        for sid, why in skipped.items():
            log(f"anchor: skipping shape {sid}: {why}")
        rec["shapes"] = optimised
        rec["skipped"] = skipped

        # Training views: sensors with a photo.
        sensors = [s.get("id") for s in root.findall("sensor")]
        photos = {sid: os.path.join(scene_dir, "images", f"{sid}.exr") for sid in sensors}
        views = [sid for sid in sensors if os.path.exists(photos[sid])]
        rec["views"] = views
        if not views:
            raise RuntimeError(f"no photos images/<sensor>.exr in {scene_dir}")

        opt_root = ET.fromstring(ET.tostring(root, encoding="unicode"))
        for el in opt_root.findall("integrator"):
            opt_root.remove(el)
        opt_root.insert(0, ET.fromstring(
            f'<integrator type="prb"><integer name="max_depth" value="{integ["max_depth"]}"/>'
            f'<integer name="rr_depth" value="{integ["rr_depth"]}"/></integrator>'))
        t0 = time.perf_counter()
        scene = mi.load_string(ET.tostring(opt_root, encoding="unicode"), optimize=False)
        index = {s.id(): i for i, s in enumerate(scene.sensors())}
        refs = []
        for sid in views:
            bmp = mi.Bitmap(photos[sid]).convert(mi.Bitmap.PixelFormat.RGB,
                                                 mi.Struct.Type.Float32, srgb_gamma=False)
            refs.append(mi.TensorXf(np.array(bmp)))
        params = mi.traverse(scene)
        keys = [reflectance_key(params.keys(), sid) for sid in optimised]
        missing = [sid for sid, k in zip(optimised, keys) if k is None]
        if missing:
            raise RuntimeError(f"reflectance parameters not found for shapes: {missing}")
        params.keep(keys)
        opt = mi.ad.Adam(lr=lr)
        for k in keys:
            opt[k] = params[k]
        params.update(opt)
        dr.eval()
        rec["load_seconds"] = time.perf_counter() - t0
        log(f"anchor: {len(optimised)} shapes x {res}x{res} texels, {len(views)} views, "
            f"prb max_depth {integ['max_depth']}, {spp} spp, Adam lr {lr}; "
            f"loaded in {rec['load_seconds']:.1f} s")

        n_iter = 1 + time_only if time_only else iterations
        losses, secs, jit = [], [], []
        dr.set_flag(dr.JitFlag.KernelHistory, True)  # per-kernel codegen + LLVM compile times
        dr.kernel_history()
        for it in range(n_iter):
            t0 = time.perf_counter()
            total = 0.0
            for v, (sid, ref) in enumerate(zip(views, refs)):
                img = mi.render(scene, params, sensor=index[sid], spp=spp,
                                seed=it * len(views) + v)
                loss = dr.mean(dr.square(img - ref), axis=None)
                dr.backward(loss)
                total += float(np.array(loss).reshape(-1)[0])
            opt.step()
            for k in keys:
                opt[k] = dr.clip(opt[k], 0.0, 1.0)
            params.update(opt)
            dr.eval()
            dr.sync_thread()
            secs.append(time.perf_counter() - t0)
            losses.append(total)
            hist = dr.kernel_history()
            jit.append({"kernels": len(hist),
                        "compiled": sum(1 for h in hist if not h.get("cache_hit")),
                        "compile_seconds": sum(h.get("codegen_time", 0.0) + h.get(
                            "backend_time", 0.0) for h in hist) / 1000.0})
            if it == 0 or (it + 1) % 10 == 0 or it + 1 == n_iter:
                log(f"anchor: iteration {it + 1}/{n_iter}: loss {total:.6g}, {secs[-1]:.2f} s")
        dr.set_flag(dr.JitFlag.KernelHistory, False)
        rec["loss"] = losses
        rec["iteration_seconds"] = secs
        rec["jit"] = jit
        rec["warmup_seconds"] = secs[0]
        timed = secs[1:] if len(secs) > 1 else secs
        spi = float(sum(timed) / len(timed))
        rec["seconds_per_iteration"] = spi
        # Compile time: Dr.Jit's own count (codegen + LLVM backend time of the warm-up's
        # kernels), not warm-up - mean iteration, which the machine's load swamps.
        rec["compile_seconds"] = jit[0]["compile_seconds"]
        rec["warmup_excess_seconds"] = secs[0] - spi
        rec["extrapolated_iterations"] = iterations
        rec["extrapolated_seconds"] = spi * iterations + rec["compile_seconds"]
        rec["optimize_seconds"] = float(sum(secs))  # measured: every iteration run here
        rec["measured_iterations"] = n_iter

        if not time_only:
            t0 = time.perf_counter()
            _write_scene(root, scene_dir, input_xml, out, optimised,
                         {sid: np.array(params[k], dtype=np.float32)
                          for sid, k in zip(optimised, keys)}, mi)
            rec["write_seconds"] = time.perf_counter() - t0
            rec["outputs"] = {"scene": os.path.join(out, "scene.xml"),
                              "textures": [os.path.join(out, "textures", f"{s}_albedo.exr")
                                           for s in optimised]}
    finally:
        shutil.rmtree(work, ignore_errors=True)
        if cache_tmp:
            shutil.rmtree(cache_tmp, ignore_errors=True)
    rec["process_seconds"] = time.perf_counter() - t_process
    with open(os.path.join(out, "anchor.json"), "w") as f:
        json.dump(rec, f, indent=1)
    return rec


def _write_scene(root, scene_dir, input_xml, out, optimised, textures, mi):
    """`<out>/scene.xml` like kdmap's: the input with each optimised shape's reflectance the
    raw bitmap `textures/<id>_albedo.exr`, meshes copied to `<out>/meshes/`, other files by
    absolute path, sensors at `$spp` samples."""
    tex_dir = os.path.join(out, "textures")
    mesh_dir = os.path.join(out, "meshes")
    os.makedirs(tex_dir, exist_ok=True)
    os.makedirs(mesh_dir, exist_ok=True)
    for sid, data in textures.items():
        mi.Bitmap(np.ascontiguousarray(data)).write(os.path.join(tex_dir, f"{sid}_albedo.exr"))
    root = ET.fromstring(ET.tostring(root, encoding="unicode"))
    used = {}
    for el in root.iter("string"):
        if el.get("name") == "filename":
            el.set("value", _abs(el.get("value"), scene_dir))
    for sh in root.findall("shape"):
        fn = next((e for e in sh.findall("string") if e.get("name") == "filename"), None)
        if fn is not None:
            src = fn.get("value")
            name = os.path.basename(src)
            if used.get(name, src) != src:
                name = f"{sh.get('id')}_{name}"
            used[name] = src
            shutil.copyfile(src, os.path.join(mesh_dir, name))
            fn.set("value", f"meshes/{name}")
        if sh.get("id") in textures:
            _set_reflectance(_diffuse_of(sh), f"textures/{sh.get('id')}_albedo.exr")
    root.insert(0, ET.Element("default", {"name": "spp", "value": "256"}))
    for s in root.findall("sensor"):
        for i in s.iter("integer"):
            if i.get("name") == "sample_count":
                i.set("value", "$spp")
    ET.indent(root)
    text = ET.tostring(root, encoding="unicode")
    header = ('<?xml version="1.0" encoding="utf-8"?>\n'
              f"<!-- Written by tools/mitsuba_inverse.py (the competitor anchor: Mitsuba 3 prb + "
              f"Adam) from {input_xml}:\n     the input's geometry, emitters and sensors with "
              "the recovered diffuse albedo (textures/*_albedo.exr,\n     linear RGB). Render "
              "with mitsuba -D spp=64 scene.xml. -->\n")
    with open(os.path.join(out, "scene.xml"), "w") as f:
        f.write(header + text + "\n")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter,
                                 epilog="\n".join(__doc__.splitlines()[1:]))
    ap.add_argument("scene", help="scene directory (input.xml, images/) or its input.xml")
    ap.add_argument("--out", required=True, help="output directory (anchor.json; full run: "
                    "scene.xml, textures/, meshes/)")
    ap.add_argument("--iterations", type=int, default=DEFAULTS["iterations"],
                    help="iterations of a full run, and the count --time-only extrapolates to")
    ap.add_argument("--time-only", type=int, metavar="K",
                    help="run a warm-up + K iterations and extrapolate to 150; writes only "
                    "anchor.json")
    ap.add_argument("--lr", type=float, default=DEFAULTS["lr"])
    ap.add_argument("--spp", type=int, default=DEFAULTS["spp"])
    ap.add_argument("--resolution", type=int, default=DEFAULTS["resolution"])
    ap.add_argument("--threads", type=int, help="Dr.Jit worker threads (default: all cores)")
    ap.add_argument("--warm-cache", action="store_true",
                    help="use Dr.Jit's on-disk kernel cache (default: compile cold)")
    a = ap.parse_args()
    if a.time_only is not None and a.time_only < 1:
        ap.error("--time-only needs K >= 1")
    rec = run(a.scene, a.out, a.iterations, a.time_only, a.lr, a.spp, a.resolution,
              a.threads, a.warm_cache, log=lambda m: print(m, file=sys.stderr, flush=True))
    summary = {k: rec.get(k) for k in ("mode", "shapes", "skipped", "views", "load_seconds",
                                       "warmup_seconds", "compile_seconds",
                                       "seconds_per_iteration", "extrapolated_seconds",
                                       "optimize_seconds", "measured_iterations",
                                       "process_seconds")}
    summary["final_loss"] = rec["loss"][-1] if rec.get("loss") else None
    print(json.dumps(summary, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
