"""Screenshots of ``lenssim explore``'s panels for docs/explore.md, in headless Chromium (Playwright, the system binary).

    python benchmarks/explore_screenshots.py [PHOTO] [--out docs/figures] [--sweep FILE.nc]

Starts the explorer on a free port, waits for the cost map, moves the crop to a point of the photo, runs the
restoration lab, and saves ``explore_design.png``, ``explore_photo.png`` and ``explore_lab.png``, each scaled to
:data:`SCALE` and reduced to a :data:`COLOURS`-colour palette (under 100 kB each: the repository keeps them).
"""

from __future__ import annotations

import argparse
import shutil
import socket
import subprocess
import sys
import time
import urllib.request

SCALE = 0.7
"""Screenshots are scaled by this before saving."""
COLOURS = 128
"""Palette size of the saved screenshots."""


def shrink(path: str) -> None:
    """``path`` (a PNG) scaled by :data:`SCALE` and reduced to :data:`COLOURS` colours, in place."""
    from PIL import Image

    im = Image.open(path).convert("RGB")
    im = im.resize((int(im.width * SCALE), int(im.height * SCALE)), Image.LANCZOS)
    im.quantize(colors=COLOURS, method=Image.Quantize.MEDIANCUT).save(path, optimize=True)


def idle(page) -> None:
    """Wait until the page computes nothing (its busy line gone), and a moment for the pictures to be drawn."""
    page.wait_for_selector("text=computing:", state="hidden", timeout=900_000)
    time.sleep(2)


def main() -> None:
    from playwright.sync_api import sync_playwright

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("photo", nargs="?", default="skimage:astronaut")
    ap.add_argument("--out", default="docs/figures")
    ap.add_argument("--sweep")
    a = ap.parse_args()
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    cmd = [sys.executable, "-m", "lenssim_cli.main", "explore", a.photo, "--port", str(port)]
    proc = subprocess.Popen(cmd + (["--sweep", a.sweep] if a.sweep else []), stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    url = f"http://127.0.0.1:{port}/"
    try:
        while True:
            try:
                urllib.request.urlopen(url, timeout=2).read()
                break
            except OSError:
                time.sleep(0.3)
        with sync_playwright() as p:
            b = p.chromium.launch(executable_path=shutil.which("chromium"), args=["--no-sandbox"])
            page = b.new_page(viewport={"width": 1750, "height": 1000})
            page.goto(url)
            page.wait_for_selector("text=MSE_R at 27.6 dB", timeout=300_000)
            page.wait_for_selector("text=/map: \\d+ x \\d+ designs/", timeout=900_000)  # the map computed
            idle(page)
            page.screenshot(path=f"{a.out}/explore_design.png")
            page.locator(".bk-tab", has_text="Photo").first.click()
            box = page.locator("canvas:visible").first.bounding_box()
            page.mouse.click(box["x"] + box["width"] * 0.3, box["y"] + box["height"] * 0.35)
            time.sleep(1)
            idle(page)
            page.screenshot(path=f"{a.out}/explore_photo.png")
            page.locator(".bk-tab", has_text="Restoration lab").first.click()
            page.get_by_text("run the restoration lab").click()
            page.wait_for_selector("text=its own PSFs", timeout=900_000)
            idle(page)
            page.evaluate("window.scrollTo(0, 0)")
            page.screenshot(path=f"{a.out}/explore_lab.png")
            b.close()
    finally:
        proc.terminate()
        proc.wait()
    for name in ("explore_design", "explore_photo", "explore_lab"):
        shrink(f"{a.out}/{name}.png")
    print(f"wrote {a.out}/explore_design.png, explore_photo.png, explore_lab.png")


if __name__ == "__main__":
    main()
