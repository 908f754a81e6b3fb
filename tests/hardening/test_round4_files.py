"""Bad inputs, fourth round (issue 43, "Errors a person can read"): every TOML file the project reads (lens, sensor,
sweep config, tolerances, designs, glass catalogue) is capped in size and in nesting before it is parsed; a message
lists a few names and quotes short strings; a progress bar is drawn only on a terminal and knows its total; and
``simulate --raw-out --full-frame`` writes the frame's mosaic and its crops' as DNGs.

Each refusal is checked for what a person reads: exactly one line on stderr, ``lenssim CMD: error: ...``, short,
exit status 2, no traceback, nothing written.
"""

from __future__ import annotations

import functools
import math
import os
import fcntl
import random
import select
import struct
import sys
import termios
import tomllib

import numpy as np
import pytest
import torch

from lenssim.io.files import MAX_TOML_BYTES, MAX_TOML_DEPTH, _toml_too_deep, read_toml
from lenssim.validate import MAX_NAMES_LISTED, MAX_QUOTED_CHARS, listed, quoted
from lenssim_cli.main import MAX_MESSAGE_CHARS, main

E = ["--design", "end_to_end_paper"]
MAX_LINE = 300
"""The longest refusal these tests accept (characters): the file's name, the problem, what is allowed."""
DEEP = 5000
"""The issue's nesting (levels): Python's TOML reader ran out of stack."""

COMMANDS = {  # each kind of TOML file a user can name: argv for a file PATH
    "lens prescription file": lambda p: ["inspect", p],
    "lens prescription file (simulate --lens)": lambda p: ["simulate", "ok.png", "--lens", p, "--crop", "64",
                                                           "--out", "o"],
    "sensor file": lambda p: ["simulate", "ok.png", *E, "--sensor", p, "--crop", "64", "--out", "o"],
    "sweep config": lambda p: ["sweep", p, "--out", "a.nc"],
    "tolerances file": lambda p: ["tolerance", *E, "--tolerances", p, "--out", "o"],
    "designs file": lambda p: ["designs", "--designs", p],
}


def _nested(kind: str, n: int) -> str:
    """A TOML text nesting ``n`` levels deep (tables and arrays below the top level) in one of the ways the format
    allows."""
    return {
        "arrays": "a = " + "[" * n + "]" * n + "\n",
        "inline tables": "a = " + "{b = " * n + "1" + "}" * n + "\n",
        "arrays of inline tables": "a = " + "[{b = " * (n // 2) + ("[1]" if n % 2 else "1") + "}]" * (n // 2) + "\n",
        "a table header": "[" + ".".join(["a"] * n) + "]\nx = 1\n",
        "an array-of-tables header": "[[" + ".".join(["a"] * (n - 1)) + "]]\nx = 1\n",  # n - 2 tables, array, table
        "a dotted key": ".".join(["a"] * (n + 1)) + " = 1\n",  # n tables, then the value
        "a section's value": "[sensor]\nx = " + "[" * (n - 1) + "1" + "]" * (n - 1) + "\n",
        "after strings and comments with brackets": 'p = "]]]]}}}}"\nq = \'\'\'[[[\n]]]\'\'\'\n# ]]]]]]]]\n'
                                                    "a = " + "[" * n + "]" * n + "\n",
    }[kind]


NESTINGS = ("arrays", "inline tables", "arrays of inline tables", "a table header", "an array-of-tables header",
            "a dotted key", "a section's value", "after strings and comments with brackets")


@pytest.fixture
def one_line(capsys):
    """``one_line(argv, match, root)``: ``main(argv)`` refuses in exactly one short line naming the problem, status 2,
    and leaves nothing new in ``root``; returns the line."""
    def check(argv, match, root):
        before = sorted(p.name for p in root.iterdir())
        try:
            rc = main(argv)
        except SystemExit as exc:
            rc = exc.code
        out = capsys.readouterr()
        err = out.err.splitlines()
        assert rc == 2, err[-3:]
        assert len(err) == 1, err[:3]
        line = err[0]
        assert line.startswith(f"lenssim {argv[0]}: error: ") and match in line, line[:400]
        assert len(line) < MAX_LINE, line
        assert "Traceback" not in out.err and "Traceback" not in out.out
        assert sorted(p.name for p in root.iterdir()) == before, "a refused run left files behind"
        return line
    return check


# -- nesting ---------------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("depth", [DEEP, MAX_TOML_DEPTH + 1])
@pytest.mark.parametrize("nesting", NESTINGS)
@pytest.mark.parametrize("what", COMMANDS)
def test_a_deeply_nested_toml_file_is_refused_in_one_line(files, one_line, what, nesting, depth):
    (files / "deep.toml").write_text(_nested(nesting, depth))
    line = one_line(COMMANDS[what]("deep.toml"), f"'deep.toml' nests tables or arrays more than {MAX_TOML_DEPTH} "
                    "levels deep", files)
    assert what.split(" (")[0] in line


@pytest.mark.parametrize("nesting", NESTINGS)
def test_the_nesting_limit_is_exact_and_the_glass_catalogue_has_it_too(tmp_path, nesting):
    from lenssim.model.glass import load_glasses

    f = tmp_path / "t.toml"
    f.write_text(_nested(nesting, MAX_TOML_DEPTH))
    assert isinstance(read_toml(f, "file"), dict)  # at the limit: read
    f.write_text(_nested(nesting, MAX_TOML_DEPTH + 1))
    with pytest.raises(ValueError, match=f"^glass catalogue '{f}' nests tables or arrays more than 16 levels deep"):
        load_glasses(f)


def _toml_value(rng: random.Random, depth: int) -> tuple[str, int]:
    """A random TOML value and its nesting depth (arrays and inline tables), with strings of all four kinds full of
    brackets, braces, quotes, escapes and hashes, and comments inside arrays."""
    def junk(alphabet, sep=""):  # multi-line strings: pieces apart, so that no three quotes meet inside
        return sep.join(rng.choice(alphabet) for _ in range(rng.randrange(0, 12))) + sep

    if depth == 0 or rng.random() < 0.25:
        kind = rng.randrange(6)
        if kind == 0:
            return '"' + junk(["[", "]", "{", "}", "#", "'", "\\\"", "\\\\", "a", " ", "\\u005B"]) + '"', 0
        if kind == 1:
            return "'" + junk(["[", "]", "{", "}", "#", '"', "\\", "a"]) + "'", 0
        if kind == 2:  # a multi-line basic string: up to two quotes inside, and before its end
            body = junk(["[", "]", "{", "\n", '"', '""', "\\\"\"\"", "#", "a", "\\\n  "], sep="a")
            return '"""' + body + '"' * rng.randrange(3) + '"""', 0
        if kind == 3:
            body = junk(["[", "]", "{", "\n", "'", "''", '"""', "\\", "#", "a"], sep="a")
            return "'''" + body + "'" * rng.randrange(3) + "'''", 0
        return rng.choice(["1", "-2.5e3", "true", "1979-05-27", "inf"]), 0
    if rng.random() < 0.5:
        items = [_toml_value(rng, depth - 1) for _ in range(rng.randrange(0, 4))]
        sep = rng.choice([", ", ",\n # ] } [ \" ' comment\n ", ","])
        return "[" + sep.join(v for v, _ in items) + ("," if items and rng.random() < 0.3 else "") + "]", \
            1 + max([d for _, d in items], default=0)
    items = [_toml_value(rng, depth - 1) for _ in range(rng.randrange(0, 4))]
    keys = [rng.choice(['"k[{#%d"', "'q]}%d'", "b%d"]) % i for i in range(len(items))]
    return "{" + ", ".join(f"{k} = {v}" for k, (v, _) in zip(keys, items)) + "}", \
        1 + max([d for _, d in items], default=0)


def test_the_nesting_scan_agrees_with_tomls_own_reading_of_strings_and_comments():
    """Against Python's TOML reader: 400 random documents whose strings and comments are full of brackets; the scan
    refuses exactly those nested deeper than the limit (depth counted independently by walking what tomllib read)."""
    def depth_of(x):
        if isinstance(x, dict):
            return 1 + max([depth_of(v) for v in x.values()], default=0)
        if isinstance(x, list):
            return 1 + max([depth_of(v) for v in x], default=0)
        return 0

    rng = random.Random(43)
    seen = set()
    for _ in range(400):
        lines, want = [], 0
        for i in range(rng.randrange(1, 5)):
            v, d = _toml_value(rng, rng.randrange(0, 7))
            lines.append(f"v{i} = {v}" + rng.choice(["", "  # ]]] [[[ {{ \"\"\" '''"]))
            want = max(want, d)
        text = "\n".join(lines) + "\n"
        parsed = tomllib.loads(text)  # the generator writes valid TOML
        assert max(depth_of(v) for v in parsed.values()) == want, text
        for limit in range(0, 7):
            assert _toml_too_deep(text, limit) == (want > limit), (limit, text)
        seen.add(want)
    assert seen >= {0, 1, 2, 3, 4, 5}


def test_a_string_that_does_not_end_stops_the_scan_where_toml_stops(tmp_path):
    f = tmp_path / "t.toml"
    for text in ['a = "' + "[" * DEEP, "a = '''" + "[" * DEEP, 'a = """' + "[" * DEEP + '\\"""', "a = '[[\n" + "[" * DEEP]:
        f.write_text(text)
        with pytest.raises(ValueError, match="is not valid TOML"):
            read_toml(f, "file")


# -- size ------------------------------------------------------------------------------------------------------------
@functools.lru_cache
def _huge(kind: str) -> str:
    if kind == "comments":
        return "# " + "x" * MAX_TOML_BYTES + "\n"
    if kind == "one byte over":
        return "a = 1\n" + "#" * (MAX_TOML_BYTES - 6) + "\n"  # MAX_TOML_BYTES + 1 bytes
    return "[sensor]\n" + "".join(f"k{i} = 1\n" for i in range(2_000_000))  # the 20 MB of unknown keys


@pytest.mark.parametrize("kind", ["comments", "one byte over", "20 MB of keys"])
@pytest.mark.parametrize("what", COMMANDS)
def test_a_toml_file_over_the_size_cap_is_refused_before_it_is_parsed(files, one_line, what, kind):
    (files / "big.toml").write_text(_huge(kind))
    one_line(COMMANDS[what]("big.toml"), "'big.toml' is larger than 1 MiB: not allowed", files)


def test_a_file_at_the_size_cap_is_read(tmp_path):
    f = tmp_path / "t.toml"
    f.write_text("a = 1\n" + "#" * (MAX_TOML_BYTES - 7) + "\n")
    assert f.stat().st_size == MAX_TOML_BYTES and read_toml(f, "file") == {"a": 1}


# -- many names, long names -----------------------------------------------------------------------------------------
LENS = ("stop_surface = 1\n[aperture]\nentrance_pupil_diameter_mm = 10\n[[surfaces]]\nradius_mm = 50\n"
        "thickness_mm = 3\nmaterial = 'N-BK7'\n[[surfaces]]\nradius_mm = 'inf'\nthickness_mm = 97\n")
"""A plano-convex singlet: a lens file the reader takes."""

MANY = 40_000
"""Unknown keys in a file under the size cap."""

NAMES = [  # (what, text, what the line says)
    ("sensor file", "[sensor]\n" + "".join(f"k{i} = 1\n" for i in range(MANY)),
     f"unknown key(s) k0, k1, k10, k100, k1000 and {MANY - 5} more; allowed: "),
    ("sensor file", "".join(f"[t{i}]\n" for i in range(MANY)), f"and {MANY - 5} more"),
    ("sensor file", f'[sensor]\n"{"k" * 200_000}" = 1\n', "(200000 characters)"),
    ("sweep config", "".join(f"[s{i}]\n" for i in range(MANY)), f"unknown section(s) s0, s1, s10, s100, s1000 and "
                                                                  f"{MANY - 5} more; allowed: [lens]"),
    ("sweep config", "[numerics]\n" + "".join(f"n{i} = 1\n" for i in range(MANY)), f"and {MANY - 5} more"),
    ("sweep config", "[focus]\n" + "".join(f"f{i} = 1\n" for i in range(MANY)), f"and {MANY - 5} more"),
    ("sweep config", "[channels]\ncamera = 'x'\n" + "".join(f"c{i} = 1\n" for i in range(MANY)), f"and {MANY - 5} more"),
    ("sweep config", "[lens]\n" + "".join(f"l{i} = 1\n" for i in range(MANY)), f"and {MANY - 5} more"),
    ("sweep config", f"[grid]\n{'g' * 100_000} = [1, 2, 1]\n", "(100000 characters)"),
    ("sweep config", f"[focus]\ncriterion = '{'c' * 100_000}'\n", "(100000 characters)"),
    ("sweep config", "[grid]\ns = [" + ", ".join(["1"] * MANY) + "]\n", "is not allowed: [start, stop, step]"),
    ("tolerances file", "[tolerances]\n" + "".join(f"t{i} = 1\n" for i in range(MANY)), f"and {MANY - 5} more"),
    ("tolerances file", "".join(f"[t{i}]\n" for i in range(MANY)), f"unknown table(s) t0, t1, t10, t100, t1000 and "
                                                                   f"{MANY - 5} more"),
    ("tolerances file", f"[tolerances]\ngrade = '{'g' * 100_000}'\n", "(100000 characters)"),
    ("tolerances file", "[tolerances]\ngrade = [1]\n", "tolerance grade [1] is not known"),
    ("designs file", f"['{'d' * 100_000}']\ns = 'x'\n", "(100000 characters)"),
    ("designs file", "[d]\n" + "".join(f"p{i} = 'x'\n" for i in range(MANY)), f"bad: p0, p1, p2, p3, p4 and "
                                                                              f"{MANY - 5} more"),
    ("lens prescription file", f'{"k" * 100_000} = 1\n', "(100000 characters) at the top level"),
    ("lens prescription file", "stop_surface = 1\n[aperture]\nentrance_pupil_diameter_mm = 1\n[[surfaces]]\n"
                               f"radius_mm = 10\nthickness_mm = 1\nmaterial = '{'m' * 100_000}'\n",
     "(100000 characters)"),
    ("lens prescription file", "stop_surface = 1\n[aperture]\nentrance_pupil_diameter_mm = 1\n[[surfaces]]\n"
                               f"radius_mm = 10\nthickness_mm = [{', '.join(['1'] * MANY)}]\n", "is not a number"),
    ("lens prescription file", LENS + f"[published]\n'{'p' * 100_000}' = [true]\n", "(100000 characters)"),
]


@pytest.mark.parametrize("what, text, match", NAMES)
def test_many_or_long_names_give_one_short_line(files, one_line, what, text, match):
    (files / "names.toml").write_text(text)
    one_line(COMMANDS[what]("names.toml"), match, files)


GRID = "[grid]\ns = [0.0, 0.0, 1.0]\nQ = [-4.0, -4.0, 1.0]\n"

WRONG_TYPES = [  # a sweep config's values of the wrong type (each was a TypeError's traceback)
    (GRID + "snr_db = true\n", "snr_db=True is not allowed: a list of numbers (SNRs in dB)"),
    (GRID + "snr_db = 27.6\n", "snr_db=27.6 is not allowed: a list of numbers (SNRs in dB)"),
    (GRID + "snr_db = [[1, 2], 'a']\n", "snr_db=[1, 2] is not allowed: a finite number"),
    (GRID + "snr_db = []\n", "snr_db=[] is not allowed: at least one SNR in dB"),
    (GRID + "[focus]\ncriterion = [1]\n", "[focus] criterion [1] is not known; valid: "),
    (GRID + "[focus]\ncriterion = {a = 1}\n", "[focus] criterion {'a': 1} is not known; valid: "),
    (GRID + "[focus]\nsnr_db = {a = 1}\n", "[focus] snr_db={'a': 1} is not allowed: a finite number"),
    (GRID + "[focus]\nbounds_um = [1]\n", "[focus] bounds_um=[1.0] is not allowed: [low, high] in um, low < high"),
    (GRID + "[focus]\nbounds_um = 'x'\n", "[focus] bounds_um='x' is not allowed: a list of numbers"),
    (GRID + "[focus]\ntol_um = 'x'\n", "[focus] tol_um='x' is not allowed: a finite number > 0"),
    (GRID + "[focus]\ntol_um = 0\n", "[focus] tol_um=0 is not allowed: a finite number > 0"),
]


@pytest.mark.parametrize("text, match", WRONG_TYPES)
def test_a_sweep_config_value_of_the_wrong_type_is_refused_in_one_line(files, one_line, text, match):
    (files / "typed.toml").write_text(text)
    one_line(["sweep", "typed.toml", "--out", "a.nc"], match, files)


def test_a_glass_catalogue_of_many_unknown_keys_is_refused_in_one_short_line(tmp_path):
    from lenssim.model.glass import load_glasses

    f = tmp_path / "g.toml"
    f.write_text("[X]\n" + "".join(f"k{i} = 1\n" for i in range(MANY)))
    with pytest.raises(ValueError) as info:
        load_glasses(f)
    assert f"unknown key(s) k0, k1, k10, k100, k1000 and {MANY - 5} more" in str(info.value)
    assert len(str(info.value)) < MAX_LINE
    f.write_text(f"['{'G' * 100_000}']\nformula = 'nope'\n")
    with pytest.raises(ValueError, match=r"\(100000 characters\): formula 'nope' is not one of") as info:
        load_glasses(f)
    assert len(str(info.value)) < MAX_LINE


def test_listed_shows_a_few_names_the_closest_first_and_how_many_more():
    assert listed([]) == "none"
    assert listed(["a", "b"]) == "a, b"
    assert listed([f"n{i}" for i in range(7)]) == "n0, n1, n2, n3, n4 and 2 more"
    assert listed([f"n{i}" for i in range(7)], limit=7) == ", ".join(f"n{i}" for i in range(7))
    allowed = ["pixel_pitch_um", "width_px", "height_px", "full_well_e", "quantum_efficiency", "read_noise_e",
               "bit_depth"]
    assert listed(allowed, near=["read_noise"]).startswith("read_noise_e, pixel_pitch_um, width_px")
    assert listed(allowed, near=["zzz"]) == "pixel_pitch_um, width_px, height_px, full_well_e, quantum_efficiency and " \
                                            "2 more"
    long = "x" * 1000
    shown = listed([long, "b\nc"], quote=True)
    assert shown == f"{'x' * MAX_QUOTED_CHARS!r}... (1000 characters), 'b\\nc'" and "\n" not in shown
    assert len(listed([long] * 100)) < (MAX_QUOTED_CHARS + 30) * MAX_NAMES_LISTED


def test_quoted_is_repr_when_short_and_cut_with_its_length_when_long():
    assert quoted("ab") == "'ab'" and quoted(1.5) == "1.5" and quoted([1, 2]) == "[1, 2]"
    assert quoted("a" * MAX_QUOTED_CHARS) == repr("a" * MAX_QUOTED_CHARS)
    assert quoted("a\n" * 100) == repr("a\n" * (MAX_QUOTED_CHARS // 2)) + "... (200 characters)"
    big = list(range(10_000))
    assert quoted(big) == repr(big)[:MAX_QUOTED_CHARS] + f"... ({len(repr(big))} characters)"


def test_any_message_is_cut_to_a_bounded_line_keeping_its_start_and_its_end(files, capsys, monkeypatch):
    """The net under every message: a line longer than MAX_MESSAGE_CHARS keeps its start and end (what is allowed)."""
    import lenssim_cli.optics as optics

    def boom(args):
        raise ValueError("start " + "y" * 100_000 + " allowed: the end")

    monkeypatch.setattr(optics, "cmd_designs", boom)
    assert main(["designs"]) == 2
    (line,) = capsys.readouterr().err.splitlines()
    assert len(line) <= MAX_MESSAGE_CHARS + 100
    assert line.startswith("lenssim designs: error: start yyy") and line.endswith("yyy allowed: the end")
    assert "characters left out" in line


# -- progress bars ---------------------------------------------------------------------------------------------------
def test_a_progress_bar_is_drawn_on_a_terminal_only(monkeypatch):
    from lenssim_studies.progress import progress_bar

    master, slave = os.openpty()
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", 24, 100, 0, 0))  # a terminal 100 columns wide
    try:
        with os.fdopen(slave, "w", buffering=1) as tty:
            monkeypatch.setattr(sys, "stderr", tty)
            with progress_bar(total=10, unit="window", desc="work") as bar:
                bar.update(10)
            tty.flush()
            drawn = b""
            while select.select([master], [], [], 1.0)[0]:
                drawn += os.read(master, 4096)
        drawn = drawn.decode()
        assert "work" in drawn and "10/10" in drawn
    finally:
        os.close(master)
    pipe_r, pipe_w = os.pipe()
    with os.fdopen(pipe_w, "w") as pipe:
        monkeypatch.setattr(sys, "stderr", pipe)
        with progress_bar(total=10, unit="window", desc="work") as bar:
            bar.update(10)
    with os.fdopen(pipe_r) as r:
        assert r.read() == ""
    with progress_bar(total=10, unit="window", desc="work", show=False) as bar:  # --quiet
        assert bar.disable


def test_a_photo_refused_after_its_scan_leaves_one_line_and_no_bar(files, one_line, monkeypatch):
    import lenssim_cli.camera as camera

    monkeypatch.setattr(camera, "PROGRESS_DELAY_S", 0.0)  # a scan long enough to show its bar
    line = one_line(["simulate", "nan.exr", *E, "--crop", "64", "--out", "o"], "nan.exr", files)
    assert "checking nan.exr" not in line and "%|" not in line  # (one_line: no other line, \r included)


def _varying_disc():
    """PSFs that grow with the field (a disc 2 px across on the axis, 9 px in the corner), known support."""
    from lenssim import FunctionPSF
    from lenssim_studies.paper import PAPER_CAMERA

    def fn(x, y, n):
        d = torch.arange(n, dtype=torch.float64) - n // 2
        r2 = d[:, None] ** 2 + d[None, :] ** 2
        radius = 1.0 + 3.5 * torch.hypot(torch.as_tensor(x), torch.as_tensor(y)) / 0.4
        p = (r2[None] <= radius[:, None, None] ** 2).to(torch.float64)
        return p / p.sum(dim=(-2, -1), keepdim=True)
    return FunctionPSF(fn, PAPER_CAMERA.geometry, extent=11, mirror_symmetric=True)


@pytest.mark.parametrize("case", ["paper noise, two ISOs, two methods", "zones", "chain, RGB", "chain, mosaic",
                                  "blur cached"])
def test_the_crops_progress_total_is_the_windows_counted(case):
    """``simulate_crops(progress_total=...)`` announces before any work exactly the windows its progress adds up to
    (the total a progress bar needs to show the time left)."""
    from lenssim.io.sensor_file import load_sensor
    from lenssim_studies.paper import PAPER_SENSOR
    from pipeline.blur import WindowScheme
    from pipeline.camera_chain import CameraChain
    from pipeline.simulate import simulate_crops

    g = torch.Generator().manual_seed(1)
    img = torch.rand(1, 3, 120, 176, generator=g, dtype=torch.float64)
    boxes = [(44, 76, 72, 104), (0, 32, 144, 176), (88, 120, 0, 32)]
    kw = dict(scheme=WindowScheme(32, 8, 16), sensor=PAPER_SENSOR, dtype=torch.float64, full_well=800.0,
              methods=("wiener:stats=16",))
    imx = load_sensor("sony_imx477")
    kw.update({"paper noise, two ISOs, two methods": dict(full_well=[800.0, 3200.0], methods=("wiener:stats=16", "tikhonov")),
               "zones": dict(blur_zones="auto"), "chain, RGB": dict(sensor=CameraChain(imx)),
               "chain, mosaic": dict(sensor=CameraChain(imx, restore_on="mosaic"), methods=("richardson_lucy:iterations=2",)),
               "blur cached": dict(blur_cache={})}[case])
    fw = kw.pop("full_well")
    psf = _varying_disc()
    for _ in range(2 if case == "blur cached" else 1):  # the second time, the blur comes from the cache
        counted, announced = [], []
        simulate_crops(img, psf, fw, boxes + boxes[:1], progress=counted.append, progress_total=announced.append, **kw)
        assert len(announced) == 1 and announced[0] == sum(counted) > 0
        if case == "blur cached" and _ == 0:
            first = announced[0]
    if case == "blur cached":
        assert announced[0] < first


# -- simulate --raw-out --full-frame -------------------------------------------------------------------------------
def test_raw_out_with_full_frame_writes_the_frames_mosaic_and_each_crops(tmp_path, capsys):
    """The frame's mosaic as a DNG (sensor_raw.dng) and each crop's, the crop's being the frame's under its box with
    the CFA pattern of its first pixel: the issue's run ended in a KeyError."""
    rawpy = pytest.importorskip("rawpy")
    from pipeline import write_image
    from pipeline.camera_chain import pattern_at

    a = np.random.default_rng(3).random((3, 256, 256)).astype(np.float32)
    write_image(tmp_path / "p.png", torch.from_numpy(a))
    out = tmp_path / "run"
    assert main(["simulate", str(tmp_path / "p.png"), *E, "--sensor", "sony_imx477", "--cfa", "RGGB", "--demosaic",
                 "Malvar2004", "--raw-out", "--full-frame", "--angles", "0", "0.6", "--crop", "48", "--out",
                 str(out)]) == 0
    capsys.readouterr()
    import json

    with rawpy.imread(str(out / "sensor_raw.dng")) as raw:
        frame = raw.raw_image.copy()
        assert frame.shape == (256, 256) and raw.white_level == 4095
    crops = json.loads((out / "metrics.json").read_text())["crops"]
    assert len(crops) == 2
    for c in crops:
        r0, r1, c0, c1 = c["box_r0_r1_c0_c1"]
        with rawpy.imread(str(out / f"crop_{c['requested_deg']:g}deg_raw.dng")) as raw:
            desc = raw.color_desc.decode()
            assert "".join(desc[i] for i in raw.raw_pattern.flatten()) == pattern_at("RGGB", r0, c0)
            assert np.array_equal(raw.raw_image, frame[r0:r1, c0:c1])
    assert not math.isnan(float(frame.mean()))
