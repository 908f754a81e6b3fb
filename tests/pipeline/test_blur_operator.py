"""The windowed blur as a linear operator (issue 45): its forward is blur_windowed, its adjoint the exact transpose
(``<A x, y> = <x, A^T y>``, and autograd's vector-Jacobian product of blur_windowed), on every device and dtype."""

import pytest
import torch

from lenssim import FunctionPSF, LensPSF
from lenssim_studies.paper import PAPER_CAMERA, PAPER_DESIGNS
from pipeline.blur import WindowScheme, _pad, blur_windowed
from pipeline.blur_operator import BlurOperator, _pad_transpose

GEOM = PAPER_CAMERA.geometry


def _field(x_mm, y_mm, n):
    """A Gaussian PSF whose widths grow with the field and whose centre sits 1.5 px off the grid (not mirror
    symmetric), ``(P, n, n)``, unit sum."""
    x = torch.as_tensor(x_mm, dtype=torch.float64) / GEOM.pitch_mm
    y = torch.as_tensor(y_mm, dtype=torch.float64) / GEOM.pitch_mm
    sx, sy = 1.0 + 0.004 * x.abs(), 1.5 + 0.002 * (x + y).abs()
    r = torch.arange(n, dtype=torch.float64) - n // 2
    g = torch.exp(-0.5 * ((r[None, None, :] - 1.5) / sx[:, None, None]) ** 2
                  - 0.5 * (r[None, :, None] / sy[:, None, None]) ** 2)
    return g / g.sum(dim=(-2, -1), keepdim=True)


FIELD = FunctionPSF(_field, GEOM, extent=21)
SCHEMES = (WindowScheme(128, 16, 32),  # 128 px windows, reflect padding
           WindowScheme(512, 32, 64))  # fitted 256 px windows (PSFs folded from 512 px), replicate padding


def _pair(shape, dtype, device, seed=0):
    g = torch.Generator().manual_seed(seed)
    return (torch.rand(shape, generator=g, dtype=torch.float64).to(dtype=dtype, device=device),
            torch.rand(shape, generator=g, dtype=torch.float64).to(dtype=dtype, device=device))


def _dot_error(A, x, y) -> float:
    lhs = float((A.forward(x).double() * y.double()).sum())
    rhs = float((x.double() * A.adjoint(y).double()).sum())
    return abs(lhs - rhs) / abs(lhs)


@pytest.mark.parametrize("scheme", SCHEMES, ids=["128", "512fit"])
@pytest.mark.parametrize("region", [None, (10, 50, 5, 77)], ids=["whole", "region"])
def test_forward_is_the_blur_and_adjoint_its_transpose(device_dtype, scheme, region):
    device, dtype = device_dtype
    x, y = _pair((2, 3, 70, 90), dtype, device)
    oc = (30.3, 170.0)  # off the image's centre, between pixels along the rows
    A = BlurOperator(FIELD, x.shape, scheme=scheme, optical_center=oc, region=region)
    Ax = A.forward(x)
    assert Ax.dtype == dtype and Ax.device.type == device.type
    torch.testing.assert_close(Ax, blur_windowed(x, FIELD, scheme=scheme, optical_center=oc, region=region),
                               rtol=0, atol=0)
    if scheme.window == 512:
        assert set(A.plan.sizes.tolist()) == {256}  # the fitted windows, the PSFs folded onto them
    Aty = A.adjoint(y)
    assert Aty.dtype == dtype and Aty.device.type == device.type
    assert _dot_error(A, x, y) < (1e-12 if dtype == torch.float64 else 1e-5)
    if region is not None:  # only the region of y is read
        y2 = y.clone()
        y2[..., :10, :] = 7.0
        torch.testing.assert_close(A.adjoint(y2), Aty, rtol=0, atol=0)
    # batched: each image of the batch on its own
    torch.testing.assert_close(A.adjoint(y[1:]), Aty[1:], rtol=1e-12 if dtype == torch.float64 else 1e-5,
                               atol=1e-12 if dtype == torch.float64 else 1e-5)


# the windows' reflect padding and the box mean's (half the scheme's window) by: both repeating the edge (the image
# not larger than either), reflection and repetition (folded apart), both reflection (folded together)
LENS_CASES = {"repeat": ((60, 72), WindowScheme(128, 16, 32), (700.0, 900.5), 152, (False, False)),
              "mixed": ((50, 60), WindowScheme(64, 16, 32), (30.0, 40.5), 64, (False, True)),
              "reflect": ((70, 80), WindowScheme(64, 16, 32), (30.0, 40.5), 64, (True, True))}


@pytest.mark.parametrize("case", list(LENS_CASES))
def test_the_lens_operator_adjoint_is_autograds_transpose_of_the_blur(case):
    """The paper's lens (mirror groups sharing PSFs, a uniform pedestal convolved as a box mean) off the frame's
    centre: the adjoint against the vector-Jacobian product of blur_windowed itself, and the dot test."""
    size, scheme, oc, pad, reflects = LENS_CASES[case]
    psf = LensPSF(PAPER_CAMERA, PAPER_DESIGNS["end_to_end_paper"])
    assert psf.pedestal_fractions(scheme.window)[0] > 0 and psf.mirror_symmetric
    x, y = _pair((1, 3) + size, torch.float64, "cpu", seed=1)
    region = (4, size[0] - 4, 8, size[1] - 12)
    A = BlurOperator(psf, x.shape, scheme=scheme, optical_center=oc, region=region)
    assert A.plan.pad == pad and (pad < min(size), scheme.window // 2 < min(size)) == reflects
    assert _dot_error(A, x, y) < 1e-12
    xr = x.clone().requires_grad_(True)
    ref = torch.autograd.grad(blur_windowed(xr, psf, scheme=scheme, optical_center=oc, region=region), xr, y)[0]
    torch.testing.assert_close(A.adjoint(y), ref, rtol=1e-10, atol=1e-13)


@pytest.mark.parametrize("shape,p", [((2, 3, 20, 30), 5), ((1, 2, 20, 30), 19), ((1, 1, 20, 30), 20),
                                     ((1, 1, 7, 40), 0), ((1, 1, 5, 9), 12)])
def test_the_padding_transpose_is_autograds(shape, p):
    """The reflect padding's transpose (and the edge repetition's, where the image is not larger than the pad) folded
    back by hand, against autograd's vector-Jacobian product of the padding."""
    g = torch.rand(shape[:2] + (shape[2] + 2 * p, shape[3] + 2 * p), generator=torch.Generator().manual_seed(2),
                   dtype=torch.float64)
    x = torch.zeros(shape, dtype=torch.float64, requires_grad=True)
    ref = torch.autograd.grad(_pad(x, p), x, g)[0]
    torch.testing.assert_close(_pad_transpose(g, p, shape[-2:]), ref, rtol=1e-13, atol=1e-13)


def test_the_operator_refuses_images_it_does_not_map():
    A = BlurOperator(FIELD, (1, 1, 40, 50), scheme=SCHEMES[0])
    with pytest.raises(ValueError, match="40 x 50 px"):
        A.forward(torch.zeros(1, 1, 40, 51))
    with pytest.raises(ValueError, match=r"\(B, C, H, W\)"):
        A.adjoint(torch.zeros(40, 50))
    with pytest.raises(ValueError, match="region"):
        BlurOperator(FIELD, (40, 50), region=(0, 41, 0, 50))
