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
    """Every (device, dtype) case, the CUDA ones skipped where no GPU is present (shown as skipped, not left out)."""
    import torch

    no_gpu = pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")
    return [pytest.param((dev, dt), id=f"{dev}-{str(dt).replace('torch.', '')}", marks=no_gpu if dev == "cuda" else ())
            for dev in ("cpu", "cuda") for dt in (torch.float32, torch.float64)]


@pytest.fixture(params=_device_dtypes())
def device_dtype(request):
    """(device, dtype): CPU float32/float64 always, CUDA float32/float64 where a GPU is present (as kornia's
    fixtures), skipped elsewhere."""
    import torch

    dev, dt = request.param
    return torch.device(dev), dt
