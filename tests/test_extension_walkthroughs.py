"""The four walkthroughs of docs/architecture.md, done at run time exactly as a contributor would do
them in the files the docs name: each new feature works end to end through the existing code."""

from __future__ import annotations

import math

import pytest
import torch

from lenssim import CRITERIA, PARAMETERS, Camera, Design, Lens, LensPSF, Numerics, Spectrum

from lenssim_studies.paper import PAPER_CAMERA
from lenssim import evaluate, psf_at, seidel_sums, slope_departure_cost
from lenssim.optics.cost import surface_cost
from lenssim.optics.paraxial import seidel_surface_sums
from lenssim_studies.sweep import SweepConfig, run_sweep
from lenssim_studies.tradeoff import find_optimum
import dataclasses
from lenssim_studies.paper import PAPER_LENS, PAPER_RHO0, PAPER_SENSOR, PAPER_SPECTRUM

D = torch.float64
FAST = Numerics(min_size=128, oversample=1)


def test_walkthrough_a_wavelength_band_is_a_spectrum():
    """No code change: a Spectrum (or a [spectrum] config section) is taken by every PSF, criterion and blur."""
    green = Camera(spectrum=Spectrum((0.50, 0.53, 0.56), (0.25, 0.5, 0.25)), lens=PAPER_LENS, sensor=PAPER_SENSOR)
    r = evaluate(green, Design(s=-0.775, Q_back=-2.4), [27.6], numerics=FAST, rho0=PAPER_RHO0)
    mono = evaluate(PAPER_CAMERA, Design(s=-0.775, Q_back=-2.4), [27.6], numerics=FAST, rho0=PAPER_RHO0)
    assert torch.isfinite(r["mse_r"]).all() and r["fft_size"].shape == (15,)
    assert float(r["rms_w"]) < float(mono["rms_w"])  # waves of a longer mean wavelength: fewer of them
    p, _ = psf_at(green, Design(s=-0.775, Q_back=-2.4), 0.0, 2.0, n=256)
    assert float(p.sum()) == pytest.approx(1.0, abs=1e-9)


def test_walkthrough_a_second_aspheric_surface(tmp_path):
    """Done for real in issue 10, as the walkthrough says: Q_front in design.PARAMETERS, the front surface's conic
    in Lens.surfaces. Everything else picked it up."""
    assert "Q_front" in PARAMETERS
    lens = PAPER_CAMERA.lens
    d = Design(s=torch.tensor(-0.775, dtype=D), Q_back=torch.tensor(-2.4, dtype=D), Q_front=torch.tensor(1.5, dtype=D))
    # third order: the front conic adds (n - 1) Q_front c1^3 y^4 to S_I, as Welford's surface sums say
    closed = seidel_sums(lens, d, [7.0])[0]
    ref = seidel_surface_sums(lens.surfaces(d), torch.tensor(2.0, dtype=D), torch.tensor(0.0, dtype=D),
                              torch.tensor(0.0, dtype=D), torch.tensor(math.tan(math.radians(7.0)), dtype=D))
    torch.testing.assert_close(closed, ref[:4], rtol=1e-12, atol=1e-15)
    assert float(closed[0]) != pytest.approx(float(seidel_sums(lens, d.replace(Q_front=0.0), [7.0])[0, 0]))
    # the cost counts both aspheres
    c1, c2 = lens.curvatures(torch.tensor(-0.775, dtype=D))
    both = surface_cost(c1, torch.tensor(1.5, dtype=D), 2.0) + surface_cost(c2, torch.tensor(-2.4, dtype=D), 2.0)
    assert float(slope_departure_cost(lens, d)) == pytest.approx(float(both), rel=1e-12)
    # a sweep over (s, Q_front) takes its dimension names from the design
    cam = Camera(dataclasses.replace(PAPER_LENS, field_angles_deg=(0.0, 10.0)), PAPER_SENSOR, PAPER_SPECTRUM)
    cfg = SweepConfig(camera=cam, grid={"s": (-0.8, -0.7, 0.05), "Q_front": (-1.0, 1.0, 1.0)}, snr_db=(27.6,),
                      numerics=FAST)
    ds = run_sweep(cfg, tmp_path / "front.nc", show_progress=False)
    assert ds["mse_r"].dims == ("s", "Q_front", "snr")
    assert set(find_optimum(ds, "mse_r")["design"]) == {"s", "Q_front"}
    # and the command line has the flag
    from lenssim_cli.main import build_parser

    args = build_parser().parse_args(["evaluate", "--s", "-0.7", "--Q_front", "0.5"])
    assert args.param_Q_front == 0.5


def test_walkthrough_a_restoration_method():
    """One file in pipeline/restoration/ that calls register(): the Tikhonov filter (tikhonov.py) was added
    exactly so. The package finds it; crops, whole frames, psnr-table and fig8 run it by name with its options
    (``--restore tikhonov:weight=...``); the generic checks of every registered method run on it in
    tests/pipeline/test_restoration.py (it lowers the error of a blurred, noisy image), and the command line's
    in tests/pipeline/test_simulate_cli.py."""
    import pkgutil

    import pipeline.restoration as package
    from pipeline import RESTORATION_METHODS, crop_at_field_angle, resolution_scene, simulate_crops

    assert "tikhonov" in {m.name for m in pkgutil.iter_modules(package.__path__)} and "tikhonov" in RESTORATION_METHODS
    ideal = resolution_scene(400, 600, seed=1, geometry=PAPER_CAMERA.geometry)
    box = crop_at_field_angle(ideal.shape, 0.3, 48, PAPER_CAMERA.geometry)
    r = simulate_crops(ideal, LensPSF(PAPER_CAMERA, Design(s=-0.775, Q_back=-2.4)), 3200.0, [box],
                       methods=("wiener", "tikhonov:weight=0.003"), sensor=PAPER_SENSOR)[0]
    assert set(r.scores) == {"sensor", "wiener", "tikhonov"} and r.images["tikhonov"].shape == r.ideal.shape


def test_walkthrough_a_design_criterion(tmp_path):
    """One file in lenssim/criteria/ that calls register(): the Strehl ratio (strehl.py) and MTF50 (mtf50.py) were
    added exactly so. The package finds them, evaluate returns them, sweeps store them with their label, unit,
    sense and role, and optima and the trade-off read their sense (both are maximised, and neither depends on
    the SNR). The generic checks of every registered criterion run on them in
    tests/lenssim/criteria/test_registered_criteria.py."""
    import pkgutil

    import lenssim.criteria as package

    files = {m.name for m in pkgutil.iter_modules(package.__path__)}
    assert {"strehl", "mtf50"} <= files and {"strehl", "mtf50"} <= set(CRITERIA)
    r = evaluate(PAPER_CAMERA, Design(s=-0.775, Q_back=-2.4), [27.6], numerics=FAST, rho0=PAPER_RHO0)
    assert 0 < float(r["strehl"]) < 1 and r["strehl_alpha"].shape == (15,)
    cfg = SweepConfig(camera=Camera(dataclasses.replace(PAPER_LENS, field_angles_deg=(0.0, 10.0)), PAPER_SENSOR, PAPER_SPECTRUM), grid={"s": (-0.8, -0.7, 0.05), "Q": (-3.0, -1.0, 1.0)},
                      snr_db=(27.6,), numerics=FAST)
    ds = run_sweep(cfg, tmp_path / "c.nc", show_progress=False)
    assert ds["strehl"].dims == ("s", "Q_back") and ds["strehl_alpha"].dims == ("s", "Q_back", "alpha")
    assert ds["strehl"].attrs["sense"] == "max" and "Strehl" in ds["strehl"].attrs["long_name"]
    assert find_optimum(ds, "strehl")["value"] == pytest.approx(float(ds["strehl"].max()))
    assert find_optimum(ds, "mtf50")["value"] == pytest.approx(float(ds["mtf50"].max()))
    assert find_optimum(ds, "mse_r")["value"] == pytest.approx(float(ds["mse_r"].min()))

def test_walkthrough_a_wavefront_model():
    """One entry in lenssim.optics.wavefront_models.WAVEFRONT_MODELS: the exact model was added so; the provider and
    `lenssim evaluate --wavefront` read it by name (generic checks in tests/lenssim/test_wavefront_models.py)."""
    from lenssim.optics.wavefront_models import WAVEFRONT_MODELS

    assert {"third_order", "exact"} <= set(WAVEFRONT_MODELS)
    p = LensPSF(PAPER_CAMERA, Design(s=-0.775, Q_back=-2.4), wavefront="exact")
    assert p.psf_at_pixels(torch.tensor([400.0]), torch.tensor([300.0]), (0.0, 0.0), 128).shape == (1, 128, 128)


def test_walkthrough_an_optical_system():
    """A new optical system implements the OpticalSystem protocol: here the thin lens described by its
    surfaces alone, its Seidel sums from the general surface-by-surface route. The wavefront, and so every PSF
    and criterion, is the same as the closed-form lens's."""
    import dataclasses as dc

    from lenssim.optics.aberrations import wavefront_coefficients
    from lenssim.optics.optical_system import OpticalSystem, surface_seidel_sums

    @dc.dataclass(frozen=True, kw_only=True)
    class SurfacePrescription(Lens):
        def seidel_sums(self, design, alpha, wavelength_um=None):
            return surface_seidel_sums(self, design, alpha, wavelength_um)

    general = SurfacePrescription(**{f.name: getattr(PAPER_LENS, f.name) for f in dc.fields(PAPER_LENS)})
    assert isinstance(general, OpticalSystem)
    d = Design(s=torch.tensor([-0.775, 0.3], dtype=D), Q_back=torch.tensor([-2.4, -6.0], dtype=D))
    torch.testing.assert_close(wavefront_coefficients(general, d, wavelength_um=0.5),
                               wavefront_coefficients(PAPER_LENS, d, wavelength_um=0.5), rtol=1e-12, atol=1e-12)


def test_walkthrough_a_surface_kind(tmp_path, capsys):
    """One file in lenssim/model/surface_kinds/ that registers a SurfaceKind, and its test: Forbes's Qbfs asphere
    (qbfs.py) was added exactly so. The package finds it; a TOML lens names it (``kind = "qbfs"`` with its own key);
    the real rays, the paraxial data, the Seidel sums, the asphere cost and ``lenssim inspect`` take the lens; a
    ``.zmx`` file refuses it in one line; the generic checks of every kind (tests/lenssim/test_surface_kinds.py,
    ``EXAMPLES``) run on it."""
    import importlib.util
    import pkgutil
    from pathlib import Path

    import lenssim.model.surface_kinds as package
    from lenssim.io.prescription_file import read_lens
    from lenssim.io.zemax import write_zmx
    from lenssim.model.prescription import PrescriptionError
    from lenssim.model.surface_kinds import SURFACE_KINDS
    from lenssim.optics.cost import prescription_costs
    from lenssim.optics.sequential import SequentialLens, pupil_grid
    from lenssim_cli.main import main

    assert "qbfs" in {m.name for m in pkgutil.iter_modules(package.__path__)} and "qbfs" in SURFACE_KINDS
    tests = Path(__file__).parent / "lenssim" / "test_surface_kinds.py"
    spec = importlib.util.spec_from_file_location("surface_kind_tests", tests)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    assert "qbfs" in module.EXAMPLES  # the generic checks cover it
    docs = (Path(__file__).parents[1] / "docs" / "architecture.md").read_text()
    walkthrough = docs[docs.index("**Add a surface kind**"):]
    snippet = walkthrough[walkthrough.index("```python") + 9:walkthrough.index("```", walkthrough.index("```python") + 9)]
    source = {line.split("#")[0].strip() for line in (Path(package.__file__).parent / "qbfs.py").read_text().splitlines()}
    for line in filter(None, (raw.split("#")[0].strip() for raw in snippet.splitlines())):
        assert line in source, line  # the docs show the file as it is
    lens = tmp_path / "qbfs_singlet.toml"
    lens.write_text("""name = "plano-convex, Qbfs back"
stop_surface = 1
[aperture]
entrance_pupil_diameter_mm = 16.0
[fields]
angles_deg = [0.0, 5.0]
[[surfaces]]
radius_mm = 50.0
thickness_mm = 6.0
material = [1.5168, 64.17]
semi_diameter_mm = 10.0
[[surfaces]]
kind = "qbfs"
radius_mm = "inf"
normalization_radius_mm = 10.0
aspheric_coefficients = [0.002, -0.0015, 0.0008]
thickness_mm = 92.0
semi_diameter_mm = 10.0
""")
    p = read_lens(str(lens))
    s2 = p.surfaces[1]
    assert s2.surface_kind.name == "qbfs" and s2.paraxial_curvature_per_mm != 0  # a flat best-fit sphere, curved vertex
    seq = SequentialLens(p)
    px, py = pupil_grid(16)
    w = seq.wavefront(5.0, px, py)
    assert 0 < w.rms_waves() < 10 and w.vignetted_fraction == 0.0
    assert torch.isfinite(seq.seidel_surfaces(5.0)).all()
    assert list(prescription_costs(p)) == [2]
    assert main(["inspect", str(lens)]) == 0 and "qbfs: 0.002 -0.0015 0.0008" in capsys.readouterr().out
    with pytest.raises(PrescriptionError, match="surface 2: a qbfs surface .* cannot be written to a .zmx file"):
        write_zmx(p, tmp_path / "qbfs_singlet.zmx")
