import pytest


def pytest_addoption(parser):
    parser.addoption("--runslow", action="store_true", default=False, help="run paper-scale (slow) tests")


def pytest_collection_modifyitems(config, items):
    if config.getoption("--runslow"):
        return
    skip = pytest.mark.skip(reason="slow: run with --runslow")
    for item in items:
        if "slow" in item.keywords:
            item.add_marker(skip)



def _device_dtypes():
    import torch

    cases = [("cpu", torch.float32), ("cpu", torch.float64)]
    if torch.cuda.is_available():
        cases += [("cuda", torch.float32), ("cuda", torch.float64)]
    return cases


@pytest.fixture(params=_device_dtypes(), ids=lambda c: f"{c[0]}-{str(c[1]).replace('torch.', '')}")
def device_dtype(request):
    """(device, dtype): CPU float32/float64 always, CUDA too where a GPU is present (as kornia's fixtures)."""
    import torch

    dev, dt = request.param
    return torch.device(dev), dt
