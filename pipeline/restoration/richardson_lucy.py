"""Richardson-Lucy deconvolution on the spatially varying blur: the non-linear, train-free comparison.

The iteration runs on the blur's own operator (:class:`pipeline.blur_operator.BlurOperator`: the windows, PSFs and
blending that made the image), over the region asked for and ``context`` px around it (the data), the estimate ``u``
reaching as far beyond as the windows read (the light that falls into the data from outside it)::

    u_{k+1} = u_k * A^T(y / A u_k) / A^T 1,        u_0 = mean(y) (flat)

the spatially varying form of [1]_ with unknown boundaries (the normaliser ``A^T 1`` counts the part of each pixel's
light that lands in the data, so pixels near the data's edge are neither forced to match a padding nor darkened).
Batched over the images of ``y``; on its device and in its dtype.

References
----------
.. [1] W. H. Richardson, "Bayesian-based iterative method of image restoration", J. Opt. Soc. Am. 62(1),
   55-59 (1972); L. B. Lucy, "An iterative technique for the rectification of observed distributions",
   Astron. J. 79, 745 (1974).
.. [2] M. Bertero, P. Boccacci, "A simple method for the reduction of boundary effects in the Richardson-Lucy
   approach to image deconvolution", Astron. Astrophys. 437, 369-374 (2005).
"""

from __future__ import annotations

import torch

from lenssim import PSFProvider

from ..blur import PAPER_SCHEME, WindowScheme
from ..blur_operator import RegionProblem
from ..checks import check_image
from . import RestorationMethod, WorkingMemory, register, windowed_margin

__all__ = ["richardson_lucy_windowed", "RL_ITERATIONS", "MAX_RL_ITERATIONS", "RL_CONTEXT_PX", "RL_MEMORY"]

RL_ITERATIONS = 8
"""Default number of Richardson-Lucy iterations (named once: the function, the registry and the CLI). Unregularised,
the iteration fits the noise after a while; sRGB PSNR (dB) measured per iteration on 256 px crops of the photos (the
paper's sensor, flat start): forest 5 deg, E2E design, no context: ISO 400 peaks at 4 iterations (38.91; 8: 38.34,
10: 37.85), ISO 100 at 9 (39.77; 8: 39.76); with 32 px of context: RMS_W design, ISO 400 peaks at 7 (38.61; 10: 38.50,
20: 37.30), ISO 100 at 16 (39.41; 8: 39.13); pier 10 deg, E2E, still rising at 15 (ISO 400 32.83, ISO 100 33.12; 8:
32.34, 32.40). Eight stays within 0.6 dB of each crop's best where it is reached, in 0.4x the former 20's iterations."""

MAX_RL_ITERATIONS = 1000
"""Most Richardson-Lucy iterations a run may ask for. Unregularised, the iteration fits the noise: on the paper's
noise levels its error is lowest after a few to tens of iterations and rises after; 1000 is far past any useful count,
and bounds the work (a forward and an adjoint pass of the blur's operator per iteration, 0.15-0.2 s for a 256 px crop
on two quiet CPU cores: a few minutes for 1000)."""

RL_CONTEXT_PX = 0
"""Observed pixels (px) around the region that the iteration fits as data besides the region's own. None by default:
with unknown boundaries the region's own data suffices (forest 5 deg, E2E, 10 iterations: 32 px of context gained
0.34 dB at ISO 400 and 0.10 dB at ISO 100, for 1.4x the windows and time; 8 iterations without context scored as 10
with it)."""

RL_MEMORY = WorkingMemory(copies=4, operator=True)
"""What the iteration holds beyond the adaptive Wiener (:class:`pipeline.restoration.WorkingMemory`), on a whole frame
the image itself (no tiles: the region is the frame): the normaliser ``A^T 1`` and its mask, the estimate, the ratio
``y / A u`` and the update's temporaries (image-sized), and the operator's (its passes' padded buffers and kept OTFs).
Measured beyond the Wiener's peak, less the kept OTFs, in a fresh process per method (the peak resident set; colour
frames, a Gaussian PSF without a pedestal, windows 64/16/32, glibc's mmap threshold fixed so that freed buffers leave
the resident set as a large frame's do): 4.1 MiB at 256 px, 14.0 MiB at 512 px, i.e. 2.9 image and 1.2 padded copies
(the operator's accumulators); declared 4 image copies. With a pedestal (0.02) the 512 px frame held 26.5 MiB; on the
whole-frame command, see :data:`pipeline.restoration.OPERATOR_PADDED_COPIES`."""

RL_SUPPORT_FLOOR = 1e-3
"""Pixels whose ``A^T 1`` is below this (less than 0.1% of their light lands in the data) keep their starting value:
the data says next to nothing of them, and their update would divide noise by a number near zero."""


def richardson_lucy_windowed(observed: torch.Tensor, psf: PSFProvider, *, iterations: int = RL_ITERATIONS,
                             scheme: WindowScheme = PAPER_SCHEME, optical_center=None, region=None,
                             context: int = RL_CONTEXT_PX, progress=None, eps: float = 1e-12) -> torch.Tensor:
    """Richardson-Lucy deconvolution of ``observed`` ``(B, C, H, W)`` (non-negative, linear) on the windowed blur of
    ``psf`` (module docstring): ``region = (r0, r1, c0, c1)`` the pixels restored (zeros elsewhere; default all),
    fitted with the observed pixels up to ``context`` px around it; the image is read up to ``context`` px plus
    half the largest window and a core beyond the region. No regularisation: stop early with ``iterations``.
    ``progress(k)`` is called after each iteration with its share of the region's windows."""
    check_image(observed, "observed")
    if isinstance(iterations, bool) or not (isinstance(iterations, int) and 1 <= iterations <= MAX_RL_ITERATIONS):
        raise ValueError(f"iterations={iterations!r} is not allowed: an integer from 1 to {MAX_RL_ITERATIONS}")
    if isinstance(context, bool) or not (isinstance(context, int) and context >= 0):
        raise ValueError(f"context={context!r} is not allowed: an integer >= 0 (px)")
    if (observed < 0).any():
        raise ValueError("observed image has negative values: Richardson-Lucy needs y >= 0")
    # the estimate: the data and what its windows read (RegionProblem)
    problem = RegionProblem(observed, psf, scheme=scheme, optical_center=optical_center, region=region, context=context)
    y, A = problem.y, problem.A
    norm = A.ones_adjoint(y)
    live = norm > RL_SUPPORT_FLOOR
    norm = norm.clamp_min(RL_SUPPORT_FLOOR)
    r = A.region  # the start: each image's and channel's mean over the data, flat (the iteration sharpens from it)
    u = y[..., r[0]:r[1], r[2]:r[3]].mean(dim=(-2, -1), keepdim=True).clamp_min(eps).expand_as(y).clone()
    tick = problem.ticks(iterations, progress)
    for k in range(iterations):
        ratio = y / A.forward(u).clamp_min(eps)
        u = torch.where(live, u * A.adjoint(ratio).clamp_min(0) / norm, u)
        tick(k)
    return problem.place(u, observed)


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
    "richardson_lucy", "Richardson-Lucy", "Richardson-Lucy deconvolution on the windowed blur's operator (non-linear, "
    "no regularisation)", _richardson_lucy, (("iterations", RL_ITERATIONS),),
    margin=lambda scheme: windowed_margin(scheme) + RL_CONTEXT_PX, check=_check, memory=RL_MEMORY))
