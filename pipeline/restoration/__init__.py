"""Restoration methods, as a registry: name -> how it restores, its label, its options and its margin.

A method is ``fn(observed, psf, *, <what it uses>, **options) -> restored`` (linear ``(B, C, H, W)``): it
declares in its signature only the keyword arguments it uses, from ``noise`` (the sensor image's noise, a
:class:`pipeline.camera_chain.NoiseModel`: the camera chain's own description of it,
:meth:`pipeline.camera_chain.CameraChain.noise_model`, so no method keeps a second noise formula), ``scheme`` (the blur's windows), ``optical_center``, ``region`` (rows and columns that must be right) and
``progress``, and the dispatcher passes it just those (as colour-science's ``filter_kwargs``). Its
``options`` are its own settings with their defaults; ``margin(scheme)`` (or ``margin(scheme, options)`` where an
option changes it) says how far (px) beyond the ``region`` it reads the observed image (the windowed methods: half a
window and a core); ``memory`` what it holds
at its peak beyond the adaptive Wiener (:class:`WorkingMemory`: the whole frame's memory check plans with it).

Adding a method is one file in this package (``pipeline/restoration/NAME.py``) that calls :func:`register`:
every module here is imported when the package is (the paper's Wiener filter first). A method and its
options are written ``NAME[:key=value,...]`` on the command line (:func:`parse_restoration`) and given as a
:class:`Restoration` to :func:`pipeline.simulate_crops` and :func:`pipeline.simulate_frame`.
"""

from __future__ import annotations

import inspect
import math
from collections.abc import Callable
from dataclasses import dataclass, field

import torch

from lenssim.registry import Registry, import_plugins
from lenssim.validate import looks_numeric

from ..blur_operator import OPERATOR_OTF_BYTES
from ..camera_chain import NoiseModel

__all__ = ["RestorationMethod", "Restoration", "WorkingMemory", "OPERATOR_PADDED_COPIES", "RESTORATION_METHODS",
           "register", "validate_method", "restore", "parse_restoration", "COMMON_ARGUMENTS", "windowed_margin",
           "mean_noise_variance"]

COMMON_ARGUMENTS = ("noise", "scheme", "optical_center", "region", "progress")
"""What a restoration may ask for besides the image and the PSF provider."""


def mean_noise_variance(noise: NoiseModel, signal: torch.Tensor) -> torch.Tensor:
    """The noise variance of ``signal`` ``(..., H, W)`` averaged over its pixels, ``(..., 1, 1)``: ``noise.variance`` at
    the mean signal (the methods' one noise -> weight rule starts here). The photon and signal-independent terms are
    affine in the signal, so this is their mean exactly; the PRNU term's falls short by ``(prnu std)^2``, a fraction
    ``prnu^2`` of the signal's variance. Taken from noisy data the mean's own noise averages out (no clamping of noisy
    dark pixels at 0, which would bias a per-pixel mean upwards)."""
    return noise.variance(signal.mean(dim=(-2, -1), keepdim=True))


def windowed_margin(scheme) -> int:
    """Pixels a windowed method reads beyond its region: half a window and a blended core."""
    return scheme.window // 2 + scheme.core


OPERATOR_PADDED_COPIES = 9
"""Float32 buffers the size of the image padded by :func:`windowed_margin` each side that a pass of the blur's operator
(:class:`pipeline.blur_operator.BlurOperator`) holds at its peak: the adjoint's accumulator and its padding's transpose
(2) and the pedestal's box mean transposed (its running sums along each axis, up to 3 buffers the size of the region
and a box more). Measured when autograd transposed the box mean and the padding (its summed-area tables and their
gradients): Richardson-Lucy on a 2048 x 2048 colour frame (paper windows, the E2E design's pedestal; its OTFs made
again on every pass, its frame-sized buffers above glibc's mmap ceiling, so freed ones leave the resident set) held
841 MiB beyond the Wiener: its tents' sum (18 MiB), 3 image copies of its own
(:data:`pipeline.restoration.richardson_lucy.RL_MEMORY`) and 8.2 padded images; the transposes written out since
hold fewer (not measured again: the declaration stands as a bound)."""


@dataclass(frozen=True)
class WorkingMemory:
    """What a restoration holds at its peak beyond what the adaptive Wiener holds (the whole frame's memory plan,
    :func:`pipeline.simulate.frame_memory_bytes`, was measured with the Wiener, so the Wiener's own working buffers
    are in it already), in float32 buffers: ``copies`` the size of the image (an iterative method's estimate,
    residual, conjugate directions, duals; a float64 copy on the host counts two), ``padded`` the size of the image
    padded by :func:`windowed_margin` each side and, with ``operator`` (a method on the blur's operator), the
    operator's: :data:`OPERATOR_PADDED_COPIES` padded images and the window OTFs and their conjugates it keeps (at
    most :data:`~pipeline.blur_operator.OPERATOR_OTF_BYTES`, by its own rule). Each method's measured peaks are in
    the docstring of its ``*_MEMORY``."""

    copies: float = 0.0
    padded: float = 0.0
    operator: bool = False

    def __post_init__(self):
        for k in ("copies", "padded"):
            v = getattr(self, k)
            if isinstance(v, bool) or not (isinstance(v, (int, float)) and 0 <= v < math.inf):
                raise ValueError(f"{k}={v!r} is not allowed: a finite number >= 0")

    def bytes(self, shape, scheme) -> int:
        """Bytes for an image of ``shape`` ``(..., H, W)`` restored in the windows of ``scheme``."""
        m = windowed_margin(scheme)
        images, H, W = math.prod(int(v) for v in shape[:-2]), int(shape[-2]), int(shape[-1])
        padded = self.padded + (OPERATOR_PADDED_COPIES if self.operator else 0)
        floats = self.copies * images * H * W + padded * images * (H + 2 * m) * (W + 2 * m)
        return math.ceil(4 * floats) + (OPERATOR_OTF_BYTES if self.operator else 0)


@dataclass(frozen=True)
class RestorationMethod:
    """A restoration method (see the module docstring): ``fn``, a label for figures and tables, its options
    ``((name, default), ...)``, ``margin(scheme) -> px`` (or ``margin(scheme, options)``) and ``check(options,
    scheme)``, which raises ``ValueError`` for option values the method refuses (``scheme`` None: those it refuses in
    any window; called when a :class:`Restoration` is made and, with the windows, by :meth:`Restoration.check` before
    any work); ``memory``: its :class:`WorkingMemory`, or ``memory(options) -> WorkingMemory`` where an option changes
    it."""

    name: str
    label: str
    description: str
    fn: Callable
    options: tuple[tuple[str, object], ...] = ()
    margin: Callable = windowed_margin
    check: Callable | None = None
    memory: WorkingMemory | Callable = WorkingMemory()

    def __post_init__(self):
        params = inspect.signature(self.fn).parameters
        takes_any = any(p.kind is p.VAR_KEYWORD for p in params.values())
        for k, _ in self.options:
            if k not in params and not takes_any:
                raise ValueError(f"restoration method {self.name!r}: option {k!r} is not an argument of its function")
            if k in COMMON_ARGUMENTS:
                raise ValueError(f"restoration method {self.name!r}: option {k!r} is one of the common arguments")

    def accepts(self) -> tuple[str, ...]:
        """The common arguments the function declares (all of them if it takes ``**kwargs``)."""
        params = inspect.signature(self.fn).parameters
        if any(p.kind is p.VAR_KEYWORD for p in params.values()):
            return COMMON_ARGUMENTS
        return tuple(k for k in COMMON_ARGUMENTS if k in params)


RESTORATION_METHODS: Registry = Registry("restoration method")
"""The registry: name -> :class:`RestorationMethod` (filled by the modules of this package)."""

register = RESTORATION_METHODS.register
"""Add a :class:`RestorationMethod` to :data:`RESTORATION_METHODS` (a name may be registered once)."""

validate_method = RESTORATION_METHODS.validate
"""The registered method of a name; ``ValueError`` listing the valid names otherwise."""


@dataclass(frozen=True)
class Restoration:
    """A registered method with its options, checked: ``Restoration("tikhonov", {"weight": 1e-3})``; the key
    under which its images and scores are filed is its ``name``."""

    name: str
    options: dict = field(default_factory=dict)

    def __post_init__(self):
        m = validate_method(self.name)
        known = dict(m.options)
        bad = sorted(set(self.options) - set(known))
        if bad:
            raise ValueError(f"restoration method {self.name!r} takes no option(s) {bad}; it takes "
                             f"{', '.join(f'{k} (default {v!r})' for k, v in known.items()) or 'none'}")
        object.__setattr__(self, "options", {k: _typed(self.name, k, v, known[k]) for k, v in self.options.items()})
        self.check(None)

    @property
    def method(self) -> RestorationMethod:
        return RESTORATION_METHODS[self.name]

    def check(self, scheme) -> None:
        """``ValueError`` for options the method refuses with the window scheme ``scheme`` (None: with any)."""
        if self.method.check is not None:
            self.method.check({**dict(self.method.options), **self.options}, scheme)

    def margin(self, scheme) -> int:
        """What the method reads beyond its region (px) in the windows of ``scheme``, with these options."""
        margin = self.method.margin
        if len(inspect.signature(margin).parameters) > 1:  # margin(scheme, options): an option changes it
            return int(margin(scheme, {**dict(self.method.options), **self.options}))
        return int(margin(scheme))

    def memory_bytes(self, shape, scheme) -> int:
        """Bytes this restoration holds at its peak beyond the adaptive Wiener (:class:`WorkingMemory`) on an image of
        ``shape`` ``(..., H, W)`` in the windows of ``scheme``."""
        mem = self.method.memory
        mem = mem({**dict(self.method.options), **self.options}) if callable(mem) else mem
        return mem.bytes(shape, scheme)

    def to_dict(self) -> dict:
        return {"name": self.name, "options": {**dict(self.method.options), **self.options}}

    @classmethod
    def of(cls, spec) -> Restoration:
        """A :class:`Restoration` from itself, a name, or ``"NAME[:key=value,...]"``."""
        return spec if isinstance(spec, Restoration) else parse_restoration(spec)


def _typed(name: str, key: str, value, default):
    """``value`` (a string from the command line, or a Python value) as the type of the option's default."""
    want = type(default)
    if want is str and isinstance(value, str) and looks_numeric(value):
        return float(value)  # a number where the default is a word (tikhonov's weight: "noise" or a number)
    if isinstance(value, str) and want is not str:
        try:
            if want is bool:
                if value.lower() not in ("true", "false", "1", "0", "yes", "no"):
                    raise ValueError
                value = value.lower() in ("true", "1", "yes")
            else:
                value = want(float(value)) if want is int and float(value).is_integer() else want(value)
        except (TypeError, ValueError):
            raise ValueError(f"option {key}={value!r} of restoration method {name!r} is not allowed: "
                             f"{want.__name__} expected (default {default!r})") from None
    if want in (int, float) and (isinstance(value, bool) or not isinstance(value, (int, float))
                                 or not math.isfinite(value) or (want is int and value != int(value))):
        raise ValueError(f"option {key}={value!r} of restoration method {name!r} is not allowed: a finite "
                         f"{want.__name__} (default {default!r})")
    return want(value) if want in (int, float) else value


def parse_restoration(spec: str) -> Restoration:
    """``"NAME"`` or ``"NAME:key=value,key=value"`` -> a checked :class:`Restoration` (values take the type of the
    option's default).

    Examples
    --------
    >>> parse_restoration("richardson_lucy:iterations=30")
    Restoration(name='richardson_lucy', options={'iterations': 30})
    >>> parse_restoration("tikhonov").to_dict()
    {'name': 'tikhonov', 'options': {'weight': 'sure', 'strength': 1.0, 'order': 1}}
    """
    if not isinstance(spec, str) or not spec.strip():
        raise ValueError(f"restoration {spec!r} is not allowed: NAME or NAME:key=value,... with NAME one of "
                         f"{', '.join(RESTORATION_METHODS)}")
    name, _, rest = spec.partition(":")
    options = {}
    for item in filter(None, (x.strip() for x in rest.split(","))):
        key, eq, value = item.partition("=")
        if not eq or not key.strip():
            raise ValueError(f"restoration {spec!r}: option {item!r} is not key=value")
        options[key.strip()] = value.strip()
    return Restoration(name.strip(), options)


def restore(method, observed: torch.Tensor, psf, *, noise, options: dict | None = None, **common) -> torch.Tensor:
    """Restore ``observed`` ``(B, C, H, W)`` with ``method`` (a name, ``"NAME:key=value,..."`` or a
    :class:`Restoration`; ``options`` adds settings), passing the method only the common arguments it declares;
    ``noise``: the image's noise (:class:`pipeline.camera_chain.NoiseModel`)."""
    spec = Restoration.of(method)
    if options:
        spec = Restoration(spec.name, {**spec.options, **options})
    bad = set(common) - set(COMMON_ARGUMENTS)
    if bad:
        raise TypeError(f"restore() got unexpected argument(s) {sorted(bad)}")
    if not isinstance(noise, NoiseModel):
        raise ValueError(f"noise is a {type(noise).__name__}: expected a pipeline.camera_chain.NoiseModel (a camera "
                         "chain's noise_model(), or NoiseModel(electrons_per_unit) for photon noise alone)")
    given = {"noise": noise, **common}
    m = spec.method
    return m.fn(observed, psf, **{k: v for k, v in given.items() if k in m.accepts()}, **spec.options)


import_plugins(__name__, __path__, first=("wiener",))  # the paper's method first

from .richardson_lucy import RL_ITERATIONS, richardson_lucy_windowed  # noqa: E402 (re-exported)
from .wiener import wiener_windowed  # noqa: E402

__all__ += ["wiener_windowed", "richardson_lucy_windowed", "RL_ITERATIONS"]
