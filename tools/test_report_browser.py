#!/usr/bin/env python3
"""The report page (<out>/report.html) in a real browser: headless Chromium (Debian's
`chromium`) driven by Playwright opens the cbox example's page from file://, and checks that
no console error is logged and nothing is fetched from the network, every image loads, the
views' pointer readout shows values, the 3D view draws non-blank pixels, and a screenshot of
each section is non-blank. Prints the page's size and its open time.

    python3 tools/test_report_browser.py [--out DIR] [--kdmap PATH] [--shots DIR]

Without --out it runs `kdmap reconstruct tests/fixtures/cbox/input.xml` into a temporary
directory first (about 40 s). Needs `apt-get install chromium` and Playwright's Python
package (`pip install playwright`; its own browsers are not used): the nightly harness
installs the package into .venv/.
"""

import argparse
import base64
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
# WebGL without a GPU: SwiftShader, which recent Chromium enables only when asked.
CHROMIUM_ARGS = ["--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--ignore-gpu-blocklist"]

# In the page: how many pixels of a PNG (a data URI) differ from its most common colour by
# more than 8 levels in some channel, and how many pixels it has.
SPREAD_JS = """async (uri) => {
  const img = new Image(); img.src = uri; await img.decode();
  const c = document.createElement('canvas'); c.width = img.width; c.height = img.height;
  const g = c.getContext('2d'); g.drawImage(img, 0, 0);
  const d = g.getImageData(0, 0, c.width, c.height).data, n = d.length / 4, count = new Map();
  for (let i = 0; i < d.length; i += 4) {
    const k = (d[i] >> 3) << 10 | (d[i + 1] >> 3) << 5 | (d[i + 2] >> 3);
    count.set(k, (count.get(k) || 0) + 1);
  }
  let top = 0, best = 0; for (const [k, v] of count) if (v > best) { best = v; top = k; }
  const bg = [(top >> 10) << 3, ((top >> 5) & 31) << 3, (top & 31) << 3];
  let off = 0;
  for (let i = 0; i < d.length; i += 4)
    if (Math.abs(d[i] - bg[0]) > 8 || Math.abs(d[i + 1] - bg[1]) > 8 || Math.abs(d[i + 2] - bg[2]) > 8) off++;
  return [off, n];
}"""


def run_cbox(kdmap, out):
    cmd = [kdmap, "reconstruct", str(REPO / "tests/fixtures/cbox/input.xml"), "--out", str(out), "--quiet"]
    subprocess.run(cmd, check=True)


def dir_bytes(path):
    return sum(f.stat().st_size for f in Path(path).rglob("*") if f.is_file())


def spread(page, png):
    """(pixels off the dominant colour, pixels) of a screenshot."""
    uri = "data:image/png;base64," + base64.b64encode(png).decode()
    return page.evaluate(SPREAD_JS, uri)


def check_page(out, shots=None):
    from playwright.sync_api import sync_playwright

    failures, errors, remote = [], [], []
    html = Path(out).resolve() / "report.html"
    with sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        page = browser.new_page(viewport={"width": 1400, "height": 900})
        page.on("console", lambda m: m.type == "error" and errors.append(m.text))
        page.on("pageerror", lambda e: errors.append(str(e)))

        def route(r):
            if r.request.url.split(":", 1)[0] in ("file", "data", "blob"):
                return r.continue_()
            remote.append(r.request.url)
            return r.abort()

        page.route("**/*", route)
        t0 = time.monotonic()
        page.goto(html.as_uri(), wait_until="load")
        opened = time.monotonic() - t0
        nav = page.evaluate("performance.getEntriesByType('navigation')[0].loadEventEnd")

        # lazy images load once near the viewport: bring each there, then wait for all
        for img in page.query_selector_all("img"):
            img.scroll_into_view_if_needed()
        page.wait_for_function("[...document.images].every(i => i.complete)", timeout=30000)
        broken = page.evaluate("[...document.images].filter(i => !i.naturalWidth).map(i => i.src)")
        n_img = page.evaluate("document.images.length")
        if broken or n_img == 0:
            failures.append(f"images that did not load ({len(broken)} of {n_img}): {broken[:5]}")

        # a view: the pointer readout gives values once the view's data has loaded
        fig = page.query_selector("figure.view")
        if fig is None:
            failures.append("no view figure")
        else:
            img = fig.query_selector("img.error")
            img.scroll_into_view_if_needed()
            img.hover(position={"x": 60, "y": 80})
            page.wait_for_timeout(500)
            img.hover(position={"x": 80, "y": 100})
            text = fig.query_selector(".readout").inner_text()
            if "photo RGB" not in text or "relative error" not in text:
                failures.append(f"no values under the pointer: {text!r}")
            fig.query_selector(".wipe").fill("20")
            wipe = fig.evaluate("f => f.style.getPropertyValue('--wipe')")
            if wipe != "20%":
                failures.append(f"the wipe slider does not move the wipe: {wipe!r}")

        # the 3D view: the model loads and its pixels are not one colour
        mv = page.query_selector("model-viewer")
        if mv is None:
            failures.append("no 3D view")
        else:
            mv.scroll_into_view_if_needed()
            try:
                page.wait_for_function("document.querySelector('model-viewer').loaded === true", timeout=60000)
                page.wait_for_timeout(1500)
            except Exception as e:  # noqa: BLE001 - reported as a failure below
                failures.append(f"the 3D model did not load: {e}")
            off, n = spread(page, mv.screenshot())
            if off < 0.05 * n:
                failures.append(f"the 3D view is blank ({off} of {n} pixels off its background)")
            if shots:
                Path(shots, "scene3d.png").write_bytes(mv.screenshot())

        # every section's screenshot is non-blank
        for sec in page.query_selector_all("main > section"):
            sid = sec.get_attribute("id")
            sec.scroll_into_view_if_needed()
            png = sec.screenshot()
            off, n = spread(page, png)
            if off < 0.01 * n:
                failures.append(f"section '{sid}' looks blank ({off} of {n} pixels)")
            if shots:
                Path(shots, f"{sid}.png").write_bytes(png)
        sections = len(page.query_selector_all("main > section"))
        browser.close()
    if errors:
        failures.append(f"console errors: {errors[:5]}")
    if remote:
        failures.append(f"requests off the machine: {remote[:5]}")
    return failures, {"open_s": opened, "load_event_ms": nav, "images": n_img, "sections": sections}


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", help="a finished run's output directory (default: run cbox)")
    ap.add_argument("--kdmap", default=str(REPO / "target/release/kdmap"))
    ap.add_argument("--shots", help="write each section's screenshot here")
    args = ap.parse_args()
    if args.shots:
        os.makedirs(args.shots, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        out = args.out
        if out is None:
            out = Path(tmp) / "cbox"
            run_cbox(args.kdmap, out)
        page_mb = (Path(out, "report.html").stat().st_size + dir_bytes(Path(out, "report"))) / 1e6
        t0 = time.monotonic()
        failures, m = check_page(out, args.shots)
        print(f"report page: {page_mb:.1f} MB (report.html + report/), {m['images']} images, "
              f"{m['sections']} sections; opened in {m['open_s']:.2f} s (load event at "
              f"{m['load_event_ms']:.0f} ms); whole check {time.monotonic() - t0:.1f} s")
    for f in failures:
        print("FAIL:", f)
    if failures:
        sys.exit(1)
    print("ok")


if __name__ == "__main__":
    main()
