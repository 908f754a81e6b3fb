"""Every tensor the library makes follows its inputs' device and dtype, never torch's defaults: checked without a GPU
(issue 44, item 5).

The bug class: a tensor made without ``device=`` (``torch.tensor(...)``, ``torch.zeros(...)``, ``arange``) lands on
torch's default device, the CPU, and a command run with ``--device cuda`` stops where it meets the inputs' CUDA
tensors (``Lens._check_blur`` stopped every such command, issue 43). CI has no GPU, so two checks stand in for one:

* the public API runs with its inputs on the CPU while torch's default device is another one (``meta``: tensors
  without data) and its default dtype float64 (not float32): a tensor made without a device lands on ``meta`` and
  the first operation that mixes it with an input raises, one that carries on ends on ``meta``, and one made without
  a dtype changes the numbers. Every result must come back on the CPU, in the dtype and with the numbers (to
  :data:`SAME`) of the run under torch's own defaults. The process caches are emptied first, so that the cached tables are made under the
  odd defaults too (and again afterwards, so that nothing made there outlives the test);
* a static check over ``lenssim/`` and ``pipeline/``: every call of a torch tensor factory names its device, the
  inputs' or :data:`lenssim.torch_utils.HOST` (tables kept on the host, numbers given as Python numbers, the CPU-only
  real-ray tracer's work), so that no path the first check does not run can depend on the default device either.

The device-parametrised tests (the ``device_dtype`` fixture of tests/conftest.py) run on CUDA wherever a GPU is
present and are skipped here.
"""

from __future__ import annotations

import ast
import contextlib
import dataclasses
import sys
from collections import OrderedDict
from pathlib import Path

import numpy as np
import pytest
import torch

from lenssim import Camera, Design, LensPSF, evaluate, psf, psf_at, otf_quarter_spectrum, spectral_coefficients
from lenssim.model.numerics import FAST_NUMERICS
from lenssim_studies.paper import PAPER_LENS, PAPER_RHO0, PAPER_SENSOR, PAPER_SPECTRUM

ROOT = Path(__file__).resolve().parents[1]
E2E = Design(s=-0.775, Q_back=-2.4)
CAMERA = Camera(dataclasses.replace(PAPER_LENS, field_angles_deg=(0.0, 5.0, 10.0)), PAPER_SENSOR, PAPER_SPECTRUM)
"""The paper's camera at three field angles (the criteria's cost is in the angles)."""
COOKE = "cooke_triplet"
TEST_SINGLET = ROOT / "tests" / "data" / "lenses" / "test_singlet.toml"
"""One wavelength, 3 degrees of field: a wavefront table in about a second."""

SAME = 1e-12
"""Results agree to this fraction of their largest value: the exact wavefront's least-squares fit
(``torch.linalg.lstsq``) differs from one call to the next by ~1e-14 relative on the same host, even on one thread;
a tensor made in the default dtype instead (float32 against float64) differs by ~1e-7."""

CASES: dict = {}


def case(fn):
    """A case: ``fn()`` makes the inputs (on the CPU, under torch's defaults) and returns ``call()``, the public API
    on them, whose result (tensors, arrays, numbers in dicts, lists and dataclasses) is compared."""
    CASES[fn.__name__] = fn
    return fn


@case
def evaluate_third_order():
    return lambda: evaluate(CAMERA, E2E, [21.6, 27.6], rho0=PAPER_RHO0, numerics=FAST_NUMERICS)


@case
def evaluate_exact_wavefront():
    from lenssim.optics.wavefront_models import validate_wavefront_model

    model = validate_wavefront_model("exact")
    cam = Camera(dataclasses.replace(PAPER_LENS, field_angles_deg=(0.0, 10.0)), PAPER_SENSOR, PAPER_SPECTRUM)
    return lambda: model.evaluate(cam, E2E, [27.6], rho0=PAPER_RHO0, numerics=FAST_NUMERICS)


@case
def psf_and_otf_banks():
    c = spectral_coefficients(CAMERA, E2E, [0.0, 9.0])
    d = Design(s=torch.tensor([-0.775, -0.725]), Q_back=torch.tensor([-2.4, -10.0]))
    x = torch.tensor([0.5, -1.0], dtype=torch.float64)
    return lambda: (psf(CAMERA, c, 128), otf_quarter_spectrum(CAMERA, c, 128), psf_at(CAMERA, d, x, x * 0.5, n=128))


@case
def lens_psf_providers():
    providers = [LensPSF(CAMERA, E2E), LensPSF(CAMERA, E2E, wavefront="exact")]
    rows, cols = torch.tensor([10.0, -300.0]), torch.tensor([0.0, 400.0])
    return lambda: [(p.psf_at_pixels(rows, cols, (0.0, 0.0), 128), p.extents_px(rows, cols, (0.0, 0.0)))
                    for p in providers]


def _lens(spec):
    from lenssim.io.prescription_file import read_lens
    from lenssim.optics.sequential import SequentialLens

    p = read_lens(str(spec))
    return p, SequentialLens(p)


@case
def cooke_triplet_rays():
    from lenssim.optics.lens_report import field_quality
    from lenssim.optics.sequential import pupil_grid

    _, seq = _lens(COOKE)
    px, py = pupil_grid(16)
    return lambda: (seq.wavefront(8.36, px, py), seq.aim(11.86, px, py, method="paraxial"),
                    field_quality(seq, 8.36, grid=32))


@case
def cooke_triplet_batched_rays():
    """A batch of designs as tensors (the real aiming, trace, fit and cost of the batched route)."""
    from lenssim.model.lens_parameters import parse_parameter
    from lenssim.optics.cost import lens_cost
    from lenssim.optics.exact_wavefront import lens_exact_coefficients
    from lenssim.optics.lens_solves import solve_numbers

    p, _ = _lens(COOKE)
    p = dataclasses.replace(p, wavelengths_um=(p.primary_wavelength_um,), fields=(0.0, 6.0))
    pars = [parse_parameter(p, n, aspherize=(6,)) for n in ("E1.bending", "S6.conic")]
    x = torch.tensor([[0.8, 0.0], [0.85, -0.3]], dtype=torch.float64)

    def call():
        seq = solve_numbers(p, pars, x, hold=("efl",))
        return lens_exact_coefficients(seq, p.fields, p.wavelengths_um), lens_cost(seq)
    return call


@case
def cooke_triplet_psfs():
    from lenssim.optics.psf_bank import image_scale_mm, psfs_from_table, wavefront_table

    p, seq = _lens(COOKE)
    lam = (p.primary_wavelength_um,)
    alpha, phi = torch.tensor([0.0, 7.5], dtype=torch.float64), torch.tensor([1.0, 2.0], dtype=torch.float64)

    def call():
        table = wavefront_table(seq, lam, 11.86, image_scale_mm(seq), grid=32, max_nodes=9)
        return table, psfs_from_table(table, ((1.0,),), alpha, phi, 16, 5, 256, 5.0, 3.5, "area")
    return call


@case
def lens_provider_and_criteria():
    """A provider as the explorer holds one, its wavefront table traced (the tracing is :func:`cooke_triplet_psfs`'s)."""
    from lenssim.metrics import evaluate_sequential
    from lenssim_studies.tradeoff import sequential_provider

    p, seq = _lens(TEST_SINGLET)
    prov = sequential_provider(p, seq, pitch_um=4.0, sampling="area", max_field_deg=3.0, coarse=True)
    prov.table()
    rows, cols = torch.tensor([0.0, 30.0]), torch.tensor([0.0, 20.0])
    return lambda: (prov.psf_at_pixels(rows, cols, (0.0, 0.0), 32), prov.extents_px(rows, cols, (0.0, 0.0)),
                    prov.estimated_extent_px(), evaluate_sequential(prov, [27.6], rho0=PAPER_RHO0, angles_deg=[2.0],
                                                                    numerics=FAST_NUMERICS, criteria=("mse_r", "rms_w")))


def _crops(chain):
    from pipeline import WindowScheme, crop_at_field_angle, resolution_scene, simulate_crops

    sensor = PAPER_SENSOR if chain is None else chain  # a sensor or a whole chain
    ideal = resolution_scene(300, 400, seed=2, geometry=CAMERA.geometry)
    boxes = [crop_at_field_angle(ideal.shape, 0.5, 32, CAMERA.geometry)]
    prov = LensPSF(CAMERA, E2E, numerics=FAST_NUMERICS)
    return lambda: simulate_crops(ideal, prov, 3200.0, boxes, seed=4, sensor=sensor,
                                  methods=("wiener:stats=32",), scheme=WindowScheme(64, 16, 32))


CHAIN_SENSOR = dataclasses.replace(PAPER_SENSOR, read_noise_e=3.0, bit_depth=12, black_level_dn=64,
                                   dark_current_e_per_s=100.0, dsnu_e=2.0, prnu_percent=1.0, cfa="RGGB")
"""A sensor with every stage of the camera chain on."""


@case
def simulate_crops_wiener():
    return _crops(None)


@case
def simulate_crops_camera_chain():
    from pipeline.camera_chain import CameraChain

    return _crops(CameraChain(CHAIN_SENSOR, exposure_ms=50.0))


@case
def camera_chain():
    from pipeline.camera_chain import CameraChain

    chain = CameraChain(CHAIN_SENSOR, exposure_ms=50.0)
    img = torch.rand(1, 3, 32, 40, generator=torch.Generator().manual_seed(0), dtype=torch.float64)

    def call():
        raw = chain.capture(chain.scene_to_camera(img), 3200.0, 3200.0, generator=torch.Generator().manual_seed(7),
                            origin=(3, 5))
        units = chain.linearise(raw, 3200.0, 3200.0, origin=(3, 5))
        gains = chain.white_balance_gains(units, origin=(3, 5))
        return raw, units, gains, chain.develop(units, gains=gains, origin=(3, 5))
    return call


@case
def sweep_chunk_with_best_focus():
    from lenssim_studies.chunks import _compute_chunk
    from lenssim_studies.config import SweepConfig

    cam = Camera(dataclasses.replace(PAPER_LENS, field_angles_deg=(0.0, 3.0)), PAPER_SENSOR, PAPER_SPECTRUM)
    cfg = SweepConfig(camera=cam, grid={"s": (-0.8, -0.75, 0.05), "Q": (-2.4, -2.4, 0.1)}, numerics=FAST_NUMERICS,
                      focus={"criterion": "mse_r", "snr_db": 27.6, "bounds_um": [-60, 60], "tol_um": 40.0})
    return lambda: _compute_chunk(cfg, 0, torch.device("cpu"), None)


@case
def as_built_lenses():
    from lenssim import GRADES, as_built_criteria

    cam = Camera(dataclasses.replace(PAPER_LENS, field_angles_deg=(0.0, 8.0)), PAPER_SENSOR, PAPER_SPECTRUM)
    lenses = GRADES["commercial"].sample(2, seed=11)
    return lambda: as_built_criteria(cam, E2E, lenses, [27.6], rho0=PAPER_RHO0, numerics=FAST_NUMERICS)


@case
def iso_cost_gradient():
    from lenssim.design_opt import DifferentiableCriterion

    f = DifferentiableCriterion(CAMERA, 27.6, "mse_r", rho0=PAPER_RHO0, numerics=FAST_NUMERICS.replace(oversample=1))
    x = torch.tensor([-0.8, -2.3], dtype=torch.float64)

    def call():
        xx = x.clone().requires_grad_(True)
        v = f(xx)
        return v.detach(), torch.autograd.grad(v, xx)[0]
    return call


# -- the run under other defaults --------------------------------------------------------------------------------------
def _leaves(x, path="result"):
    """``(path, value)`` of every tensor (numpy arrays as tensors) and number in ``x``."""
    if isinstance(x, torch.Tensor):
        yield path, x
    elif isinstance(x, np.ndarray):
        yield path, torch.from_numpy(x)
    elif isinstance(x, dict):
        for k, v in x.items():
            yield from _leaves(v, f"{path}[{k!r}]")
    elif isinstance(x, (list, tuple)):
        for i, v in enumerate(x):
            yield from _leaves(v, f"{path}[{i}]")
    elif dataclasses.is_dataclass(x):
        for f in dataclasses.fields(x):
            yield from _leaves(getattr(x, f.name), f"{path}.{f.name}")
    elif x is None or isinstance(x, (bool, int, float, str)):
        yield path, x


def _clear_process_caches(monkeypatch) -> None:
    """Empty every cache of tensors the library keeps in the process: the ``functools`` caches of its modules and its
    own tables (replaced by empty ones that ``monkeypatch`` puts back)."""
    from lenssim.optics import psf_bank
    from pipeline import blur

    for name, mod in list(sys.modules.items()):
        if name.partition(".")[0] in ("lenssim", "pipeline", "lenssim_studies"):
            for obj in list(vars(mod).values()):
                if callable(getattr(obj, "cache_clear", None)):
                    obj.cache_clear()
    monkeypatch.setattr(psf_bank, "_BASIS_CACHE", OrderedDict())
    monkeypatch.setattr(psf_bank, "_basis_cache_used", 0)
    monkeypatch.setattr(blur, "_ZONE_ERRORS", OrderedDict())
    monkeypatch.setattr(psf_bank, "_TABLES", {})


@contextlib.contextmanager
def _other_defaults():
    """torch's default device ``meta`` and default dtype float64 (the inputs are CPU tensors, mostly float32)."""
    dtype = torch.get_default_dtype()
    torch.set_default_dtype(torch.float64)
    try:
        with torch.device("meta"):
            yield
    finally:
        torch.set_default_dtype(dtype)


@pytest.fixture
def fresh_caches(monkeypatch):
    yield lambda: _clear_process_caches(monkeypatch)
    _clear_process_caches(monkeypatch)  # nothing made under the other defaults outlives the test


@pytest.mark.parametrize("name", CASES)
def test_the_public_api_follows_its_inputs_not_torchs_defaults(name, fresh_caches):
    ref = dict(_leaves(CASES[name]()()))
    call = CASES[name]()  # the inputs, made under torch's defaults as a caller makes them
    fresh_caches()
    with _other_defaults():
        got = dict(_leaves(call()))
    assert got.keys() == ref.keys()
    assert any(isinstance(v, torch.Tensor) for v in got.values())
    for path, v in got.items():
        if isinstance(v, torch.Tensor):  # on the CPU, in the reference's dtype, the same numbers (NaN where they were)
            r = ref[path]
            scale = float(r.abs().nan_to_num(posinf=0.0).max()) if r.is_floating_point() and r.numel() else 0.0
            torch.testing.assert_close(v, r, rtol=0, atol=SAME * scale, equal_nan=True, msg=lambda m: f"{path}: {m}")
        else:
            assert v == ref[path] or (v != v and ref[path] != ref[path]), path


def test_a_tensor_made_on_the_default_device_is_caught():
    """The check can fail: the bug of issue 43 (a tensor made without the design's device, stacked with its tensors)
    raises under the other defaults, and a tensor made without a dtype comes out in float64."""
    design = E2E.to(torch.float64)

    def blur_check_before_issue_43():
        alpha = torch.tensor(max(CAMERA.lens.field_angles_deg), dtype=torch.float64)
        return CAMERA.lens.seidel_sums(design, alpha)

    blur_check_before_issue_43()
    with _other_defaults(), pytest.raises((RuntimeError, NotImplementedError)):
        blur_check_before_issue_43()
    with _other_defaults():
        assert torch.tensor([0.5], device="cpu").dtype == torch.float64


def test_numbers_go_to_the_host_and_tensors_stay_where_they_are():
    """The helpers every conversion goes through, under the other defaults: a tensor stays on its device (``meta``
    here stands for a GPU), numbers go to the host, and Python numbers in a design join its tensors' device."""
    from lenssim.torch_utils import as_tensor, tensor_of

    gpu = torch.zeros(2, device="meta")
    with _other_defaults():
        assert tensor_of([1.0, 2.0]).device.type == "cpu" and tensor_of(gpu).device.type == "meta"
        assert tensor_of(np.zeros(2, dtype=np.float32)).dtype == torch.float32
        assert as_tensor(1.5, dtype=torch.float64).device.type == "cpu" and as_tensor(gpu).device.type == "meta"
        assert Design(s=-0.775, Q_back=-2.4)["s"].device.type == "cpu"
    d = Design(s=gpu, Q_back=-2.4)
    assert d["Q_back"].device.type == "meta" and d["focus_shift_um"].device.type == "meta"
    assert Design(s=-0.775)["Q_back"].device.type == "cpu"


# -- the static check --------------------------------------------------------------------------------------------------
FACTORIES = frozenset({"tensor", "as_tensor", "asarray", "scalar_tensor", "zeros", "ones", "empty", "full", "eye",
                       "arange", "range", "linspace", "logspace", "rand", "randn", "randint", "randperm",
                       "tril_indices", "triu_indices", "empty_strided"})
"""The ``torch.*`` functions that make a tensor on torch's default device unless given ``device=``
(``torch.utils._device._device_constructors``; the ``*_like`` functions and ``torch.from_numpy`` follow their
argument)."""
LIBRARY = ("lenssim", "pipeline")


def factories_without_device(source: str, filename: str = "<source>") -> list[str]:
    """``"file:line: torch.NAME(...)"`` for each call of a :data:`FACTORIES` function in ``source`` that names no
    ``device`` (a ``**kwargs`` is taken to name one)."""
    out = []
    for node in ast.walk(ast.parse(source, filename)):
        if (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr in FACTORIES
                and isinstance(node.func.value, ast.Name) and node.func.value.id == "torch"
                and not any(k.arg in ("device", None) for k in node.keywords)):
            out.append(f"{filename}:{node.lineno}: torch.{node.func.attr}(...)")
    return out


def test_the_static_check_finds_a_factory_without_a_device():
    src = ("import torch\n"
           "def f(x):\n"
           "    a = torch.zeros(3, dtype=x.dtype)\n"
           "    b = torch.tensor([1.0], device=x.device)\n"
           "    return torch.arange(4) + a + b + torch.zeros_like(x) + torch.ones(2, **{'device': x.device})\n")
    assert factories_without_device(src) == ["<source>:3: torch.zeros(...)", "<source>:5: torch.arange(...)"]


def test_every_tensor_factory_of_the_library_names_its_device():
    found = []
    for package in LIBRARY:
        for path in sorted((ROOT / package).rglob("*.py")):
            found += factories_without_device(path.read_text(encoding="utf-8"), str(path.relative_to(ROOT)))
    assert not found, ("tensors made on torch's default device: give device= (the inputs' device, or "
                       "lenssim.torch_utils.HOST for a table kept on the host):\n" + "\n".join(found))
