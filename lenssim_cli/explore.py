"""``lenssim explore``: a local web application over the explorer's computations (issue 32; docs/explore.md).

    lenssim explore [PHOTO] [--photo FILE ...] [--design NAME] [--sweep FILE.nc] [--port 5006] [--host 127.0.0.1]
                    [--allow-origin ORIGIN ...] [--max-upload-mb 200]
    lenssim explore [PHOTO] --lens LENS --vary NAME=LO:HI[:STEP] [--vary ...] [--hold efl,fnum] [--image file]
                    [--aspherize S7] [--pixel-pitch UM] ...

Panel (HoloViz, on a Bokeh server) lays out :mod:`lenssim_studies.explore`'s update functions: the design panel (sliders,
the criteria, PSFs and MTFs, the cost map; a click on the map selects a design), the photo panel (a click on the photo
moves the crop; sensor preset, CFA, demosaicing, ISO, seed), the restoration lab (two methods side by side, a
manufactured lens restored with the nominal PSFs and with its own) and the export (the command line that reproduces
the photo panel, a PNG of it). Every script and style comes from the installed packages (Bokeh's server serves them);
nothing is fetched from elsewhere. The server binds to 127.0.0.1 unless ``--host`` says otherwise (with a warning),
and answers only requests for the address it was started for, from pages of that address (its Host and Origin,
:func:`lock_down`; ``--allow-origin`` adds others): 403 otherwise, on every port. Every computation runs off the
server's event loop (:class:`PageJobs`), the page saying what runs, with a Cancel button.
An upload is checked as the command line checks a photo (format, size from the header, every pixel finite), under a
name of the server's own in a private temporary folder removed after reading; no other path is read or written.
A failed computation shows its one-line error on the page; the app keeps serving.
"""

from __future__ import annotations

import math
import sys
import threading

DEFAULT_PORT = 5006
DEFAULT_MAX_UPLOAD_MB = 200.0
UPLOAD_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".exr", ".dng", ".nef", ".cr2", ".cr3", ".arw", ".raf",
                   ".orf", ".rw2")
"""Extensions an upload may have (its name is used for nothing else)."""
MAP_POLL_MS = 3000
"""How often (ms) a page redraws the cost map while it is being computed."""
OVERVIEW_PX = 480
"""Longer side (px) of the clickable overview of the photo."""
SAMPLE_PHOTOS = ("skimage:astronaut", "skimage:chelsea", "skimage:coffee", "skimage:rocket",
                 "skimage:hubble_deep_field", "skimage:camera")
"""scikit-image's samples the page offers besides the user's photos (each shipped inside the package: none is
downloaded)."""
GENERATED = "generated scene"
LAB_COLUMN_PX = 260
"""Width (px) of each of the restoration lab's control columns (method A, method B, the manufactured lens)."""
LAB_BOX_STYLE = {"border": "1px solid #d0d0d0", "border-radius": "4px", "padding": "4px"}
"""The frame around each method's controls in the restoration lab."""


def register(sub) -> None:
    p = sub.add_parser("explore", help="an interactive explorer of designs, photos and restorations in the browser "
                       "(a local web app; docs/explore.md)")
    p.add_argument("photo", nargs="?", help="image file (also a camera RAW file) or skimage:NAME; default: the "
                   "generated scene")
    p.add_argument("--photo", dest="photos", action="append", metavar="FILE", default=[],
                   help="another photo the page offers (repeat; the page also offers the generated scene and "
                        "scikit-image's samples)")
    p.add_argument("--design", metavar="NAME", help="the design the sliders start at (see `lenssim designs`; default "
                   "end_to_end_paper)")
    p.add_argument("--lens", metavar="LENS", help="any lens instead of the paper's singlet: a .zmx or .toml "
                   "prescription, or a shipped lens's name (docs/any-lens.md); its free parameters by --vary")
    p.add_argument("--vary", action="append", metavar="NAME=LO:HI[:STEP]",
                   help="--lens: a free parameter as a slider from LO to HI (STEP: its step; default "
                        f"{SLIDER_STEPS_HELP} steps), named as `lenssim tradeoff` names them (S5.conic, S7.A4, "
                        "E1.bending, focus_um, ...); repeat for up to 3; the map is over the first two")
    p.add_argument("--hold", help="--lens: what each design holds: a comma-separated list of efl, fnum")
    p.add_argument("--image", choices=("file", "paraxial", "best"), default="file",
                   help="--lens: each design's image plane (default: the file's)")
    p.add_argument("--aspherize", nargs="+", metavar="S5", help="--lens: surfaces made even aspheres (their A4..A16 "
                   "free)")
    p.add_argument("--pixel-pitch", type=float, metavar="UM", help="--lens: the sensor's pixel pitch (um) instead of "
                   "the photo spanning the lens's field (and, for the criteria, of the lens's Nyquist pitch)")
    p.add_argument("--sweep", metavar="FILE.nc", help="a sweep over s and Q_back (lenssim sweep) for the cost map; "
                   "default: a coarse 13 x 15 grid computed once in the background (~1 min)")
    p.add_argument("--port", type=int, default=DEFAULT_PORT, help=f"port (default {DEFAULT_PORT}; 0: any free one)")
    p.add_argument("--host", default="127.0.0.1",
                   help="address to listen on (default 127.0.0.1: this machine only; another one is warned about)")
    p.add_argument("--max-upload-mb", type=float, default=DEFAULT_MAX_UPLOAD_MB,
                   help=f"largest photo a page may upload (MB; default {DEFAULT_MAX_UPLOAD_MB:g})")
    p.add_argument("--allow-origin", action="append", default=[], metavar="ORIGIN",
                   help="another address the page may be opened at: http://NAME:PORT (a page of that origin may "
                        "connect, and the server answers to NAME:PORT), or NAME[:PORT] (NAME at the explorer's port); "
                        "repeat for more. Default: only the address the server was started for (docs/explore.md)")
    p.set_defaults(func=cmd_explore)


SLIDER_STEPS_HELP = 100


def check_explore_arguments(args) -> list:
    """Every argument of ``lenssim explore`` that needs no file checked (one-line ``ValueError``); returns
    ``--allow-origin``'s ``(name, port)`` pairs."""
    if not 0 <= args.port <= 65535:
        raise ValueError(f"--port {args.port} is not allowed: 0 (any free port) to 65535")
    if not (math.isfinite(args.max_upload_mb) and 0 < args.max_upload_mb <= 4096):
        raise ValueError(f"--max-upload-mb {args.max_upload_mb:g} is not allowed: more than 0 and at most 4096")
    if not args.host or any(c.isspace() for c in args.host):
        raise ValueError(f"--host {args.host!r} is not allowed: an address or a host name")
    return [parse_allowed_origin(o) for o in args.allow_origin]


def cmd_explore(args) -> int:
    allow_origins = check_explore_arguments(args)
    lens_args = [f for f, v in (("--vary", args.vary), ("--hold", args.hold), ("--aspherize", args.aspherize),
                                ("--pixel-pitch", args.pixel_pitch),
                                ("--image", None if args.image == "file" else args.image)) if v is not None]
    if args.lens is None and lens_args:
        raise ValueError(f"{', '.join(lens_args)} appl(ies) to --lens LENS (any lens); the paper's singlet has its "
                         "own sliders")
    if args.lens is not None:
        given = [f for f, v in (("--design", args.design), ("--sweep", args.sweep)) if v is not None]
        if given:
            raise ValueError(f"{', '.join(given)} describe(s) the paper's singlet; leave them out with --lens")
        if not args.vary:
            raise ValueError("--lens needs its free parameters: --vary NAME=LO:HI (e.g. --vary E1.bending=0.3:1.3)")
    # the lens: any lens with its --vary sliders, or the paper's singlet from --design (each checked before serving)
    kind = _lens_arguments(args) if args.lens else {"start": _start_design(args.design)}
    try:
        import panel  # noqa: F401
    except ImportError:
        raise ValueError("lenssim explore needs Panel: pip install 'lenssim[explore]'") from None
    from lenssim_studies.explore import Explorer

    ds = None
    if args.sweep:
        ds = _load_sweep(args.sweep)
    for extra in args.photos:
        _check_photo_arg(extra)
    photo, source = _open_photo(args.photo)
    explorer = Explorer(photo=photo, photo_source=source, **kind)
    photos = ([args.photo] if args.photo else []) + [p for p in args.photos if p != args.photo]
    if ds is not None:
        explorer.load_map(ds)
    else:  # the coarse map, once, in the background (the page shows its progress)
        import threading

        threading.Thread(target=explorer.compute_map, daemon=True, name="lenssim-explore-map").start()
    if args.host not in LOOPBACK_HOSTS:
        print(f"warning: --host {args.host}: the explorer is reachable from other machines; it has no login",
              file=sys.stderr)
    serve(explorer, args.photo, host=args.host, port=args.port, max_upload_mb=args.max_upload_mb, photos=photos,
          allow_origins=allow_origins)
    return 0


def parse_slider(text: str):
    """``NAME=LO:HI[:STEP]`` -> :class:`lenssim_studies.explore.FreeParameter` (one-line ``ValueError``)."""
    from lenssim_studies.explore import SLIDER_STEPS, FreeParameter

    name, sep, spec = text.partition("=")
    parts = spec.split(":")
    try:
        nums = [float(v) for v in parts]
    except ValueError:
        nums = []
    if not sep or not name.strip() or len(nums) not in (2, 3):
        raise ValueError(f"--vary {text!r} is not allowed: NAME=LO:HI[:STEP] with numbers (e.g. S7.conic=-2:0)")
    lo, hi = nums[:2]
    step = nums[2] if len(nums) == 3 else (hi - lo) / SLIDER_STEPS
    return FreeParameter(name.strip(), lo, hi, step)


def _lens_arguments(args) -> dict:
    """The explorer's lens from ``--lens`` and its ``--vary`` sliders, ``--hold``, ``--image``, ``--aspherize`` and
    ``--pixel-pitch`` (the file read and the arguments checked; the names and solves are checked by the explorer)."""
    from lenssim.io.prescription_file import read_lens
    from lenssim.optics.lens_solves import HOLDS

    free = tuple(parse_slider(v) for v in args.vary)
    hold = tuple(h.strip() for h in (args.hold or "").split(",") if h.strip())
    for h in hold:
        if h not in HOLDS:
            raise ValueError(f"--hold {h!r} is not allowed: a comma-separated list of {', '.join(HOLDS)}")
    p = read_lens(args.lens)
    aspherize = tuple(int(v.lstrip("Ss")) if v.lstrip("Ss").isdigit() else -1 for v in args.aspherize or ())
    for k, v in zip(aspherize, args.aspherize or ()):
        if not 1 <= k <= len(p.surfaces):
            raise ValueError(f"--aspherize {v} is not allowed: surfaces S1 to S{len(p.surfaces)}")
    return dict(prescription=p, lens=str(args.lens), free=free, hold=hold, image=args.image, aspherize=aspherize,
                pixel_pitch_um=args.pixel_pitch)


def _start_design(name):
    """The sliders' first values: a named design's (checked), or None (the explorer's default)."""
    if name is None:
        return None
    from lenssim_studies.explore import Controls

    from .common import designs

    named = designs(None)
    if name not in named:
        raise ValueError(f"--design {name!r} is not known; choose from {', '.join(sorted(named))}")
    return Controls(tuple(named[name].complete().floats().items()))


def _load_sweep(path):
    """A sweep file (``lenssim sweep``'s NetCDF), checked (its checksum) before use."""
    import xarray as xr

    from lenssim.io.files import check_input_file
    from lenssim_studies.sweep import verify_sweep

    check_input_file(path, "sweep file")
    try:
        ds = xr.load_dataset(path, engine="scipy")
    except Exception:  # noqa: BLE001 - whatever the reader says, the file is not a sweep
        raise ValueError(f"--sweep {str(path)!r} is not a sweep file (NetCDF written by `lenssim sweep`)") from None
    if "config_digest" not in ds.attrs:
        raise ValueError(f"--sweep {str(path)!r} is a NetCDF file but not a lenssim sweep (no config digest)")
    verify_sweep(ds, path)
    return ds


def _check_photo_arg(spec) -> None:
    """A photo the page may open later, checked now (a sample's name; a file's header and size)."""
    if spec.startswith("skimage:"):
        if spec not in SAMPLE_PHOTOS:
            raise ValueError(f"photo {spec!r} is not offered: a file, or one of {', '.join(SAMPLE_PHOTOS)}")
    else:
        _check_photo_bytes(spec, spec)


def _open_photo(spec):
    from lenssim_studies.paper import PAPER_CAMERA
    from pipeline.photo import open_photo

    if spec is None or spec == GENERATED:
        return None, GENERATED
    _check_photo_arg(spec)
    photo = open_photo(spec, PAPER_CAMERA)
    return photo, photo.source


def _check_photo_bytes(path, shown) -> None:
    """The explorer keeps its photo in memory: refused from the header, before any pixel is decoded, when its linear
    float32 frame would take more than :data:`pipeline.photo.PHOTO_KEEP_BYTES`."""
    from pipeline.photo import PHOTO_KEEP_BYTES, photo_info

    info = photo_info(path, "photo")
    need = info.pixels * info.channels * 4
    if need > PHOTO_KEEP_BYTES:
        raise ValueError(f"photo {shown!r} is {info.width} x {info.height} px ({need / 2**30:.3g} GiB as linear "
                         f"float32): the explorer keeps its photo in memory, at most {PHOTO_KEEP_BYTES / 2**30:.3g} GiB; "
                         "crop or scale it first")


class PageJobs:
    """The long computations of one page, off the server's event loop: each kind (the design, the photo panel, the
    restoration lab, opening a photo) in a daemon thread of its own, one at a time per kind; a newer job of a kind
    supersedes the running one (which stops at its next step, :class:`lenssim_studies.explore.Cancelled`, its result
    dropped); :meth:`cancel` drops them all.

    ``schedule(fn)`` runs ``fn`` on the page's event loop with its document locked (Bokeh's
    ``Document.add_next_tick_callback``, safe to call from a thread); None runs every job at once in the caller's
    thread (no server: tests, the in-process page). ``on_change()`` is called on the loop whenever :attr:`running`
    changes."""

    def __init__(self, schedule=None, on_change=None):
        self.schedule = schedule
        self.on_change = on_change or (lambda: None)
        self.running: dict = {}
        """``{kind: threading.Event}``: the jobs running (the event: cancel it)."""
        self.cancelled: tuple = ()
        """The kinds the last :meth:`cancel` stopped."""
        self._turns: dict = {}

    def submit(self, kind: str, work, done, failed) -> None:
        """Run ``work(cancel)`` (``cancel``: a ``threading.Event``); then, on the loop and unless superseded or
        cancelled, ``done(result)``, or ``failed(message)`` with its one-line error."""
        from functools import partial

        old = self.running.get(kind)
        if old is not None:
            old.set()
        token = threading.Event()
        self.running[kind] = token
        self.cancelled = ()
        self.on_change()
        finish = partial(self._finish, kind, token, done, failed)
        if self.schedule is None:
            finish(self._run(work, token))
            return
        turn = self._turns.setdefault(kind, threading.Lock())

        def worker():
            with turn:  # one job of a kind at a time: a superseded one stops at its next step
                outcome = self._run(work, token)
            try:
                self.schedule(partial(finish, outcome))
            except Exception:  # noqa: BLE001 - the page was closed meanwhile: nothing to show the result on
                pass
        threading.Thread(target=worker, daemon=True, name=f"lenssim-explore-{kind}").start()

    @staticmethod
    def _run(work, token):
        """``("done", result)``, ``("failed", one line)`` or ``("cancelled", None)``."""
        from lenssim_studies.explore import Cancelled

        if token.is_set():
            return "cancelled", None
        try:
            return "done", work(token)
        except Cancelled:
            return "cancelled", None
        except (ValueError, OSError) as exc:
            return "failed", str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        except Exception as exc:  # noqa: BLE001 - a defect: its traceback on the server's stderr, one line on the page
            import traceback

            traceback.print_exc()
            return "failed", f"internal error ({type(exc).__name__}; the server's log has the details)"

    def _finish(self, kind, token, done, failed, outcome) -> None:
        if self.running.get(kind) is not token:  # superseded or cancelled: its result is not wanted
            return
        del self.running[kind]
        self.on_change()
        status, value = outcome
        if status == "done":
            done(value)
        elif status == "failed":
            failed(value)

    def cancel(self, *kinds) -> None:
        """Stop the running jobs of ``kinds`` (all by default): their results are dropped."""
        stopped = [k for k in (kinds or tuple(self.running)) if k in self.running]
        for k in stopped:
            self.running.pop(k).set()
        if stopped:
            self.cancelled = tuple(stopped)
            self.on_change()

    def close(self) -> None:
        """The page is gone: stop its jobs and tell it nothing more."""
        self.on_change = lambda: None
        self.cancel()


JOB_LABELS = {"open": "opening the photo", "design": "the criteria and PSFs", "photo": "the photo panel",
              "lab": "the restoration lab"}
"""What the busy line calls each kind of job."""


def build_app(explorer, photo_arg=None, *, max_upload_mb: float = DEFAULT_MAX_UPLOAD_MB, photos=()):
    """The page (a Panel layout) over ``explorer`` (its design sliders are the explorer's: the paper's singlet or any
    lens); ``photos``: the photos offered besides the generated scene and scikit-image's samples. Its widgets are
    reachable as ``app.widgets`` for tests.

    Served (a Bokeh document), every computation runs off the event loop (:class:`PageJobs`), the first ones once the
    page has loaded; the page shows what runs, with a Cancel button. Without a server (tests) they run at once."""
    import io

    import numpy as np
    import panel as pn
    from bokeh.events import Tap
    from bokeh.plotting import figure

    from lenssim.io.sensor_file import sensor_names
    from lenssim.model.glass import load_glasses
    from lenssim.model.tolerances import GRADES
    from lenssim_studies.explore import MAP_CRITERIA, Cancelled, PhotoControls, command_line, figure_png
    from pipeline.camera_chain import DEMOSAIC_METHODS
    from pipeline.cfa import CFA_PATTERNS

    pn.config.loading_indicator = True
    sliders = explorer.sliders()  # at the explorer's start
    w = {sl.key: pn.widgets.FloatSlider(label=sl.label, start=sl.start, end=sl.end, step=sl.step, value=sl.value,
                                        format=_slider_format(sl.step)) for sl in sliders}
    w["glass"] = pn.widgets.Select(label="glass (catalogue)", options=list(load_glasses()),
                                   value=explorer.start.glass, visible=explorer.prescription is None)
    shown = [photo_arg or GENERATED] + [p for p in photos if p != photo_arg]
    offered = list(dict.fromkeys(shown + [GENERATED, *SAMPLE_PHOTOS]))
    w.update({
        "photo": pn.widgets.Select(label="photo", options=offered, value=shown[0]),
        "criterion": pn.widgets.Select(label="map criterion", options=list(MAP_CRITERIA), value="mse_r"),
        "snr": pn.widgets.Select(label="SNR [dB]", options={f"{s:g}": i for i, s in enumerate(explorer.snr_db)},
                                 value=min(1, len(explorer.snr_db) - 1)),
        "iso": pn.widgets.Select(label="ISO", options=[25, 100, 400], value=100),
        "seed": pn.widgets.IntInput(label="noise seed", value=0, start=0),
        "full_well": pn.widgets.FloatInput(label="full well [e-] (0: the ISO's)", value=0.0, start=0.0),
        "sensor": pn.widgets.Select(label="sensor", options=["(paper)"] + sensor_names(), value="(paper)"),
        "cfa": pn.widgets.Select(label="CFA", options=["none", *CFA_PATTERNS], value="none"),
        "demosaic": pn.widgets.Select(label="demosaicing", options=list(DEMOSAIC_METHODS), value="Malvar2004"),
        "restore": pn.widgets.TextInput(label="restoration", value="wiener"),
        "method_a": pn.widgets.TextInput(label="method A", value="wiener"),  # the lab's first picks (controls below)
        "method_b": pn.widgets.TextInput(label="method B", value="richardson_lucy"),
        "grade": pn.widgets.Select(label="tolerance grade", options=list(GRADES), value="commercial",
                                   sizing_mode="stretch_width"),
        "lens_seed": pn.widgets.IntInput(label="lens seed", value=0, start=0, sizing_mode="stretch_width"),
        "upload": pn.widgets.FileInput(label="upload a photo", accept=",".join(UPLOAD_SUFFIXES)),
    })
    # the page's own photo (another page's pick or upload does not change it), and what each panel shows now
    state = {"center": None, "photo": shown[0], "shown": explorer.shown_photo, "design": None, "panel": None}
    error = pn.pane.Alert("", alert_type="danger", visible=False, name="error")

    def controls():
        return explorer.controls_from({sl.key: w[sl.key].value for sl in sliders}, w["glass"].value)

    def photo_controls():
        sensor = None if w["sensor"].value == "(paper)" else w["sensor"].value
        fw = float(w["full_well"].value or 0.0)
        return PhotoControls(state["center"], int(w["iso"].value), int(w["seed"].value), sensor, w["cfa"].value,
                             w["demosaic"].value, w["restore"].value.strip(), fw if fw > 0 else None)

    def show_error(message):
        error.object = f"**error:** {message}"
        error.visible = True

    def guarded(fn, *a):
        """``fn(*a)``, or None with its one-line error shown on the page (the app keeps serving)."""
        try:
            out = fn(*a)
        except (ValueError, OSError) as exc:
            show_error(str(exc).splitlines()[0])
            return None
        error.visible = False
        return out

    # ---- long work off the event loop: what runs, and a Cancel button ------------------------------------------
    busy_md = pn.pane.Markdown("", name="busy", margin=(4, 10))
    cancel = pn.widgets.Button(label="Cancel", color="warning", visible=False, width=90)
    busy_panes = {}  # kind -> the panes its result goes to (shown as loading while it runs)

    def on_jobs():
        running = [JOB_LABELS[k] for k in JOB_LABELS if k in jobs.running]
        if running:
            busy_md.object = f"**computing:** {', '.join(running)} ..."
        elif jobs.cancelled:
            busy_md.object = f"cancelled: {', '.join(JOB_LABELS[k] for k in jobs.cancelled)} (what is shown is " \
                             "labelled with what made it)"
        else:
            busy_md.object = ""
        cancel.visible = bool(running)
        for kind, panes in busy_panes.items():
            for pane in panes:
                pane.loading = kind in jobs.running

    doc = pn.state.curdoc
    served = doc is not None and doc.session_context is not None
    jobs = PageJobs(doc.add_next_tick_callback if served else None, on_jobs)
    cancel.on_click(lambda e: jobs.cancel())
    if served:
        pn.state.on_session_destroyed(lambda ctx: jobs.close())

    def submit(kind, work, done, failed=show_error):
        """``work(cancel)`` off the loop, then ``done(result)`` (the error line hidden), or ``failed(message)``."""
        def ok(result):
            error.visible = False
            done(result)
        jobs.submit(kind, work, ok, failed)

    def stop_if(cancel_event):
        if cancel_event.is_set():
            raise Cancelled()

    # ---- design panel ------------------------------------------------------------------------------------------
    criteria_md = pn.pane.Markdown("", name="criteria")
    optics_png = pn.pane.PNG(None, name="optics", sizing_mode="stretch_width")
    busy_panes["design"] = (criteria_md, optics_png)
    from bokeh.models import ColorBar, ColumnDataSource, LabelSet, LinearColorMapper
    from bokeh.palettes import Viridis256

    xk, yk = explorer.map_axes
    (x0, x1), (y0, y1) = explorer.map_ranges()
    mapper = LinearColorMapper(palette=Viridis256, nan_color="lightgrey")
    map_fig = figure(width=600, height=440, tools="tap", toolbar_location=None, name="map",
                     x_range=(x0, x1), y_range=(y0, y1),  # the parameters' ranges from the start
                     x_axis_label=explorer.axis_label(xk), y_axis_label=explorer.axis_label(yk),
                     title="click to select a design; white: iso-cost curves (log10 C_a)")
    img_src = ColumnDataSource({"image": [np.full((1, 1), np.nan)], "x": [x0], "y": [y0], "dw": [x1 - x0],
                                "dh": [y1 - y0]})
    map_fig.image(image="image", x="x", y="y", dw="dw", dh="dh", source=img_src, color_mapper=mapper)
    color_bar = ColorBar(color_mapper=mapper, title="")
    map_fig.add_layout(color_bar, "right")
    points = explorer.named_points()
    named = ColumnDataSource({"x": [v[0] for v in points.values()], "y": [v[1] for v in points.values()],
                              "name": list(points)})
    map_fig.scatter("x", "y", source=named, size=9, fill_alpha=0, line_color="red", line_width=2)
    map_fig.add_layout(LabelSet(x="x", y="y", text="name", source=named, text_font_size="8pt", text_color="#b00000",
                                x_offset=5, y_offset=5, background_fill_color="white", background_fill_alpha=0.8,
                                name="design_labels"))  # readable on every colour of the map
    sx, sy = explorer.map_point(controls())
    sel_src = ColumnDataSource({"x": [sx], "y": [sy]}, name="selected")
    map_fig.scatter("x", "y", source=sel_src, marker="x", size=16, line_width=3, color="black")
    contours = {}

    def update_design(*_):
        c = controls()
        update_map()  # the marker moves at once

        def work(cancel_event):
            crit = explorer.criteria(c)
            stop_if(cancel_event)
            return crit, explorer.optics_figure(c)

        def done(result):
            crit, optics = result
            state["design"] = (c, crit, optics)
            criteria_md.object = f"**{explorer.design_label(c)}**\n\n| criterion | value |\n|---|---|\n" + "".join(
                f"| {k} | {v:.4g} |\n" for k, v in crit.items())
            optics_png.object = optics
            design_download.disabled = False

        def refused(message):
            show_error(message)
            state["design"] = None  # no figures of another design beside these sliders
            criteria_md.object = f"**{explorer.design_label(c)}**: no criteria (see the error above)"
            optics_png.object = None
            design_download.disabled = True
        submit("design", work, done, refused)

    map_status = pn.pane.Markdown("", name="map_status")

    def update_map(*_):
        px, py = explorer.map_point(controls())
        sel_src.data = {"x": [px], "y": [py]}
        layer = guarded(explorer.map_layer, w["criterion"].value, int(w["snr"].value))
        if layer is not None:
            q, sv, z = layer["x"], layer["y"], layer["z"]
            dq = (q[-1] - q[0]) / max(len(q) - 1, 1)
            ds = (sv[-1] - sv[0]) / (len(sv) - 1) if len(sv) > 1 else 1.0
            img_src.data = {"image": [z], "x": [q[0] - dq / 2], "y": [sv[0] - ds / 2], "dw": [q[-1] - q[0] + dq],
                            "dh": [sv[-1] - sv[0] + ds]}
            # the axes: the parameters' ranges, and the map's grid where a sweep reaches beyond them
            map_fig.x_range.start, map_fig.x_range.end = min(x0, float(np.min(q))), max(x1, float(np.max(q)))
            map_fig.y_range.start, map_fig.y_range.end = min(y0, float(np.min(sv))), max(y1, float(np.max(sv)))
            finite = z[np.isfinite(z)]
            if finite.size:
                mapper.low, mapper.high = float(finite.min()), float(finite.max())
            color_bar.title = ("log10 " if layer["log10"] else "") + w["criterion"].value
            lc = layer["log10_cost"]
            if ("cost" not in contours and lc is not None and min(lc.shape) > 1 and np.isfinite(lc).sum() > 3
                    and np.nanmax(lc) > np.nanmin(lc)):
                lo, hi = np.nanmin(lc), np.nanmax(lc)
                contours["cost"] = map_fig.contour(q, sv, np.nan_to_num(lc, nan=hi), levels=np.linspace(lo, hi, 8)[1:-1],
                                                   line_color="white", line_width=1)
        m = explorer.map_data
        done, total = explorer.map_progress
        map_status.object = (f"map: computing, {done} of {total or '?'} designs" if m is None else
                             f"map: {m[xk].size} x {m[yk].size} designs ({explorer.map_note()})")

    # ---- photo panel --------------------------------------------------------------------------------------------
    over = figure(width=OVERVIEW_PX, height=OVERVIEW_PX, x_range=(0, 1), y_range=(1, 0), tools="tap",
                  toolbar_location=None, name="overview", title="click to move the crop")
    over.axis.visible = False
    over.grid.visible = False
    over_src = ColumnDataSource({"image": [np.zeros((1, 1), np.uint32)], "x": [0], "y": [0], "dw": [1], "dh": [1]})
    over.image_rgba(image="image", x="x", y="y", dw="dw", dh="dh", source=over_src)  # the y axis runs down
    crop_rect = over.quad(left=[0], right=[1], top=[0], bottom=[1], fill_alpha=0, line_color="red", line_width=2)

    def draw_overview():
        """The page's photo's overview (at most :data:`OVERVIEW_PX` on its longer side) and its axes."""
        from pipeline.colour_space import linear_to_srgb

        H, W = state["shown"].shape[-2:]
        step = max(1, math.ceil(max(H, W) / OVERVIEW_PX))
        img = state["shown"].photo.load()[..., ::step, ::step]
        a = (linear_to_srgb(img.clamp(0, 1))[0].cpu().numpy() * 255).astype(np.uint8)
        a = np.repeat(a, 3, axis=0) if a.shape[0] == 1 else a
        rgba = np.dstack([a[0], a[1], a[2], np.full_like(a[0], 255)]).view(np.uint32)[..., 0]
        over.width, over.height = max(1, W // step), max(1, H // step)
        over.x_range.start, over.x_range.end = 0, W
        over.y_range.start, over.y_range.end = H, 0
        over_src.data = {"image": [rgba], "x": [0], "y": [0], "dw": [W], "dh": [H]}

    draw_overview()
    images = {k: pn.pane.PNG(None, name=k, width=256, height=256) for k in ("ideal", "sensor", "restored")}
    scores = {k: pn.pane.Markdown("", name=f"score_{k}") for k in ("sensor", "restored")}
    field_md = pn.pane.Markdown("", name="field")
    command = pn.pane.Markdown("", name="command")
    busy_panes["photo"] = tuple(images.values())

    def move_crop(box):
        crop_rect.data_source.data = {"left": [box[2]], "right": [box[3]], "top": [box[0]], "bottom": [box[1]]}

    def update_photo(*_):
        c, pc, shown_photo, name = controls(), photo_controls(), state["shown"], state["photo"]
        move_crop(explorer.crop_box(pc.center, shown_photo.shape))  # the rectangle moves at once

        def done(r):
            state["panel"] = (c, pc, shown_photo, r)
            move_crop(r["box"])
            for k, pane in images.items():
                pane.object = r["png"][k]
            for k, pane in scores.items():
                pane.object = f"**{k}**: PSNR {r['scores'][k]['psnr_db']:.2f} dB, SSIM {r['scores'][k]['ssim']:.3f}"
            field_md.object = f"crop {r['box']} at {r['field_deg']:.2f} deg of field ({explorer.design_label(c)})"
            named_photo = None if name == GENERATED else name
            command.object = "```\n" + command_line(named_photo, c, pc, explorer, shown_photo.shape) + "\n```"
            download.disabled = False
        submit("photo", lambda cancel_event: explorer.photo_panel(c, pc, photo=shown_photo, cancel=cancel_event),
               done)

    def show_photo(shown_photo, name):
        """Show ``shown_photo`` on this page (the crop back at the centre; the lab's pictures, of the previous photo,
        cleared)."""
        jobs.cancel("lab")
        state["center"], state["photo"], state["shown"] = None, name, shown_photo
        for k in lab_imgs:
            lab_imgs[k].object, lab_scores[k].object = None, ""
        lab_note.object = ""
        draw_overview()
        update_photo()

    def on_pick(event):
        name = event.new
        submit("open", lambda cancel_event: explorer.new_photo(*_open_photo(name)),
               lambda shown_photo: show_photo(shown_photo, name))

    w["photo"].param.watch(on_pick, "value")

    def on_tap(event):
        state["center"] = (int(event.y), int(event.x))
        update_photo()

    over.on_event(Tap, on_tap)

    def on_upload(event):
        from pathlib import PurePath

        data = w["upload"].value
        name = w["upload"].filename or ""
        shown_name = PurePath(name).name or "uploaded photo"
        submit("open", lambda cancel_event: explorer.new_photo(_read_upload(data, name, max_upload_mb),
                                                               "uploaded photo"),
               lambda shown_photo: show_photo(shown_photo, shown_name))

    w["upload"].param.watch(on_upload, "value")

    # ---- restoration lab --------------------------------------------------------------------------------------
    from pipeline.restoration import RESTORATION_METHODS

    def option_widget(method, key, default):
        """A control for one option of a restoration method, from its default's type (as wide as its column)."""
        kw = {"label": f"{key}", "sizing_mode": "stretch_width"}
        if isinstance(default, bool):
            return pn.widgets.Checkbox(value=default, **kw)
        if isinstance(default, int):
            return pn.widgets.IntInput(value=default, start=1, **kw)
        if isinstance(default, float):
            return pn.widgets.FloatInput(value=default, **kw)
        return pn.widgets.TextInput(value=str(default), **kw)

    def method_controls(tag, initial):
        """A method picker and its options as controls; ``spec()`` gives ``NAME:key=value,...``."""
        name, _, rest = initial.partition(":")
        given = dict(kv.split("=", 1) for kv in rest.split(",") if "=" in kv)
        pick = pn.widgets.Select(label=f"method {tag}", options=list(RESTORATION_METHODS), value=name,
                                 sizing_mode="stretch_width")
        box = pn.Column(sizing_mode="stretch_width", margin=0)
        controls_of = {}

        def rebuild(*_):
            m = RESTORATION_METHODS[pick.value]
            controls_of.clear()
            for k, default in m.options:
                wdg = option_widget(pick.value, k, default)
                if pick.value == name and k in given:
                    wdg.value = type(default)(given[k]) if not isinstance(default, bool) else given[k] == "True"
                controls_of[k] = wdg
            box.objects = list(controls_of.values())

        pick.param.watch(rebuild, "value")
        rebuild()

        def spec():
            m = RESTORATION_METHODS[pick.value]
            changed = [f"{k}={controls_of[k].value}" for k, default in m.options if controls_of[k].value != default]
            return pick.value + (":" + ",".join(changed) if changed else "")
        # a fixed width with its controls inside it: the two methods' boxes side by side, apart
        return pn.Column(pick, box, width=LAB_COLUMN_PX, margin=(5, 15, 5, 5), styles=LAB_BOX_STYLE), spec

    method_a_box, spec_a = method_controls("A", w["method_a"].value)
    method_b_box, spec_b = method_controls("B", w["method_b"].value)
    lab_imgs = {k: pn.pane.PNG(None, name=f"lab_{k}", width=256, height=256) for k in ("a", "b", "nominal", "own")}
    lab_scores = {k: pn.pane.Markdown("", name=f"lab_score_{k}") for k in lab_imgs}
    lab_button = pn.widgets.Button(label="run the restoration lab", color="primary", sizing_mode="stretch_width")
    lab_note = pn.pane.Markdown("", name="lab_note")
    busy_panes["lab"] = tuple(lab_imgs.values())

    def update_lab(*_):
        a, b = spec_a(), spec_b()
        c, pc, shown_photo = controls(), photo_controls(), state["shown"]
        grade, lens_seed = w["grade"].value, int(w["lens_seed"].value)

        def done(r):
            labels = {"a": a, "b": b, "nominal": "as built, nominal PSFs", "own": "as built, its own PSFs"}
            for k in lab_imgs:
                lab_imgs[k].object = r["png"][k]
                lab_scores[k].object = f"**{labels[k]}**: PSNR {r['scores'][k]['psnr_db']:.2f} dB, " \
                                       f"SSIM {r['scores'][k]['ssim']:.3f}"
            lab_note.object = f"{explorer.design_label(c)}; crop {explorer.crop_box(pc.center, shown_photo.shape)}; " \
                              f"grade {grade}, lens seed {lens_seed}"
        submit("lab", lambda cancel_event: explorer.restoration_lab(c, pc, a, b, grade, lens_seed, photo=shown_photo,
                                                                    cancel=cancel_event), done)

    lab_button.on_click(update_lab)

    # ---- export: what the panels show (computed already: nothing long runs here) ----------------------------------
    def _save(fig):
        return io.BytesIO(figure_png(fig, dpi=100))

    def panel_png():
        """The photo panel as a PNG: ideal, sensor and restored crops with their scores, what made them."""
        import matplotlib.image
        from matplotlib.figure import Figure

        if state["panel"] is None:
            raise ValueError("the photo panel is not computed yet")
        c, pc, shown_photo, r = state["panel"]
        fig = Figure(figsize=(9, 3.4), layout="constrained")
        for ax, k in zip(fig.subplots(1, 3), ("ideal", "sensor", "restored")):
            ax.imshow(matplotlib.image.imread(io.BytesIO(r["png"][k]), format="png"))
            sc = r["scores"].get(k)
            ax.set_title(k + ("" if sc is None else f": {sc['psnr_db']:.2f} dB, SSIM {sc['ssim']:.3f}"), fontsize=9)
            ax.set_axis_off()
        fig.suptitle(f"{shown_photo.source}, {explorer.design_label(c)}, ISO {pc.iso}, crop at {r['field_deg']:.2f} "
                     "deg", fontsize=9)
        return _save(fig)

    def design_png():
        """The design panel as a PNG: the criteria, the cost map with the design, the PSFs and MTFs."""
        import matplotlib.image
        from matplotlib.figure import Figure

        if state["design"] is None:
            raise ValueError("the design panel is not computed yet")
        c, crit, optics = state["design"]
        crit_img = matplotlib.image.imread(io.BytesIO(explorer.cost_map(w["criterion"].value, int(w["snr"].value), c)),
                                           format="png")
        fig = Figure(figsize=(12, 8.5), layout="constrained")
        top, bottom = fig.subfigures(2, 1, height_ratios=(1.25, 1))
        ax_t, ax_m = top.subplots(1, 2, width_ratios=(0.8, 1.2))
        ax_t.set_axis_off()
        ax_t.table(cellText=[[k, f"{v:.4g}"] for k, v in crit.items()], colLabels=["criterion", "value"],
                   loc="center").scale(1, 1.4)
        ax_m.imshow(crit_img)
        ax_m.set_axis_off()
        ax_o = bottom.subplots()
        ax_o.imshow(matplotlib.image.imread(io.BytesIO(optics), format="png"))
        ax_o.set_axis_off()
        fig.suptitle(explorer.design_label(c), fontsize=10)
        return _save(fig)

    download = pn.widgets.FileDownload(callback=panel_png, filename="lenssim_explore.png", label="download the panel "
                                       "as PNG", color="default", disabled=True)
    design_download = pn.widgets.FileDownload(callback=design_png, filename="lenssim_design.png",
                                              label="download the design panel as PNG", color="default", disabled=True)
    exports = [download]
    if explorer.prescription is not None:  # any lens: the design as a lens file, which the command line names
        from lenssim_studies.explore import LENS_EXPORT_FILE

        def lens_file():
            if state["panel"] is None:
                raise ValueError("the photo panel is not computed yet")
            return io.BytesIO(explorer.lens_toml(state["panel"][0]).encode())  # the design of the command shown
        exports.append(pn.widgets.FileDownload(callback=lens_file, filename=LENS_EXPORT_FILE,
                                               label=f"download the lens ({LENS_EXPORT_FILE})", color="default"))

    for sl in sliders:
        w[sl.key].param.watch(lambda e: (update_design(), update_photo()), "value_throttled")
    w["glass"].param.watch(lambda e: (update_design(), update_photo()), "value")
    for k in ("criterion", "snr"):
        w[k].param.watch(update_map, "value")
    for k in ("iso", "seed", "full_well", "sensor", "cfa", "demosaic", "restore"):
        w[k].param.watch(update_photo, "value")

    sidebar = pn.Column("### Design", *[w[sl.key] for sl in sliders], w["glass"], "### Camera",
                        w["iso"], w["full_well"], w["seed"], w["sensor"], w["cfa"], w["demosaic"], w["restore"],
                        "### Photo", w["photo"], w["upload"], width=300)

    def on_map_tap(event):
        for key, v in ((xk, event.x), (yk, event.y)):
            if key in w:  # (a lens with one free parameter has no vertical axis)
                sl = w[key]
                v = min(max(v, sl.start), sl.end)
                sl.value = round(sl.start + round((v - sl.start) / sl.step) * sl.step, 9)
        update_design()
        update_photo()

    map_fig.on_event(Tap, on_map_tap)
    design_tab = pn.Column(pn.Row(pn.Column(criteria_md, design_download),
                                  pn.Column(w["criterion"], w["snr"], map_status, pn.pane.Bokeh(map_fig))), optics_png,
                           name="Design")
    photo_tab = pn.Column(pn.Row(over, pn.Column(field_md, command, *exports)),
                          pn.Row(*[pn.Column(f"**{k}**", images[k], scores.get(k, "")) for k in images]),
                          name="Photo")
    lab_tab = pn.Column(pn.Row(method_a_box, method_b_box,
                               pn.Column(w["grade"], w["lens_seed"], lab_button, width=LAB_COLUMN_PX)),
                        lab_note, pn.Row(*[pn.Column(lab_imgs[k], lab_scores[k]) for k in lab_imgs]),
                        name="Restoration lab")
    app = pn.Row(sidebar, pn.Column(error, pn.Row(busy_md, cancel), pn.Tabs(design_tab, photo_tab, lab_tab)))
    if explorer.map_data is None:  # the map is being computed in the background: redrawn until it is there
        def poll():
            update_map()
            if explorer.map_data is not None and cb.running:
                cb.stop()
        cb = pn.state.add_periodic_callback(poll, period=MAP_POLL_MS, start=False)
        pn.state.onload(cb.start)
    app.widgets = w
    app.panes = {"criteria": criteria_md, "map": map_fig, "optics": optics_png, "images": images, "scores": scores,
                 "command": command, "overview": over, "error": error, "lab": lab_imgs, "field": field_md,
                 "busy": busy_md, "selected": sel_src, "design_labels": map_fig.select_one({"name": "design_labels"})}
    app.specs = {"a": spec_a, "b": spec_b}
    app.actions = {"tap": on_tap, "map_tap": on_map_tap, "update_design": update_design, "update_photo": update_photo,
                   "update_lab": update_lab, "upload": on_upload, "pick": on_pick, "panel_png": panel_png,
                   "design_png": design_png, "cancel": jobs.cancel}
    app.exports = exports
    app.jobs = jobs
    update_map()
    pn.state.onload(lambda: (update_design(), update_photo()))  # served: once the page is there, off the loop
    return app


def _slider_format(step: float) -> str:
    """The slider's number format (numbro): as many decimals as its step has, at least 2."""
    text = f"{step:.10f}".rstrip("0")
    decimals = len(text.split(".")[1]) if "." in text else 0
    return "0[.]" + "0" * min(max(decimals, 2), 10)


def _read_upload(data: bytes | None, filename: str, max_upload_mb: float):
    """An uploaded photo, checked as the command line checks a photo file: its extension one of
    :data:`UPLOAD_SUFFIXES`, at most ``max_upload_mb``, decoded from a file of the server's own naming in a private
    temporary folder (removed after), every pixel checked."""
    import os
    import tempfile
    from pathlib import PurePath

    from lenssim_studies.paper import PAPER_CAMERA
    from pipeline.photo import open_photo

    if not data:
        raise ValueError("the upload is empty")
    if len(data) > max_upload_mb * 1e6:
        raise ValueError(f"the upload is {len(data) / 1e6:.1f} MB: at most {max_upload_mb:g} MB (--max-upload-mb)")
    suffix = PurePath(filename).suffix.lower()
    if suffix not in UPLOAD_SUFFIXES:
        raise ValueError(f"the upload's type {suffix or '(none)'!r} is not allowed: {', '.join(UPLOAD_SUFFIXES)}")
    with tempfile.TemporaryDirectory(prefix="lenssim-upload-") as tmp:
        path = os.path.join(tmp, "upload" + suffix)  # the server's name; the user's is used for nothing else
        with open(path, "wb") as f:
            f.write(data)
        try:
            _check_photo_bytes(path, path)  # from the header, before decoding
            return open_photo(path, PAPER_CAMERA, keep_bytes=2**62).load()
        except (ValueError, OSError) as exc:  # said of the upload, not of the server's temporary file
            shown = PurePath(filename).name or "the upload"
            raise ValueError(str(exc).splitlines()[0].replace(repr(path), repr(shown)).replace(path, shown)) from None


# ---- who may connect ----------------------------------------------------------------------------------------------
LOOPBACK_HOSTS = ("localhost", "127.0.0.1", "::1")
"""This machine's own names: a server bound to one of them answers to all three (at its port)."""
WILDCARD_HOSTS = ("0.0.0.0", "::")
"""Addresses that bind every interface: the server answers to this machine's own names and its host name."""
MAX_REFUSALS_REPORTED = 32
"""Distinct refused Host or Origin values reported on stderr (each once), so that a hostile page cannot flood it."""


def _unbracket(name: str) -> str:
    return name[1:-1] if name.startswith("[") and name.endswith("]") else name


def _valid_name(name: str) -> bool:
    """A host name (letters, digits, hyphens between dots) or an IP address."""
    import ipaddress
    import re

    try:
        ipaddress.ip_address(name)
        return True
    except ValueError:
        return re.fullmatch(r"[a-z0-9]([a-z0-9-]*[a-z0-9])?(\.[a-z0-9]([a-z0-9-]*[a-z0-9])?)*\.?", name) is not None


def parse_allowed_origin(text: str) -> tuple[str, int | None]:
    """``--allow-origin``'s ``http[s]://NAME[:PORT]`` or ``NAME[:PORT]`` -> ``(name, port)`` (the name in lower case;
    port None: the explorer's own). An origin with a scheme and no port has its scheme's port (80, 443), as a browser
    sends it; a bare NAME is that name at the explorer's port. One-line ``ValueError`` for anything else (a path, a
    wildcard, a bad port)."""
    from urllib.parse import urlsplit

    bad = (f"--allow-origin {text!r} is not allowed: an origin, http://NAME:PORT or https://NAME[:PORT], or NAME[:PORT] "
           "(NAME at the explorer's port); no path, no wildcard")
    u = urlsplit(text if "://" in text else "//" + text)
    try:
        port = u.port
    except ValueError:
        raise ValueError(bad) from None
    name = (u.hostname or "").lower()
    if (u.scheme not in ("", "http", "https") or u.path not in ("", "/") or u.query or u.fragment or u.username
            or u.password is not None or not _valid_name(name) or port == 0):
        raise ValueError(bad)
    if port is None and u.scheme:
        port = 443 if u.scheme == "https" else 80
    return name, port


def allowed_addresses(host: str, port: int, origins=()) -> frozenset:
    """The ``(name, port)`` pairs a server bound to ``host``:``port`` answers to (its Host header) and accepts pages
    from (the Origin of a request, a WebSocket's above all): the name it was started for (all of
    :data:`LOOPBACK_HOSTS` for one of them; those and this machine's host name for a wildcard address) at its port,
    and ``origins`` (:func:`parse_allowed_origin`'s pairs; a port None is the server's)."""
    import socket

    name = _unbracket(host.lower())
    names = {name}
    if name in LOOPBACK_HOSTS:
        names |= set(LOOPBACK_HOSTS)
    if name in WILDCARD_HOSTS:
        names = set(LOOPBACK_HOSTS) | {socket.gethostname().lower()}
    return frozenset({(n, port) for n in names} | {(n, port if p is None else p) for n, p in origins})


def _address_of(text: str | None, default_port: int):
    """``(name, port)`` of a Host header's ``NAME[:PORT]`` (None when it is not one)."""
    from urllib.parse import urlsplit

    if not text or any(c in text for c in "/@?#\\ \t"):
        return None
    try:
        u = urlsplit("//" + text)
        port = u.port
    except ValueError:
        return None
    return (u.hostname or "").lower(), default_port if port is None else port


def refusal(host_header: str | None, origin_header: str | None, allowed) -> str | None:
    """Why a request with these headers is refused (None: it is accepted): its Host is not one of ``allowed``
    (:func:`allowed_addresses`: DNS rebinding), or it comes from a page (its Origin) of another address."""
    from urllib.parse import urlsplit

    if _address_of(host_header, 80) not in allowed:
        return f"Host {host_header!r}"
    if origin_header is not None:  # a browser's request from a page (every WebSocket handshake)
        u = urlsplit(origin_header)
        default = {"http": 80, "https": 443}.get(u.scheme)
        if default is None or u.path or _address_of(u.netloc, default) not in allowed:
            return f"Origin {origin_header!r}"
    return None


def lock_down(server, allowed, report=None) -> None:
    """Make ``server`` (Bokeh's, from ``pn.serve(..., start=False)``) answer 403 to every request that
    :func:`refusal` refuses, before any handler sees it (the page, its scripts, the WebSocket), and make Bokeh's own
    WebSocket origin list ``allowed``. ``report(line)``: told of each refused value once (at most
    :data:`MAX_REFUSALS_REPORTED`)."""
    from tornado.web import ErrorHandler

    app = server._tornado  # Bokeh's Tornado application (Bokeh 3: the server has no public name for it)
    origins = app.websocket_origins  # the live set Bokeh's WebSocket handler checks
    origins.clear()
    origins.update(f"[{n}]:{p}" if ":" in n else f"{n}:{p}" for n, p in allowed)
    find_handler = app.find_handler
    reported = set()

    def checked_find_handler(request, **kwargs):
        why = refusal(request.headers.get("Host"), request.headers.get("Origin"), allowed)
        if why is None:
            return find_handler(request, **kwargs)
        if report is not None and why not in reported and len(reported) < MAX_REFUSALS_REPORTED:
            reported.add(why)
            report(f"lenssim explore: refused a request from {why} (403): not an address this explorer was started "
                   "for; allow another with --allow-origin")
        return app.get_handler_delegate(request, ErrorHandler, {"status_code": 403})
    app.find_handler = checked_find_handler


def _print_now(line: str) -> None:
    print(line, flush=True)  # at once: a script reading the address (--port 0) waits for it


def serve(explorer, photo_arg, *, host: str, port: int, max_upload_mb: float, show_address=_print_now, photos=(),
          allow_origins=()):
    """Serve the app until interrupted; prints its address. Only requests for the address it was started for (and
    ``allow_origins``, :func:`parse_allowed_origin`'s pairs) are answered (:func:`lock_down`), on every port."""
    import panel as pn

    server = pn.serve(lambda: build_app(explorer, photo_arg, max_upload_mb=max_upload_mb, photos=photos),
                      address=host,
                      port=port,
                      show=False, start=False,
                      websocket_max_message_size=int(max_upload_mb * 1e6) + 2**20,
                      title="lenssim explore")
    lock_down(server, allowed_addresses(host, server.port, allow_origins),  # the port bound (also for --port 0)
              report=lambda line: print(line, file=sys.stderr, flush=True))
    server.start()
    shown = "127.0.0.1" if host in WILDCARD_HOSTS else f"[{host}]" if ":" in host else host
    show_address(f"lenssim explore: http://{shown}:{server.port}/ (Ctrl-C to stop)")
    try:
        server.io_loop.start()
    except KeyboardInterrupt:
        pass
    return 0
