import pytest


def pytest_addoption(parser):
    parser.addoption("--runslow", action="store_true", default=False, help="run paper-scale (slow) tests")


def pytest_sessionstart(session):
    """The project's own modules compiled to bytecode once, before any test: where ``PYTHONDONTWRITEBYTECODE`` is set
    (as on this project's machines) no import writes it, so every subprocess a test starts (the console command, the
    examples, the explorer's servers) compiled every module of the project again, 1.3 s of its 3.6 s start here.
    Python reads bytecode that exists whatever that variable says; the caches are ``__pycache__`` folders, which git
    ignores. Measured on the subprocess-heavy test files (install, hardening, the browser, the camera commands): 227.9
    -> 204.6 s."""
    import compileall
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    for package in ("lenssim", "pipeline", "lenssim_studies", "lenssim_cli", "examples", "benchmarks"):
        if (root / package).is_dir():
            compileall.compile_dir(root / package, quiet=2)


def pytest_collection_modifyitems(config, items):
    if config.getoption("--runslow"):
        return
    skip = pytest.mark.skip(reason="slow: run with --runslow")
    for item in items:
        if "slow" in item.keywords:
            item.add_marker(skip)


@pytest.fixture(autouse=True)
def _environment_unchanged():
    """Every test leaves the process's environment as it found it (monkeypatch's changes are undone before this
    runs): a variable left behind reaches every later test's subprocesses (a dask LocalCluster's
    ``OMP_NUM_THREADS=1`` and ``MALLOC_TRIM_THRESHOLD_`` once slowed the rest of the suite's subprocesses 2.6x)."""
    import os

    # pytest's own (set for each phase of a test), and those a library sets for itself when it is first imported, which
    # may be inside whichever test comes first (OpenImageIO's root, pyviz_comms' mark, torch inductor's cache folder,
    # matplotlib's config folder where the home has none)
    own = {"PYTEST_CURRENT_TEST", "OpenImageIO_ROOT", "_PYVIZ_COMMS_INSTALLED", "TORCHINDUCTOR_CACHE_DIR", "MPLCONFIGDIR"}

    before = {k: v for k, v in os.environ.items() if k not in own}
    yield
    changed = sorted(k for k in set(before) | set(os.environ) if k not in own and before.get(k) != os.environ.get(k))
    if changed:
        for k in changed:
            if k in before:
                os.environ[k] = before[k]
            else:
                del os.environ[k]
        pytest.fail(f"the test left the environment changed: {', '.join(changed)}", pytrace=False)


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
