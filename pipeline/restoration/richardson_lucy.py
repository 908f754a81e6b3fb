"""Richardson-Lucy deconvolution in the blur's windows: the non-linear, train-free comparison.

References
----------
.. [1] W. H. Richardson, "Bayesian-based iterative method of image restoration", J. Opt. Soc. Am. 62(1),
   55-59 (1972); L. B. Lucy, "An iterative technique for the rectification of observed distributions",
   Astron. J. 79, 745 (1974).
"""

from __future__ import annotations

import torch

from lenssim import PSFProvider

from ..blur import PAPER_SCHEME, WindowScheme, apply_windowed
from ..checks import check_image
from . import RestorationMethod, register

__all__ = ["richardson_lucy_windowed", "RL_ITERATIONS", "MAX_RL_ITERATIONS"]

RL_ITERATIONS = 20
"""Default number of Richardson-Lucy iterations (named once: the function, the registry and the CLI)."""

MAX_RL_ITERATIONS = 1000
"""Most Richardson-Lucy iterations a run may ask for. Unregularised, the iteration fits the noise: on the paper's
noise levels its error is lowest after tens of iterations and rises after; 1000 is far past any useful count, and
bounds the work (two window-sized FFT convolutions per window and iteration: about an hour for one 256 px crop on
two CPU cores)."""


def richardson_lucy_windowed(observed: torch.Tensor, psf: PSFProvider, *, iterations: int = RL_ITERATIONS,
                             scheme: WindowScheme = PAPER_SCHEME, optical_center=None, region=None, chunk: int = 4,
                             progress=None, eps: float = 1e-12) -> torch.Tensor:
    """Richardson-Lucy deconvolution (the non-linear, train-free comparison) in the blur's windows.

    Per window, with the local PSF ``h`` (circular convolution over the window, as the blur)::

        u_{k+1} = u_k * ( h~ conv ( y / (h conv u_k) ) ),   u_0 = 0.5,   h~ the mirrored PSF

    the same iteration as ``skimage.restoration.richardson_lucy`` (which the tests compare against).
    Non-negative input required; no regularisation (stop early with ``iterations``).
    """
    check_image(observed, "observed")
    if isinstance(iterations, bool) or not (isinstance(iterations, int) and 1 <= iterations <= MAX_RL_ITERATIONS):
        raise ValueError(f"iterations={iterations!r} is not allowed: an integer from 1 to {MAX_RL_ITERATIONS}")
    if (observed < 0).any():
        raise ValueError("observed image has negative values: Richardson-Lucy needs y >= 0")
    def rl(patches, otf):
        H = otf
        win = patches.shape[-1]  # the scheme's window, or larger where the PSF outgrows it
        conv = lambda x, F: torch.fft.irfft2(torch.fft.rfft2(x) * F, s=(win, win))  # noqa: E731
        Hc = H.conj().resolve_conj()  # once: a conj view is resolved again by every product
        u = torch.full_like(patches, 0.5)  # scikit-image's starting point
        for _ in range(iterations):
            ratio = patches / conv(u, H).clamp_min(eps)
            u = u * conv(ratio, Hc)
        return u

    return apply_windowed(observed, psf, rl, scheme=scheme, optical_center=optical_center, region=region,
                          chunk=chunk, progress=progress)


def _check(options, scheme):
    it = options["iterations"]
    if isinstance(it, bool) or not (isinstance(it, int) and 1 <= it <= MAX_RL_ITERATIONS):
        raise ValueError(f"richardson_lucy option iterations={it!r} is not allowed: an integer from 1 to "
                         f"{MAX_RL_ITERATIONS}")


def _richardson_lucy(observed, psf, *, scheme, optical_center=None, region=None, progress=None,
                     iterations=RL_ITERATIONS):
    # the noise level does not enter the (unregularised) iteration, which needs a non-negative input
    return richardson_lucy_windowed(observed.clamp_min(0), psf, iterations=iterations, scheme=scheme,
                                    optical_center=optical_center, region=region, progress=progress)


register(RestorationMethod(
    "richardson_lucy", "Richardson-Lucy", "windowed Richardson-Lucy deconvolution (non-linear, no regularisation)",
    _richardson_lucy, (("iterations", RL_ITERATIONS),), check=_check))
