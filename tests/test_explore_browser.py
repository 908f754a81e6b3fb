"""``lenssim explore`` served for real. Who may connect, over HTTP: on every port and host setting (a fixed port,
``--port 0``, ``--host`` with ``--allow-origin``) a WebSocket handshake from a foreign page (its Origin) and a request
for a foreign host name (DNS rebinding) are refused with 403, the allowed ones accepted. The page in a real headless
browser (Debian's Chromium driven by Playwright with the system binary; skipped, saying why, where either is missing):
it loads with no console error and no request off this machine, moving the Q_back slider changes the criteria and the
PSF figure, a click on the cost map selects a design and moves its marker, a click on the photo moves the crop, a bad
upload shows its one-line error and the app keeps serving, a second page loads while the first runs a long
computation, which shows that it is busy and is cancelled."""

from __future__ import annotations

import http.client
import queue
import re
import shutil
import socket
import subprocess
import sys
import threading
import time
from contextlib import ExitStack, contextmanager
from urllib.parse import urlparse

import pytest

pytest.importorskip("panel", reason="Panel is not installed (pip install 'lenssim[explore]')")
CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser") or shutil.which("google-chrome")
try:
    import playwright.sync_api as playwright
except ImportError:
    playwright = None
needs_browser = pytest.mark.skipif(CHROMIUM is None or playwright is None, reason=(
    "Chromium is not installed (apt-get install chromium)" if CHROMIUM is None else
    "Playwright is not installed (pip install playwright)"))

SMALL_SWEEP = """
[lens]
field_angles_deg = [0, 10]

[grid]
s = [-1.0, 0.0, 1.0]
Q = [-4.0, 0.0, 4.0]
snr_db = [21.6, 27.6, 33.6]
"""
"""A 2 x 2 sweep for the cost map (so that no server computes the default map in the background)."""
SLOW_LAB_S = 300
"""Longest the test's slow restoration lab waits to be cancelled (s): the bound of the long computation."""
SLOW_LAB = f"""
import sys
import lenssim_studies.explore as explore

def slow_lab(self, *args, cancel=None, **kwargs):  # a long computation: it ends when the page cancels it
    if cancel is None or not cancel.wait({SLOW_LAB_S}):
        raise ValueError("the test's slow restoration lab was not cancelled")
    raise explore.Cancelled()

explore.Explorer.restoration_lab = slow_lab
from lenssim_cli.main import main
sys.exit(main(sys.argv[1:]))
"""
"""``lenssim explore`` with the restoration lab replaced by one that runs until cancelled (at most
:data:`SLOW_LAB_S`)."""
START_S = 300
"""Longest a server may take to print its address (s; a busy 2-core machine imports torch and Panel slowly)."""


@pytest.fixture(scope="module")
def sweep(tmp_path_factory):
    from lenssim_studies.config import load_config
    from lenssim_studies.sweep import run_sweep

    d = tmp_path_factory.mktemp("explore")
    (d / "small.toml").write_text(SMALL_SWEEP)
    run_sweep(load_config(d / "small.toml"), d / "small.nc", show_progress=False)
    return d / "small.nc"


@contextmanager
def _explore_many(*arg_lists, slow_lab=False):
    """``lenssim explore`` once per argument list (all started at once), until the block ends: each one's
    ``(url, port, output)``, its address read from the line it prints (``--port 0`` too); ``output``: the lines it
    printed so far (stdout and stderr). Each server is stopped at the end."""
    launch = ["-c", SLOW_LAB] if slow_lab else ["-m", "lenssim_cli.main"]
    with ExitStack() as stack:
        started = []
        for args in arg_lists:
            proc = subprocess.Popen([sys.executable, *launch, "explore", *args], stdout=subprocess.PIPE,
                                    stderr=subprocess.STDOUT, text=True)
            lines, output = queue.Queue(), []

            def read(proc=proc, lines=lines, output=output):
                for line in proc.stdout:
                    output.append(line)
                    lines.put(line)
                lines.put(None)
            reader = threading.Thread(target=read, daemon=True)
            reader.start()
            stack.callback(_stop, proc, reader)
            started.append((lines, output))
        servers = []
        for lines, output in started:
            t0 = time.monotonic()
            while True:
                try:
                    line = lines.get(timeout=max(1.0, START_S - (time.monotonic() - t0)))
                except queue.Empty:
                    line = None
                if line is None:
                    pytest.fail("lenssim explore did not start: " + "".join(output)[-3000:])
                m = re.match(r"lenssim explore: (http://127\.0\.0\.1:(\d+)/)", line)
                if m:
                    servers.append((m.group(1), int(m.group(2)), output))
                    break
        yield servers


def _stop(proc, reader) -> None:
    proc.terminate()
    try:
        proc.wait(timeout=30)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
    reader.join(timeout=30)
    proc.stdout.close()


@contextmanager
def _explore(*args, slow_lab=False):
    with _explore_many(list(args), slow_lab=slow_lab) as (server,):
        yield server


@pytest.fixture(scope="module")
def server(sweep, tmp_path_factory):
    """The paper's explorer on the astronaut with the small sweep as its map, its restoration lab a long computation
    that runs until cancelled (the other panels are the real ones): ``(url, folder)``."""
    with _explore("skimage:astronaut", "--sweep", str(sweep), "--port", "0", slow_lab=True) as (url, _, _):
        yield url, tmp_path_factory.mktemp("explore_page")


@pytest.fixture(scope="module")
def lens_server(tmp_path_factory):
    with _explore("skimage:astronaut", "--lens", "paper_singlet", "--vary", "E1.bending=-1:0:0.025",
                  "--vary", "S2.conic=-10:0:0.1", "--port", "0") as (url, _, _):
        yield url, tmp_path_factory.mktemp("explore_lens")


def _handshake(port: int, origin: str, host: str | None = None) -> int:
    """The status of the WebSocket handshake a page opens (``/ws``), sent from ``origin`` for ``host`` (by default
    the server's own address): 101 (switching protocols) or 403."""
    host = host or f"127.0.0.1:{port}"
    request = (f"GET /ws HTTP/1.1\r\nHost: {host}\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
               "Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\n"
               f"Origin: {origin}\r\n\r\n")
    with socket.create_connection(("127.0.0.1", port), timeout=60) as s:
        s.sendall(request.encode())
        head = b""
        while b"\r\n" not in head:
            chunk = s.recv(1024)
            if not chunk:
                break
            head += chunk
    return int(head.split()[1])


def _get(port: int, host: str, path: str = "/lenssim-no-such-page") -> int:
    """The status of ``GET path`` with the Host header ``host``: 403 when the server refuses the host, else what the
    path gives (404 for a page that does not exist: the request was let in)."""
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=120)
    try:
        conn.putrequest("GET", path, skip_host=True)
        conn.putheader("Host", host)
        conn.endheaders()
        r = conn.getresponse()
        r.read()
        return r.status
    finally:
        conn.close()


def test_only_the_address_it_was_started_for_may_connect(sweep):
    """A fixed port, --port 0 and --host with --allow-origin: a page of another origin cannot open the WebSocket (403)
    and a request for another host name is refused (403) on each; the server's own names and the allowed origins
    are let in (101; the page 200)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        fixed = s.getsockname()[1]
    common = ["--sweep", str(sweep)]
    settings = (["--port", str(fixed)], ["--port", "0"],
                ["--host", "127.0.0.1", "--port", "0", "--allow-origin", "http://friend.example:8080",
                 "--allow-origin", "lab.example"])
    with _explore_many(*[common + a for a in settings]) as servers:
        assert servers[0][1] == fixed
        for (url, port, output), args in zip(servers, settings):
            for origin in ("http://evil.example", f"http://evil.example:{port}", "https://evil.example",
                           f"http://127.0.0.1:{port + 1}", "null"):
                assert _handshake(port, origin) == 403, (args, origin)
            for origin in (f"http://127.0.0.1:{port}", f"http://localhost:{port}"):
                assert _handshake(port, origin) == 101, (args, origin)
            # DNS rebinding: a page of evil.example whose name now points here
            assert _handshake(port, f"http://evil.example:{port}", host=f"evil.example:{port}") == 403
            for host in (f"evil.example:{port}", "evil.example", f"127.0.0.1.evil.example:{port}"):
                assert _get(port, host) == 403, (args, host)
                assert _get(port, host, "/") == 403, (args, host)
            for host in (f"127.0.0.1:{port}", f"localhost:{port}"):
                assert _get(port, host) == 404, (args, host)  # let in (the page does not exist)
        _, port, output = servers[2]
        assert _handshake(port, "http://friend.example:8080") == 101
        assert _handshake(port, "http://friend.example:8081") == 403
        assert _get(port, f"lab.example:{port}") == 404 and _get(port, "lab.example:8080") == 403
        assert _get(servers[1][1], f"127.0.0.1:{servers[1][1]}", "/") == 200  # the page itself
        time.sleep(0.5)  # the report line is printed as the request is refused; let the reader take it
        said = "".join(servers[1][2])
        assert f"refused a request from Host 'evil.example:{servers[1][1]}' (403)" in said, said[-2000:]


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


def _slider_value(page, label: str) -> float:
    return float(_text(page, f"text={label}").rsplit(":", 1)[1])


MARKER = """() => { const m = Bokeh.documents[0].get_model_by_name('selected'); return [m.data.x[0], m.data.y[0]]; }"""
"""The cost map's marker of the selected design, as the browser has it: ``[x, y]``."""


@needs_browser
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
        # a click on the cost map selects a design: the sliders move, the marker moves there, the criteria change
        before_c, before_m, before_o = criteria(), page.evaluate(MARKER), optics()
        box = page.locator("canvas:visible").first.bounding_box()
        page.mouse.click(box["x"] + box["width"] * 0.3, box["y"] + box["height"] * 0.3)
        _wait_change(lambda: page.evaluate(MARKER), before_m)
        assert page.evaluate(MARKER) == [_slider_value(page, "Q_back (back conic)"), _slider_value(page, "s (bending)")]
        _wait_change(criteria, before_c)
        _wait_change(optics, before_o)  # the PSF figure follows the click too
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
        # a long computation (the restoration lab; here one that runs until it is cancelled) runs off the server's
        # event loop: the page says it is busy, a second page loads meanwhile, and Cancel stops it
        page.locator(".bk-tab", has_text="Restoration lab").first.click()
        page.get_by_text("run the restoration lab").click()
        busy = "text=/computing:.*the restoration lab/"
        page.wait_for_selector(busy, timeout=60_000)
        second = page.context.browser.new_page()  # a context of its own: another user
        second.goto(url)
        second.wait_for_selector("text=MSE_R at 27.6 dB", timeout=150_000)
        assert page.locator(busy).is_visible()  # the lab still runs: the second page loaded during it
        second.close()
        page.get_by_role("button", name="Cancel").click()
        page.wait_for_selector("text=/cancelled:.*the restoration lab/", timeout=60_000)
        assert not page.locator(busy).is_visible()
        page.screenshot(path=str(d / "page.png"), full_page=True)
    assert not outside, f"requests off this machine: {outside[:5]}"
    assert not errors, f"console errors: {errors[:5]}"


@needs_browser
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
