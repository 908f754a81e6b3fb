"""The numerical helpers of lenssim.torch_utils against the expressions they replace and against float64."""

import pytest
import torch

from lenssim.torch_utils import abs_square, centred_variance


def test_abs_square_is_the_expression_bit_for_bit(device_dtype):
    device, dtype = device_dtype
    cdtype = torch.complex64 if dtype == torch.float32 else torch.complex128
    g = torch.Generator().manual_seed(3)
    z = torch.randn(4, 1, 3, 96, 49, dtype=cdtype, generator=g).to(device)
    z[0, 0, 0, :3] = 0  # zeros and a conjugate view go through too
    got = abs_square(z)
    assert got.dtype == dtype and got.device.type == device.type
    assert torch.equal(got, z.real.square() + z.imag.square())
    assert torch.equal(abs_square(z.conj()), got)
    # the squared modulus it names: |z|^2 from the modulus in float64
    assert torch.allclose(got.double(), z.abs().double().square(), rtol=1e-6 if dtype == torch.float32 else 1e-14, atol=0)


def test_abs_square_gradient_is_the_expressions():
    g = torch.Generator().manual_seed(5)
    z0 = torch.randn(7, 9, dtype=torch.complex128, generator=g)
    w = torch.randn(7, 9, dtype=torch.float64, generator=g)
    a = z0.clone().requires_grad_(True)
    (abs_square(a) * w).sum().backward()
    b = z0.clone().requires_grad_(True)
    ((b.real.square() + b.imag.square()) * w).sum().backward()
    assert torch.equal(a.grad, b.grad)
    assert torch.allclose(a.grad, 2 * w * z0)  # d|z|^2 in torch's convention for a real loss: 2 w z


@pytest.mark.parametrize("offset", [0.0, 0.3, 1e3])
def test_centred_variance_matches_float64(device_dtype, offset):
    device, dtype = device_dtype
    g = torch.Generator().manual_seed(11)
    x = (offset + 0.01 * torch.randn(5, 1, 3, 128, 128, dtype=torch.float64, generator=g)).to(device=device, dtype=dtype)
    mu = x.mean(dim=(-2, -1), keepdim=True)
    got = centred_variance(x, mu, (-2, -1))
    assert got.shape == (5, 1, 3, 1, 1) and got.dtype == dtype
    exact = x.double().var(dim=(-2, -1), correction=0, keepdim=True)
    # each deviation is exact to an ulp of x: relative to the variance ~2 eps offset / std, and sums of 16 k terms
    tol = torch.finfo(dtype).eps * (64 + 20 * offset / 0.01)
    assert torch.allclose(got.double(), exact, rtol=tol, atol=0)
    # and torch's own population variance to the same rounding
    assert torch.allclose(got, x.var(dim=(-2, -1), correction=0, keepdim=True), rtol=tol, atol=0)


@pytest.mark.parametrize("shapes", [((2, 1), (1, 3)), ((), (4,)), (torch.Size([5, 1, 3]), (7, 1)), ((0, 1), (1, 2)),
                                    ((3,),)])
def test_broadcast_shape_is_torchs(shapes):
    from lenssim.torch_utils import broadcast_shape

    got = broadcast_shape(*shapes)
    assert isinstance(got, torch.Size) and got == torch.broadcast_shapes(*shapes)


def test_broadcast_shape_refuses_as_torch_does():
    from lenssim.torch_utils import broadcast_shape

    with pytest.raises(RuntimeError):
        torch.broadcast_shapes((2, 3), (4,))
    with pytest.raises(RuntimeError, match="do not broadcast"):
        broadcast_shape((2, 3), (4,))


def test_a_command_starts_without_sympy():
    """torch.broadcast_shapes imports torch.fx's symbolic shapes and sympy (0.3 s) on its first call: the command line
    and a design are built without it."""
    import subprocess
    import sys

    code = ("import sys; from lenssim_cli.main import build_parser; from lenssim import Design; build_parser(); "
            "Design(s=[0.0, 1.0], Q_back=-1.0).shape; print('sympy' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
