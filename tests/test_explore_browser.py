"""``lenssim explore`` in a real headless browser (Debian's Chromium driven by Playwright with the system binary;
skipped, saying why, where either is missing): the page loads with no console error and no request off this
machine, moving the Q_back slider changes the criteria and the PSF figure, a click on the cost map selects a design,
a click on the photo moves the crop, a bad upload shows its one-line error and the app keeps serving."""

from __future__ import annotations

import shutil
import socket
import subprocess
import sys
import time
import urllib.request
from contextlib import contextmanager
from urllib.parse import urlparse

import pytest

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser") or shutil.which("google-chrome")
pytestmark = [pytest.mark.skipif(CHROMIUM is None, reason="Chromium is not installed (apt-get install chromium)")]
playwright = pytest.importorskip("playwright.sync_api", reason="Playwright is not installed (pip install playwright)")
pytest.importorskip("panel", reason="Panel is not installed (pip install 'lenssim[explore]')")

TINY_SWEEP = """
[lens]
field_angles_deg = [0, 7, 14]

[grid]
s = [-1.0, 0.0, 0.5]
Q = [-4.0, 0.0, 2.0]
snr_db = [21.6, 27.6, 33.6]
"""


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    from lenssim_studies.config import load_config
    from lenssim_studies.sweep import run_sweep

    d = tmp_path_factory.mktemp("explore")
    (d / "tiny.toml").write_text(TINY_SWEEP)
    run_sweep(load_config(d / "tiny.toml"), d / "tiny.nc", show_progress=False)
    yield from _serve(["skimage:astronaut", "--sweep", str(d / "tiny.nc")], d)


def _serve(args, d):
    """``lenssim explore ARGS`` on a free port until the test is done: ``(url, d)``."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    proc = subprocess.Popen([sys.executable, "-m", "lenssim_cli.main", "explore", *args, "--port", str(port)],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    url = f"http://127.0.0.1:{port}/"
    t0 = time.time()
    while True:
        try:
            urllib.request.urlopen(url, timeout=2).read()
            break
        except OSError:
            if proc.poll() is not None or time.time() - t0 > 120:
                proc.kill()
                proc.wait()
                pytest.fail("lenssim explore did not start: " + (proc.stdout.read() if proc.stdout else ""))
            time.sleep(0.3)
    yield url, d
    proc.terminate()
    proc.wait(timeout=20)
    proc.stdout.close()


@pytest.fixture(scope="module")
def lens_server(tmp_path_factory):
    yield from _serve(["skimage:astronaut", "--lens", "paper_singlet", "--vary", "E1.bending=-1:0:0.025",
                       "--vary", "S2.conic=-10:0:0.1"], tmp_path_factory.mktemp("explore_lens"))


def _text(page, selector: str) -> str:
    return " ".join(page.locator(selector).all_inner_texts())


def _wait_change(fn, before, timeout=60.0):
    t0 = time.time()
    while time.time() - t0 < timeout:
        now = fn()
        if now != before:
            return now
        time.sleep(0.1)
    raise AssertionError(f"no change from {before!r} within {timeout} s")


@contextmanager
def _browser_page(url):
    """Headless Chromium (the system binary) at ``url``: ``(page, outside, errors)``, the requests that leave this
    machine and the console's errors recorded as the page runs."""
    outside, errors = [], []
    with playwright.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=["--no-sandbox"])
        page = browser.new_page(viewport={"width": 1500, "height": 1100})
        page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
        page.on("request", lambda r: outside.append(r.url) if urlparse(r.url).hostname not in (
            "127.0.0.1", "localhost") and not r.url.startswith(("data:", "blob:")) else None)
        page.goto(url)
        yield page, outside, errors
        browser.close()


def test_the_explorer_page_in_a_real_browser(server):
    url, d = server
    with _browser_page(url) as (page, outside, errors):
        page.wait_for_selector("text=MSE_R at 27.6 dB", timeout=120_000)
        criteria = lambda: _text(page, "table")  # noqa: E731
        optics = lambda: page.locator("img").first.get_attribute("src")  # noqa: E731  (the PSF/MTF figure)
        before_c, before_o = criteria(), optics()
        # move the Q_back slider (the second) by keyboard: four steps of 0.1
        page.locator(".noUi-handle").nth(1).focus()
        for _ in range(4):
            page.keyboard.press("ArrowLeft")
        after_c = _wait_change(criteria, before_c)
        assert "MSE_R at 27.6 dB" in after_c
        _wait_change(optics, before_o)
        assert "-2.80" in _text(page, "text=Q_back (back conic)")
        # a click on the cost map selects a design: the sliders move, the criteria change
        before_c = criteria()
        box = page.locator("canvas:visible").first.bounding_box()
        page.mouse.click(box["x"] + box["width"] * 0.3, box["y"] + box["height"] * 0.3)
        _wait_change(criteria, before_c)
        # the photo: a click on the overview moves the crop
        page.locator(".bk-tab", has_text="Photo").first.click()
        field = lambda: _text(page, "p:has-text('of field')")  # noqa: E731
        page.wait_for_selector("text=of field", timeout=60_000)
        before_f = field()
        box = page.locator("canvas:visible").first.bounding_box()
        page.mouse.click(box["x"] + box["width"] * 0.15, box["y"] + box["height"] * 0.2)
        after_f = _wait_change(field, before_f)
        assert "(0, 256, 0, 256)" in after_f or after_f != before_f
        # a bad upload: its one-line error on the page, and the app keeps serving
        bad = d / "broken.png"
        bad.write_bytes(b"this is not an image")
        page.locator("input[type=file]").set_input_files(str(bad))
        page.wait_for_selector("text=error:", timeout=60_000)
        page.wait_for_selector("text=cannot read photo", timeout=10_000)
        page.locator(".bk-tab", has_text="Design").first.click()
        page.locator(".noUi-handle").nth(1).focus()
        before_c = criteria()
        page.keyboard.press("ArrowRight")
        _wait_change(criteria, before_c)
        page.screenshot(path=str(d / "page.png"), full_page=True)
    assert not outside, f"requests off this machine: {outside[:5]}"
    assert not errors, f"console errors: {errors[:5]}"


def test_any_lens_in_a_real_browser(lens_server):
    """``--lens`` with two free parameters: their sliders on the page; moving one changes the criteria (real rays)
    and the PSF figure; the lens file and the command line are offered on the photo tab."""
    url, _ = lens_server
    with _browser_page(url) as (page, outside, errors):
        page.wait_for_selector("text=EFL [mm]", timeout=120_000)
        page.wait_for_selector("text=S2.conic", timeout=10_000)
        page.wait_for_selector("text=E1.bending", timeout=10_000)
        criteria = lambda: _text(page, "table")  # noqa: E731
        optics = lambda: page.locator("img").first.get_attribute("src")  # noqa: E731
        before_c, before_o = criteria(), optics()
        page.locator(".noUi-handle").nth(1).focus()  # S2.conic: three steps of 0.1
        for _ in range(3):
            page.keyboard.press("ArrowLeft")
        _wait_change(criteria, before_c)
        _wait_change(optics, before_o)
        page.locator(".bk-tab", has_text="Photo").first.click()
        page.wait_for_selector("text=download the lens (explored_lens.toml)", timeout=60_000)
        page.wait_for_selector("text=--lens explored_lens.toml", timeout=60_000)
    assert not outside, f"requests off this machine: {outside[:5]}"
    assert not errors, f"console errors: {errors[:5]}"
