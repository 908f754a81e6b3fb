"""Checks shared by every layer: numbers in their allowed ranges, finite tensors, resource limits.

Rules (README, "Errors and limits"): every result that is printed or written is finite and means
what its label says, or the computation stops with a ``ValueError`` naming the input and what is
allowed; values that are legal but outside where the model was validated raise a
:class:`ModelValidityWarning`; work that would not fit this machine is refused up front with a
:class:`ResourceLimitError` naming the limit and the setting that overrides it.
"""

from __future__ import annotations

import math
import os
import warnings

import torch

from .torch_utils import HOST

__all__ = ["ResourceLimitError", "NumericalError", "ModelValidityWarning", "ResumeWarning", "check_real", "check_int", "check_finite",
           "available_memory_bytes", "check_memory", "warn_model", "SNR_DB_RANGE", "SNR_DB_VALIDATED",
           "FULL_WELL_RANGE_E", "MEMORY_FRACTION", "MAX_SEED", "check_snr_db", "check_pixel_pitch_um",
           "PIXEL_PITCH_RANGE_UM", "check_max_fft_size", "OTF_BYTES_PER_SAMPLE", "check_distinct", "MAX_NAMES_LISTED",
           "MAX_QUOTED_CHARS", "quoted", "listed", "looks_numeric"]

SNR_DB_RANGE = (-20.0, 100.0)
"""SNR (dB per pixel) accepted by the criteria: beyond 100 dB the noise variance (1e-10) is below the
float32 OTFs' resolution and MSE_R stops meaning what it says."""

SNR_DB_VALIDATED = (10.0, 50.0)
"""SNRs where the numerics' convergence was checked (around the paper's 21.6-33.6 dB); outside: a warning."""

FULL_WELL_RANGE_E = (1.0, 1e9)
"""Full-well capacities (electrons) accepted by the noise model (real sensors: 1e3-1e5)."""

MEMORY_FRACTION = 0.8
"""Share of the available memory one run may plan to use."""

PIXEL_PITCH_RANGE_UM = (0.1, 1000.0)
"""Pixel pitches (um) a sensor may have: 0.1 um is a fifth of the smallest pixel made (0.56 um) and below the
diffraction limit of any lens in visible light (a PSF there spans thousands of pixels); 1 mm is twenty times the
largest sensor pixel and above the pitch that maps a photo of a hundred pixels onto a lens's field. Each lens
narrows this further (its PSFs must fit the FFT limit: checked where the lens is known)."""

OTF_BYTES_PER_SAMPLE = 24
"""Bytes per sample of a PSF's OTF on an ``N x N`` FFT grid as the criteria hold it (six float64 half planes:
:func:`lenssim.optics.psf_bank.choose_fft_size` estimates ``24 N^2`` bytes)."""

MAX_SEED = 2**62
"""Largest random seed a run takes: torch's generators take seeds below 2**64, and runs add offsets to the seed
(one per crop or lens chunk), so a margin is left below that."""


MAX_NAMES_LISTED = 5
"""Names one message lists (unknown keys or sections, the allowed ones, ...): the first few and how many more, so
that a file of a million unknown keys is refused in one short line."""

MAX_QUOTED_CHARS = 40
"""Characters of one name or value from the user's input that a message quotes: a longer one (a key of a megabyte)
shows its start, ``...`` and its length."""


def quoted(value, *, limit: int = MAX_QUOTED_CHARS) -> str:
    """``repr(value)`` for a message, of at most ``limit`` characters (of a string) or ``limit`` characters of its
    ``repr`` (anything else): a longer one is cut, with its length, e.g.
    ``'aaaaaaaa...' (5000 characters)``. Control characters and quotes are escaped (``repr``), so the message
    stays on one line."""
    if isinstance(value, str):
        return repr(value) if len(value) <= limit else f"{value[:limit]!r}... ({len(value)} characters)"
    text = repr(value)
    return text if len(text) <= limit else f"{text[:limit]}... ({len(text)} characters)"


def listed(names, *, limit: int = MAX_NAMES_LISTED, near=(), quote: bool = False) -> str:
    """Names for a message, e.g. ``a, b, c, d, e and 1995 more``: at most ``limit`` of them, each at most
    :data:`MAX_QUOTED_CHARS` long (``quote``: as :func:`quoted` writes them, else bare unless too long). The names
    closest to the first few of ``near`` (the unknown ones a user gave, say) come first, so that a list of the
    allowed names cut short still shows what was meant."""
    import difflib

    names = [str(n) for n in names]
    if near:
        close = []
        for n in list(near)[:limit]:
            close += [c for c in difflib.get_close_matches(str(n)[:MAX_QUOTED_CHARS], names, n=2) if c not in close]
        names = close + [n for n in names if n not in close]

    def one(n):
        return quoted(n) if quote or len(n) > MAX_QUOTED_CHARS else n

    shown = ", ".join(one(n) for n in names[:limit]) or "none"
    return shown + (f" and {len(names) - limit} more" if len(names) > limit else "")


class ResourceLimitError(ValueError):
    """Work refused before it starts because it would exceed a limit; ``setting`` names the override."""

    def __init__(self, message: str, setting: str):
        super().__init__(message)
        self.setting = setting


class NumericalError(ValueError):
    """A result that is not a finite number (it is never printed or written)."""


class ResumeWarning(UserWarning):
    """A resumable piece (a sweep chunk, a checkpoint) failed its check and is computed again."""


class ModelValidityWarning(UserWarning):
    """A legal input outside the range where the model or its numerics were validated."""


def warn_model(message: str) -> None:
    warnings.warn(message, ModelValidityWarning, stacklevel=3)


def check_real(name: str, value, lo: float | None = None, hi: float | None = None, *, lo_open: bool = False,
               hi_open: bool = False, unit: str = "") -> float:
    """``value`` as a finite float in ``[lo, hi]`` (open ends as asked); ``ValueError`` naming it otherwise."""
    u = f" {unit}" if unit else ""
    lo_s = "" if lo is None else f"{'>' if lo_open else '>='} {lo:g}{u}"
    hi_s = "" if hi is None else f"{'<' if hi_open else '<='} {hi:g}{u}"
    allowed = "a finite number" + (f" {lo_s}" if lo_s else "") + (" and" if lo_s and hi_s else "") + (f" {hi_s}" if hi_s else "")
    if isinstance(value, bool) or isinstance(value, torch.Tensor) and value.numel() != 1:
        raise ValueError(f"{name}={value!r} is not allowed: {allowed}")
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name}={value!r} is not allowed: {allowed}") from None
    ok = math.isfinite(v)
    if ok and lo is not None:
        ok = v > lo if lo_open else v >= lo
    if ok and hi is not None:
        ok = v < hi if hi_open else v <= hi
    if not ok:
        raise ValueError(f"{name}={value!r} is not allowed: {allowed}")
    return v


def check_snr_db(values, name: str = "", *, warn: bool = True) -> tuple[float, ...]:
    """SNRs (dB per pixel) as a tuple of floats, at least one, each finite and within :data:`SNR_DB_RANGE`; a
    :class:`ModelValidityWarning` (``warn``) for any outside :data:`SNR_DB_VALIDATED`. The one rule of every SNR: the
    criteria's noise model (:func:`lenssim.optics.image_model.noise_variance`) and every command's ``--snr`` (``name``,
    e.g. ``"--snr"``, prefixes the message)."""
    lead = f"{name}: " if name else ""
    try:
        snr = torch.as_tensor(values, dtype=torch.float64, device=HOST).reshape(-1)
    except (TypeError, ValueError, RuntimeError):
        raise ValueError(f"{lead}SNR {values!r} is not allowed: numbers in dB") from None
    lo, hi = SNR_DB_RANGE
    shown = ", ".join(f"{v:g}" for v in snr.tolist())
    if snr.numel() == 0 or not torch.isfinite(snr).all() or bool((snr < lo).any()) or bool((snr > hi).any()):
        raise ValueError(f"{lead}SNR [{shown}] dB is not allowed: finite values in [{lo:g}, {hi:g}] dB (beyond {hi:g} "
                         "dB the noise is below the float32 OTFs' resolution)")
    vlo, vhi = SNR_DB_VALIDATED
    if warn and (bool((snr < vlo).any()) or bool((snr > vhi).any())):
        warnings.warn(f"SNR [{shown}] dB is outside [{vlo:g}, {vhi:g}] dB, where the criteria's numerics were "
                      "validated", ModelValidityWarning, stacklevel=3)
    return tuple(snr.tolist())


def check_pixel_pitch_um(value, name: str = "pixel_pitch_um") -> float:
    """A pixel pitch (um) within :data:`PIXEL_PITCH_RANGE_UM`; ``ValueError`` naming ``name`` otherwise (the one rule
    of every ``--pixel-pitch``)."""
    lo, hi = PIXEL_PITCH_RANGE_UM
    number = isinstance(value, (int, float)) and not isinstance(value, bool)
    if not number or not (math.isfinite(value) and lo <= value <= hi):
        raise ValueError(f"{name} {f'{value:g}' if number else repr(value)} is not allowed: a pixel pitch from "
                         f"{lo:g} to {hi:g} um")
    return float(value)


def check_max_fft_size(value, name: str = "max_fft_size") -> int:
    """A limit on the FFT size of a PSF: a whole number >= 16 whose one OTF (:data:`OTF_BYTES_PER_SAMPLE` per sample)
    fits the memory (:func:`check_memory`); a larger limit would let a design ask for more than the machine has."""
    if isinstance(value, bool) or not isinstance(value, int) or value < 16:
        raise ValueError(f"{name} {value!r} is not allowed: an FFT size >= 16")
    n = value
    limit = MEMORY_FRACTION * available_memory_bytes()
    if OTF_BYTES_PER_SAMPLE * float(n) ** 2 > limit:
        most = int(math.sqrt(limit / OTF_BYTES_PER_SAMPLE))
        raise ValueError(f"{name} {n} is not allowed: one OTF of {n} x {n} samples would need "
                         f"{OTF_BYTES_PER_SAMPLE * n ** 2 / 2**30:.3g} GiB, more than this machine's "
                         f"{limit / 2**30:.3g} GiB; at most {most}")
    return n


def check_distinct(name: str, values, *, as_written: bool = False) -> None:
    """``ValueError`` if ``values`` holds a number twice (``as_written``: twice as ``%g`` writes it, the form of the
    tables and file names; -0 is 0); ``name`` names the flag."""
    keys = [f"{float(v) + 0.0:g}" if as_written else float(v) + 0.0 for v in values]
    dup = sorted({k for k in keys if keys.count(k) > 1}, key=keys.index)
    if dup:
        raise ValueError(f"{name} holds {', '.join(f'{float(k):g}' for k in dup)} more than once; give each value "
                         "once")


def check_int(name: str, value, lo: int | None = None, hi: int | None = None) -> int:
    """``value`` as an int in ``[lo, hi]``; ``ValueError`` naming it otherwise."""
    allowed = "a whole number" + (f" >= {lo}" if lo is not None else "") + (f" <= {hi}" if hi is not None else "")
    if isinstance(value, bool) or not isinstance(value, int) and not (isinstance(value, float) and value.is_integer()):
        raise ValueError(f"{name}={value!r} is not allowed: {allowed}")
    v = int(value)
    if (lo is not None and v < lo) or (hi is not None and v > hi):
        raise ValueError(f"{name}={value!r} is not allowed: {allowed}")
    return v


def check_finite(name: str, t: torch.Tensor, what: str = "values") -> torch.Tensor:
    """``t`` itself if every element is finite; ``ValueError`` naming ``name`` and the first bad element otherwise.

    A finite sum (one fast read of ``t``) proves every element finite: a NaN or an infinity makes any IEEE sum
    non-finite. Only otherwise are the elements tested one by one (a sum that merely overflowed is then cleared).
    """
    if t.is_floating_point() or t.is_complex():
        if bool(torch.isfinite(t.sum()).all()):
            return t
        bad = ~torch.isfinite(t)
        if bool(bad.any()):
            idx = tuple(int(i) for i in torch.nonzero(bad)[0])
            raise ValueError(f"{name} holds NaN or infinite {what} (first at index {idx}: {t[idx].item()!r}); "
                             "expected finite numbers")
    return t


def available_memory_bytes() -> int:
    """Memory available to this process (bytes): /proc/meminfo's MemAvailable, else the physical memory."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        return 1 << 62


def check_memory(nbytes: float, what: str, limit_bytes: float | None = None, setting: str = "memory_limit_gib") -> None:
    """Refuse ``what`` (needing about ``nbytes``) if it exceeds ``limit_bytes`` (default: a share of the
    available memory), with a :class:`ResourceLimitError` naming the limit and ``setting``."""
    limit = MEMORY_FRACTION * available_memory_bytes() if limit_bytes is None else limit_bytes
    if nbytes > limit:
        raise ResourceLimitError(f"{what} needs about {nbytes / 2**30:.3g} GiB of memory; the limit is "
                                 f"{limit / 2**30:.3g} GiB ({setting})", setting)


def looks_numeric(text: str) -> bool:
    """Whether ``text`` reads as a number (``float(text)`` succeeds: ``"1e-3"``, ``"nan"``, ``"inf"`` do)."""
    try:
        float(text)
    except ValueError:
        return False
    return True
