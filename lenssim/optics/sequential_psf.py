"""PSFs of any sequential lens on a sensor: Fourier optics of the real-ray wavefront, field by field.

:class:`SequentialPSF` is the PSF provider (:class:`lenssim.optics.psf_provider.PSFProvider`) of a
:class:`lenssim.optics.sequential.SequentialLens` (object at infinity) on a sensor's pixels, in one spectrum or in
colour channels. How a PSF is made:

1. **The wavefront table** (:func:`wavefront_table`). The lens is rotationally symmetric, so the wavefront of a field
   depends on the field angle only, up to a rotation of the pupil. For each wavelength and each field angle of a set
   of nodes from the axis to the largest angle asked, the OPD (:meth:`SequentialLens.wavefront`, real rays aimed at
   the stop, vignetted by every semi-diameter) is traced on a ``grid x grid`` square of the entrance pupil in the
   meridional frame (field along ``+y``), against the reference sphere centred on the primary wavelength's chief-ray
   point; the distortion that moves that point from the pixel's paraxial one ``m tan(alpha)`` (``m`` the paraxial
   image scale on the image plane, :attr:`SequentialPSF.image_scale_mm`) is kept apart and added as a tilt. The OPD
   therefore holds, as tilt, the distortion and the lateral colour (each wavelength's image lies where its rays go),
   and as defocus the axial colour and the focus. Beyond the vignetting's edge the OPD is traced through the surfaces
   extended past their semi-diameters (its smooth continuation, what the interpolation at the edge reads).
   Field-angle nodes are added (bisection) until the table, interpolated linearly in angle, matches traced OPDs at
   the mid-nodes to :data:`TABLE_TOLERANCE_WAVES`; the error reached is
   :attr:`WavefrontTable.interpolation_error_waves`.
2. **The pupil of one PSF**: the FFT grid's pupil samples (radius ``R = N delta / (2 lambda N_w)`` samples for an
   ``N``-point FFT of pitch ``delta``, ``N_w`` the paraxial working F-number) are rotated into the meridional frame
   of the PSF's azimuth and the table's OPD and aperture ratio (each ray's largest height over a semi-diameter) are
   interpolated there (bilinear in the pupil, cubic in angle). The amplitude is 1 inside the unit disc where the rays
   pass (interpolated aperture ratio <= 1), so an off-axis pupil takes the vignetted shape the semi-diameters give,
   and no symmetry is assumed beyond the lens's.
3. **The PSF** ``|FFT(A exp(-2 pi i W))|^2`` (the sign puts the PSF's centroid where the rays land: checked against
   the rays' centroid in the tests), summed over the wavelengths with their weights, on a grid ``s`` times finer
   than the pixels; ``sampling="area"`` (the default) sums each pixel's ``s x s`` samples (a pixel of full fill
   factor integrates the light falling on it; ``s`` odd, at least 3, and fine enough for the Nyquist pitch
   ``lambda N_w / 2`` at the shortest wavelength), ``sampling="point"`` takes the samples at the pixel centres
   (the paper's model, ``s = 1``). Each PSF has unit sum on its ``n x n`` pixels.

Neglected, as in :mod:`lenssim.optics.lens_report`: the entrance pupil's grid is mapped linearly onto the exit
pupil (pupil aberrations and the oblique beam's foreshortening, ``1/cos`` factors of the off-axis PSF's scale).

The pixel at distance ``r`` from the optical axis is at field angle ``atan(r / m)`` (:attr:`SequentialPSF.geometry`,
the paraxial mapping): the PSF there is centred on that pixel shifted by the lens's distortion, so distortion is
rendered in a simulated image, as a camera records it.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field

import torch

from ..model.geometry import FieldGeometry
from ..model.numerics import DEFAULT_NUMERICS, Numerics
from ..model.sensor import Sensor
from ..model.spectrum import Spectrum, shared_quadrature, shared_wavelengths
from .psf_bank import nice_fft_size
from .psf_provider import PSFProvider
from .sequential import SequentialLens
from ..torch_utils import HOST, tensor_of

__all__ = ["SequentialPSF", "WavefrontTable", "wavefront_table", "psfs_from_table", "image_scale_mm", "SAMPLINGS",
           "TABLE_GRID", "TABLE_TOLERANCE_WAVES", "MIN_PUPIL_RADIUS_SAMPLES", "chief_point_mm"]

SAMPLINGS = ("area", "point")
"""How a PSF is sampled on the pixels: integrated over each pixel's area, or at the pixel centres."""
TABLE_GRID = 64
"""Pupil samples across the entrance pupil's diameter in the wavefront table (each wavelength and field node)."""
TABLE_INITIAL_NODES = 9
"""Field-angle nodes of the table before bisection (from the axis to the largest angle, evenly)."""
TABLE_MAX_NODES = 257
"""Most field-angle nodes of the table (the bisection stops there and the error reached is reported)."""
TABLE_TOLERANCE_WAVES = 0.01
"""Largest error (waves) of the table's angle interpolation at the mid-nodes, over the unvignetted pupil."""
MIN_PUPIL_RADIUS_SAMPLES = 24
"""The FFT is at least large enough for the pupil's radius to span this many samples at every wavelength."""
DIFFRACTION_MARGIN_AIRY = 16.0
"""The PSF's diameter exceeds the rays' spot by this many ``lambda N_w``: the Airy pattern holds 97.5% of its light
within a radius of 8 ``lambda N_w`` (``1 - J0^2 - J1^2`` at ``8 pi``); each PSF is renormalised to unit sum on its
window, so the far wings' few percent are given back to the window in proportion."""
MIN_MARGIN_PX = 4
"""The least diffraction margin (px) of a PSF's diameter."""
MIN_AREA_OVERSAMPLE = 3
"""``sampling="area"`` integrates each pixel over at least this many samples across."""
PHASE_SIGN = -1.0
"""The pupil function is ``A exp(PHASE_SIGN 2 pi i W)`` with ``W`` Welford's OPD (reference minus ray) and the image
axes along the pupil's: with -1 the PSF's centroid is the rays' centroid (tests/lenssim/test_sequential_psf.py)."""
TABLE_CACHE_SIZE = 8
"""Wavefront tables kept in the process (each a few MB)."""
_TABLES: dict = {}
CHUNK_BYTES = 2**28
"""PSFs are computed in batches whose complex FFT grids take at most this many bytes."""
EXTENT_PUPIL_POINTS = 96
"""Pupil points traced per field and wavelength for :meth:`SequentialPSF.estimated_extent_px` (half on the rim)."""
EXTENT_FIELDS = 5
"""Field angles (evenly from the axis to the largest) of :meth:`SequentialPSF.estimated_extent_px`."""
APERTURE_UNTRACED = 2.0
"""The aperture ratio given to a pupil sample whose ray cannot be traced at all (well beyond the pass level 1)."""


def _meridional_grid(grid: int):
    """The table's pupil grid: ``grid`` samples from ``-e`` to ``e`` per axis, ``e`` a little beyond the unit disc so
    that interpolation at the rim has samples on both sides. Returns ``(coords (grid,), e)``."""
    e = 1.0 + 2.0 / (grid - 1) * 2
    return torch.linspace(-e, e, grid, dtype=torch.float64, device=HOST), e


def _inpaint(W: torch.Tensor, valid: torch.Tensor, sweeps: int = 3) -> torch.Tensor:
    """``W`` (…, G, G) with the samples where ``valid`` is False filled from their valid neighbours (``sweeps`` rings),
    0 beyond: the values a bilinear interpolation reads at the vignetting's edge."""
    W = torch.where(valid, W, torch.zeros_like(W))
    have = valid.to(W.dtype)
    for _ in range(sweeps):
        num = torch.zeros_like(W)
        den = torch.zeros_like(W)
        for dy, dx in ((0, 1), (0, -1), (1, 0), (-1, 0), (1, 1), (1, -1), (-1, 1), (-1, -1)):
            num += torch.roll(W * have, (dy, dx), dims=(-2, -1))
            den += torch.roll(have, (dy, dx), dims=(-2, -1))
        fill = (have == 0) & (den > 0)
        W = torch.where(fill, num / den.clamp(min=1), W)
        have = torch.where(fill, torch.ones_like(have), have)
    return W


def _stencil(nodes: torch.Tensor, alpha: torch.Tensor, width: int = 4):
    """Cubic Lagrange interpolation in angle: for each ``alpha`` ``(P,)`` the ``width`` nodes around it (fewer if the
    table has fewer) and their weights, ``(P, w)`` each (the weights sum to 1)."""
    A = nodes.numel()
    w = min(width, A)
    j = torch.clamp(torch.searchsorted(nodes, alpha.contiguous(), right=True) - 1, 0, A - 1)
    first = torch.clamp(j - (w // 2 - 1), 0, A - w)
    idx = first[:, None] + torch.arange(w, device=nodes.device)[None, :]
    x = nodes[idx]  # (P, w)
    wts = torch.ones_like(x)
    for i in range(w):
        for k in range(w):
            if i != k:
                wts[:, i] = wts[:, i] * (alpha - x[:, k]) / (x[:, i] - x[:, k])
    return idx, wts


@dataclass(frozen=True)
class WavefrontTable:
    """OPD maps (waves) of a lens per wavelength and field-angle node, in the meridional frame (see the module
    docstring): ``opd_waves`` and ``aperture_ratio`` ``(K, A, G, G)`` (the ray's largest height over a semi-diameter,
    :attr:`lenssim.optics.sequential.RayBundle.aperture_ratio`: the ray passes where it is <= 1, a smooth function
    whose interpolation places the vignetting's edge between samples; ``opd_waves`` continued smoothly across that
    edge), on the pupil coordinates
    ``grid_coords`` ``(G,)`` (``[row, col] = [py, px]``), ``angles_deg`` ``(A,)`` increasing from 0;
    ``spot_radius_mm`` ``(K, A)``: the largest distance of a ray's image point from the paraxial image point. The OPD
    is against the sphere centred on the primary wavelength's chief-ray point; the distortion that moves that point
    from the paraxial one is :attr:`distortion_mm` (a smooth function of the angle, interpolated by a cubic spline and
    added to the PSF as the tilt that moves it there: a tilt's linear interpolation in angle would need many more
    nodes)."""

    wavelengths_um: tuple[float, ...]
    angles_deg: torch.Tensor
    grid_coords: torch.Tensor
    extent: float
    opd_waves: torch.Tensor
    aperture_ratio: torch.Tensor
    spot_radius_mm: torch.Tensor
    distortion_mm: torch.Tensor
    """``(A,)``: the primary wavelength's chief-ray point minus the paraxial point ``m tan(alpha)`` (mm, radial)."""
    interpolation_error_waves: float

    def _bracket(self, alpha_deg: torch.Tensor):
        a = self.angles_deg
        if bool((alpha_deg > a[-1] * (1 + 1e-9) + 1e-12).any()):
            raise ValueError(f"field angle {float(alpha_deg.max()):.4g} deg is beyond the wavefront table's "
                             f"{float(a[-1]):.4g} deg")
        j = torch.clamp(torch.searchsorted(a, alpha_deg.contiguous(), right=True) - 1, 0, max(len(a) - 2, 0))
        if len(a) == 1:
            return j, j, torch.zeros_like(alpha_deg)
        t = ((alpha_deg - a[j]) / (a[j + 1] - a[j])).clamp(0, 1)
        return j, j + 1, t

    def spot_radius_at(self, alpha_deg: torch.Tensor) -> torch.Tensor:
        """The largest spot radius (mm) over the wavelengths at ``alpha_deg`` ``(P,)``: the larger of the two nodes'."""
        j0, j1, _ = self._bracket(alpha_deg)
        r = self.spot_radius_mm.amax(dim=0)
        return torch.maximum(r[j0], r[j1])

    def distortion_at(self, alpha_deg: torch.Tensor) -> torch.Tensor:
        """The distortion (mm, radial) at ``alpha_deg`` ``(P,)``: cubic spline through the nodes (not-a-knot)."""
        a = self.angles_deg.numpy()
        if len(a) < 4:
            return torch.from_numpy(__import__("numpy").interp(alpha_deg.numpy(), a, self.distortion_mm.numpy()))
        from scipy.interpolate import CubicSpline

        return torch.from_numpy(CubicSpline(a, self.distortion_mm.numpy())(alpha_deg.to(torch.float64).numpy()))

    def sample(self, k: int, alpha_deg: torch.Tensor, px: torch.Tensor, py: torch.Tensor):
        """OPD (waves) and aperture ratio (the ray passes where <= 1) of wavelength ``k`` at field angles ``alpha_deg``
        ``(P,)`` and meridional pupil points ``px, py`` ``(P, M, M)``: bilinear in the pupil, cubic in angle (Lagrange
        through the four nearest nodes). Returns two ``(P, M, M)``."""
        import torch.nn.functional as F

        self._bracket(alpha_deg)  # refuses angles beyond the table
        grid = torch.stack([px / self.extent, py / self.extent], dim=-1).to(self.opd_waves.dtype)  # x = col, y = row
        idx, wts = _stencil(self.angles_deg, alpha_deg.to(torch.float64))
        # the angle interpolation on the table's grid first (linear operations commute): one bilinear lookup per map
        wts = wts.to(self.opd_waves.dtype)[:, :, None, None]
        maps = torch.stack([(self.opd_waves[k][idx] * wts).sum(1), (self.aperture_ratio[k][idx] * wts).sum(1)], dim=1)
        out = F.grid_sample(maps, grid, mode="bilinear", padding_mode="border", align_corners=True)
        return out[:, 0], out[:, 1]


def chief_point_mm(seq: SequentialLens, alpha: float, lam: float) -> tuple[float, float]:
    """Where the chief ray of field ``alpha`` (deg) at ``lam`` meets the image plane: its ``(x, y)`` (mm; ``x`` is 0
    for a centred lens, and taken as exactly 0 there)."""
    zero = torch.zeros(1, dtype=torch.float64, device=HOST)
    w = seq.wavefront(alpha, zero, zero, lam)
    return (0.0 if seq.is_centred else float(w.chief_mm[0])), float(w.chief_mm[1])


def _trace_node(seq: SequentialLens, alpha: float, lams, scale_mm: float, grid: int):
    """One field node: per wavelength, the OPD map against the sphere centred on the primary wavelength's chief-ray
    point, the vignetting, the disc's unvignetted samples, and the largest distance (mm) of a ray's image point from
    the paraxial point ``scale tan(alpha)``; and the distortion (mm) of the primary chief ray."""
    coords, e = _meridional_grid(grid)
    Y, X = torch.meshgrid(coords, coords, indexing="ij")
    inside = X**2 + Y**2 <= (1 + 2 * (coords[1] - coords[0])) ** 2
    paraxial = scale_mm * math.tan(math.radians(alpha))
    chief_x, chief = chief_point_mm(seq, alpha, seq.primary_wavelength_um)
    out = []
    for lam in lams:
        w = seq.wavefront(alpha, X[inside], Y[inside], lam, reference_mm=(chief_x, chief), vignette=False)
        W = torch.zeros(grid, grid, dtype=torch.float64, device=HOST)
        V = torch.zeros(grid, grid, dtype=torch.bool, device=HOST)
        T = torch.zeros(grid, grid, dtype=torch.bool, device=HOST)
        W[inside] = torch.nan_to_num(w.opd_waves, nan=0.0)
        V[inside] = w.valid
        T[inside] = ~torch.isnan(w.opd_waves)  # traced through the surfaces extended beyond their semi-diameters
        ratio = torch.full((grid, grid), APERTURE_UNTRACED, dtype=torch.float64, device=HOST)
        ratio[inside] = torch.where(T[inside], w.aperture_ratio, torch.full_like(w.aperture_ratio, APERTURE_UNTRACED))
        disc = V & (X**2 + Y**2 <= 1)
        if not bool(disc.any()):
            raise ValueError(f"field {alpha:.4g} deg at {lam:g} um: every ray is vignetted")
        pts = w.image_mm[w.valid][:, :2]
        spot = float(torch.hypot(pts[:, 0] - chief_x, pts[:, 1] - paraxial).max())
        out.append((_inpaint(W, T), ratio, spot, disc))
    return out, chief - paraxial


def wavefront_table(seq: SequentialLens, wavelengths_um, max_angle_deg: float, image_scale_mm: float, *,
                    grid: int = TABLE_GRID, tolerance_waves: float = TABLE_TOLERANCE_WAVES,
                    max_nodes: int = TABLE_MAX_NODES, progress=None) -> WavefrontTable:
    """The :class:`WavefrontTable` of ``seq`` at ``wavelengths_um`` from the axis to ``max_angle_deg`` (see the module
    docstring); ``progress(k)`` is called with the number of traced maps as they are traced."""
    lams = tuple(float(v) for v in wavelengths_um)
    amax = float(max_angle_deg)
    nodes = torch.linspace(0, amax, TABLE_INITIAL_NODES if amax > 0 else 1, dtype=torch.float64, device=HOST).tolist()
    maps: dict[float, tuple] = {}

    def trace(a):
        if a not in maps:
            maps[a] = _trace_node(seq, a, lams, image_scale_mm, grid)
            if progress is not None:
                progress(len(lams))
        return maps[a][0]

    for a in nodes:
        trace(a)
    err = 0.0
    todo = list(zip(nodes, nodes[1:]))  # intervals whose mid-node is checked
    left = 0.0
    while todo and len(maps) < max_nodes:
        refine, left = [], 0.0
        for a0, a1 in todo:
            known = torch.tensor(sorted(maps), dtype=torch.float64, device=HOST)
            mid = (a0 + a1) / 2
            idx, wts = _stencil(known, torch.tensor([mid], dtype=torch.float64, device=HOST))
            stencil = [float(known[i]) for i in idx[0]]
            m = trace(mid)
            e = 0.0
            for k, (Wm, _, _, dm) in enumerate(m):
                both = dm.clone()
                guess = torch.zeros_like(Wm)
                for a, wt in zip(stencil, wts[0]):
                    Wa, _, _, da = maps[a][0][k]
                    both &= da
                    guess = guess + float(wt) * Wa
                if bool(both.any()):
                    e = max(e, float((Wm - guess)[both].abs().max()))
            if e > tolerance_waves:
                refine += [(a0, mid), (mid, a1)]
                left = max(left, e)
            else:
                err = max(err, e)  # an interval accepted: its mid-node's error
        todo = refine
    if todo:  # stopped at max_nodes: the intervals not refined keep their error
        err = max(err, left)
    nodes = sorted(maps)
    K = len(lams)
    W = torch.stack([torch.stack([maps[a][0][k][0] for a in nodes]) for k in range(K)])
    V = torch.stack([torch.stack([maps[a][0][k][1] for a in nodes]) for k in range(K)])
    spot = torch.tensor([[maps[a][0][k][2] for a in nodes] for k in range(K)], dtype=torch.float64, device=HOST)
    dist = torch.tensor([maps[a][1] for a in nodes], dtype=torch.float64, device=HOST)
    coords, e = _meridional_grid(grid)
    return WavefrontTable(lams, torch.tensor(nodes, dtype=torch.float64, device=HOST), coords, e, W, V, spot, dist, err)


@dataclass(frozen=True)
class SequentialPSF(PSFProvider):
    """The PSFs of ``lens`` (object at infinity) on ``sensor``'s pixels in the spectrum ``light`` (or in colour
    channels ``colour_channels``, each a :class:`lenssim.Spectrum`): see the module docstring. ``max_field_deg`` is the largest field angle the
    PSFs are asked at (the table is traced that far; default: the lens's largest field); ``sampling`` one of
    :data:`SAMPLINGS`."""

    lens: SequentialLens
    sensor: Sensor
    light: Spectrum
    colour_channels: tuple = ()
    max_field_deg: float | None = None
    sampling: str = "area"
    numerics: Numerics = field(default_factory=lambda: DEFAULT_NUMERICS)
    mirror_symmetric: bool = True
    table_max_nodes: int = TABLE_MAX_NODES
    """Most field-angle nodes of the wavefront table (:func:`wavefront_table`); :data:`TABLE_INITIAL_NODES` (or
    fewer) traces the initial nodes only, no bisection (a coarser, faster table)."""

    def __post_init__(self):
        p = self.lens.prescription
        if not p.object_at_infinity:
            raise ValueError("a lens imaging an object at a finite distance is not supported on a sensor yet: its "
                             "PSFs are defined per field angle (object at infinity)")
        if self.sampling not in SAMPLINGS:
            raise ValueError(f"sampling={self.sampling!r} is not allowed: one of {', '.join(SAMPLINGS)}")
        object.__setattr__(self, "colour_channels", tuple(self.colour_channels))
        amax = max(p.fields) if self.max_field_deg is None else float(self.max_field_deg)
        if not (math.isfinite(amax) and 0 <= amax < 90):
            raise ValueError(f"max_field_deg={amax!r} is not allowed: a field angle from 0 to below 90 degrees")
        object.__setattr__(self, "max_field_deg", amax)
        if not self.lens.is_centred:  # not rotationally symmetric: no mirror groups in a blur
            object.__setattr__(self, "mirror_symmetric", False)
        par = self.lens.paraxial()
        if not (math.isfinite(par.working_f_number) and par.working_f_number > 0):
            raise ValueError("the lens has no finite working F-number (its image is at infinity)")
        object.__setattr__(self, "_cache", {})
        if self.sampling == "point":
            lam = min(self._all_wavelengths())
            if not self.sensor.pixel_pitch_um < lam * par.working_f_number:
                raise ValueError(f"pixel pitch {self.sensor.pixel_pitch_um:g} um with sampling 'point' is not allowed "
                                 f"with this lens: below lambda N_w = {lam * par.working_f_number:.4g} um at {lam:g} um "
                                 "(use sampling 'area')")

    # -- what the pipeline reads ---------------------------------------------------------------------------------------
    @property
    def working_f_number(self) -> float:
        return self.lens.paraxial().working_f_number

    @property
    def image_scale_mm(self) -> float:
        """Paraxial image height (mm) per unit ``tan(field angle)`` on the image plane, at the primary wavelength (the
        focal length for a lens focused at infinity)."""
        if "scale" not in self._cache:
            self._cache["scale"] = image_scale_mm(self.lens)
        return self._cache["scale"]

    @property
    def geometry(self) -> FieldGeometry:
        return FieldGeometry(self.image_scale_mm, self.sensor.pixel_pitch_um)

    @property
    def channels(self) -> int:
        """1 (one PSF for every colour) or the number of colour channels."""
        return max(1, len(self.colour_channels))

    def _all_wavelengths(self) -> tuple[float, ...]:
        return tuple(sorted({w for s in (self.light, *self.colour_channels) for w in s.wavelengths_um}))

    def quadrature(self) -> tuple[tuple[float, ...], tuple[tuple[float, ...], ...]]:
        """The wavelengths (um) the PSFs integrate and each channel's weight at them ``(C, K)``: the spectrum's own, or
        for channels on one table a few shared by all (:func:`lenssim.model.spectrum.shared_quadrature`, spaced by the
        lens's spectral arc: axial and lateral colour and the diffraction scale, in pixels)."""
        if "quad" in self._cache:
            return self._cache["quad"]
        chans = self.colour_channels
        if not chans:
            q = (tuple(self.light.wavelengths_um), (tuple(self.light.weights),))
        elif shared_wavelengths(chans) and len(chans[0]) > 2:
            chans, _ = shared_quadrature(chans, self._spectral_arc_px(chans[0].wavelengths_um),
                                         self.numerics.spectral_tol)
            q = (tuple(chans[0].wavelengths_um), tuple(tuple(c.weights) for c in chans))
        else:
            lams = self._all_wavelengths()
            rows = []
            for c in chans:
                w = dict(zip(c.wavelengths_um, c.weights))
                rows.append(tuple(w.get(v, 0.0) for v in lams))
            q = (lams, tuple(rows))
        self._cache["quad"] = q
        return q

    def _spectral_arc_px(self, wavelengths_um) -> list[float]:
        pitch_mm = self.sensor.pixel_pitch_um * 1e-3
        z = self.lens.image_z_mm
        tan_max = math.tan(math.radians(self.max_field_deg))
        pts = []
        for lam in wavelengths_um:
            marg, chief = _paraxial_image_heights(self.lens, lam, z, tan_max)
            airy = lam * self.lens.paraxial(lam).working_f_number * 1e-3
            pts.append((marg / pitch_mm, chief / pitch_mm, airy / pitch_mm))
        arc = [0.0]
        for a, b in zip(pts, pts[1:]):
            arc.append(arc[-1] + sum(abs(x - y) for x, y in zip(a, b)))
        return arc

    def spectrum(self) -> tuple[tuple[float, ...], tuple[float, ...]]:
        """The wavelengths (um) the PSFs integrate and their weights (the channels' mean)."""
        lams, w = self.quadrature()
        return lams, tuple(sum(row[k] for row in w) / len(w) for k in range(len(lams)))

    def table(self, progress=None) -> WavefrontTable:
        """The :class:`WavefrontTable` (traced once, on first use; shared in the process by providers of the same lens,
        image plane, wavelengths and largest angle: :data:`TABLE_CACHE_SIZE` are kept)."""
        if "table" not in self._cache:
            # everything that changes the optics (the lens's cache_key: prescription, image plane, index offsets)
            key = json.dumps([self.lens.cache_key(), self.quadrature()[0], self.max_field_deg]
                             + ([self.table_max_nodes] if self.table_max_nodes != TABLE_MAX_NODES else []),
                             sort_keys=True, default=str)
            hit = _TABLES.pop(key, None)
            if hit is None:
                hit = wavefront_table(self.lens, self.quadrature()[0], self.max_field_deg, self.image_scale_mm,
                                      progress=progress, max_nodes=self.table_max_nodes)
            _TABLES[key] = hit  # most recently used last
            while len(_TABLES) > TABLE_CACHE_SIZE:
                _TABLES.pop(next(iter(_TABLES)))
            self._cache["table"] = hit
        return self._cache["table"]

    def oversample(self) -> int:
        """Samples per pixel (odd) of the grid the PSFs are computed on."""
        if self.sampling == "point":
            return 1
        nyq = min(self.quadrature()[0]) * self.working_f_number / 2  # um
        s = max(MIN_AREA_OVERSAMPLE, math.ceil(self.sensor.pixel_pitch_um / nyq))
        return s + 1 - s % 2

    def fft_size(self, n: int) -> int:
        """The FFT size for ``n x n``-pixel PSFs: the fine window ``n s`` and the pupil's radius at least
        :data:`MIN_PUPIL_RADIUS_SAMPLES` at the longest wavelength."""
        s = self.oversample()
        fine_um = self.sensor.pixel_pitch_um / s
        lam_max = max(self.quadrature()[0])
        need = math.ceil(MIN_PUPIL_RADIUS_SAMPLES * 2 * lam_max * self.working_f_number / fine_um)
        return nice_fft_size(max((n + 1) * s, need))  # the window n s around the centre, for odd and even n

    def estimated_extent_px(self) -> int:
        """The PSF diameter (px) over the whole traced field, estimated from a few rays before any wavefront table is
        traced (the table of a badly blurred lens takes minutes): :data:`EXTENT_PUPIL_POINTS` pupil points (the rim
        and a grid inside) at :data:`EXTENT_FIELDS` field angles from the axis to :attr:`max_field_deg`, every
        wavelength, the largest distance of a ray's image point from the paraxial point doubled, + :meth:`margin_px`
        (as :meth:`extents_px`). A lower bound: 8-19% below the table's extent on the test singlet, the Cooke triplet,
        the double Gauss and a phone lens (the table also traces rays just beyond the pupil's rim), so a refusal
        from it is never wrong and a PSF it passes is checked again batch by batch (:meth:`check_fft_size`). The pupil
        points are CPU float64 tensors, as every ray of :class:`SequentialLens` (its surfaces are Python floats)."""
        n_rim = EXTENT_PUPIL_POINTS // 2
        t = torch.arange(n_rim, dtype=torch.float64, device=HOST) * (2 * math.pi / n_rim)
        g = torch.linspace(-1, 1, math.isqrt(EXTENT_PUPIL_POINTS - n_rim), dtype=torch.float64, device=HOST)
        gy, gx = torch.meshgrid(g, g, indexing="ij")
        inside = gx**2 + gy**2 < 1
        px = torch.cat([torch.cos(t), gx[inside]])
        py = torch.cat([torch.sin(t), gy[inside]])
        spot = 0.0
        for k in range(EXTENT_FIELDS):
            alpha = self.max_field_deg * k / (EXTENT_FIELDS - 1)
            paraxial = self.image_scale_mm * math.tan(math.radians(alpha))
            for lam in self.quadrature()[0]:
                w = self.lens.wavefront(alpha, px, py, lam)
                pts = w.image_mm[w.valid][:, :2]
                if pts.numel():
                    spot = max(spot, float(torch.hypot(pts[:, 0], pts[:, 1] - paraxial).max()))
        return math.ceil(2 * spot / (self.sensor.pixel_pitch_um * 1e-3)) + self.margin_px()

    def check_fft_size(self, n: int, what: str = "") -> int:
        """:meth:`fft_size` of ``n x n``-pixel PSFs, refused (:class:`lenssim.validate.ResourceLimitError`, setting
        ``max_fft_size``) above ``numerics.max_fft_size``: one such FFT grid is ``16 N^2`` bytes (complex128)."""
        N = self.fft_size(n)
        if N > self.numerics.max_fft_size:
            from ..validate import ResourceLimitError

            raise ResourceLimitError(
                f"{what or 'the lens'}: its PSF spans {n} px ({n * self.sensor.pixel_pitch_um * 1e-3:.3g} mm) on "
                f"{self.sensor.pixel_pitch_um:.4g} um pixels, sampled {self.oversample()} times per pixel for its F/"
                f"{self.working_f_number:.3g} beam: an FFT of {N} samples ({16 * N * N / 2**30:.3g} GiB per PSF), more "
                f"than the limit max_fft_size = {self.numerics.max_fft_size}", "max_fft_size")
        return N

    def margin_px(self) -> int:
        """Pixels added to the geometric PSF diameter for diffraction: :data:`DIFFRACTION_MARGIN_AIRY` times
        ``lambda N_w`` at the longest wavelength, at least :data:`MIN_MARGIN_PX`."""
        lam = max(self.quadrature()[0])
        return max(MIN_MARGIN_PX, math.ceil(DIFFRACTION_MARGIN_AIRY * lam * self.working_f_number
                                            / self.sensor.pixel_pitch_um))

    def extents_px(self, rows, cols, optical_center) -> torch.Tensor:
        """PSF diameter (px) at each position: twice the largest distance of a ray's image point from the pixel (every
        wavelength; distortion and lateral colour included), rounded up, + :meth:`margin_px`."""
        x, y = self.geometry.offsets_mm(rows, cols, optical_center)
        alpha = self.geometry.field_angle_deg(x, y).reshape(-1).cpu()  # the table's device
        self._check_angles(alpha)
        r = self.table().spot_radius_at(alpha)
        return torch.ceil(2 * r / (self.sensor.pixel_pitch_um * 1e-3)).to(torch.int64) + self.margin_px()

    def extent_px(self, rows, cols, optical_center) -> int:
        e = self.extents_px(rows, cols, optical_center)
        return int(e.max()) if e.numel() else self.margin_px()

    def _check_angles(self, alpha):
        if alpha.numel() and float(alpha.max()) > self.max_field_deg * (1 + 1e-9) + 1e-9:
            raise ValueError(f"field angle {float(alpha.max()):.4g} deg is beyond the {self.max_field_deg:.4g} deg "
                             "this lens's PSFs were set up for (max_field_deg)")

    def psf_at_pixels(self, rows, cols, optical_center, n, *, centered=True, dtype=None, device=None,
                      pedestal: bool = True, distortion: bool = True):
        """PSFs ``(P, n, n)`` (one channel) or ``(P, C, n, n)`` at pixel positions, unit sum each.

        Each PSF is computed on the support it needs (the largest of the positions' :meth:`extents_px`, at most ``n``)
        and laid in the middle of the ``n x n`` grid (a blur's window may be far larger than the PSF). The light the
        FFT puts beyond that support (the far wings of diffraction and aberration) is spread evenly over the whole
        ``n x n`` grid, a uniform pedestal as in today's model (:meth:`PSFProvider.pedestal_fractions`), so no light
        is lost or moved into the core; ``pedestal=False`` renormalises the support to unit sum instead.
        ``distortion=False``: each PSF about its chief ray's point, not the pixel (:func:`psfs_from_table`)."""
        r = tensor_of(rows).cpu()
        c = tensor_of(cols).cpu()
        x, y = self.geometry.offsets_mm(r, c, optical_center)
        x, y = x.reshape(-1), y.reshape(-1)
        alpha = self.geometry.field_angle_deg(x, y)
        self._check_angles(alpha)
        phi = torch.atan2(y, x)
        k = int(self.extents_px(r, c, optical_center).max()) if alpha.numel() else n
        out = self.psfs_at_angles(alpha, phi, n, k, pedestal=pedestal, distortion=distortion,
                                  complex_dtype=torch.complex128 if dtype == torch.float64 else torch.complex64)
        if not self.colour_channels:
            out = out[:, 0]
        out = out.to(dtype=dtype or torch.float32, device=device)
        return out if centered else torch.fft.ifftshift(out, dim=(-2, -1))

    def psfs_at_angles(self, alpha_deg, phi_rad, n: int, support_px: int, *, table: WavefrontTable | None = None,
                       pedestal: bool = True, distortion: bool = True, complex_dtype=torch.complex64) -> torch.Tensor:
        """PSFs ``(P, C, n, n)`` float64 (unit sum) at field angles ``alpha_deg`` and image-plane azimuths ``phi_rad``
        ``(P,)``, centred at ``[n//2, n//2]``, computed on ``support_px`` pixels (at most ``n``; given ``n``'s parity,
        so the support lies symmetrically about the grid's centre) and laid in the middle of the grid, the light
        beyond the support spread evenly over it (``pedestal``) or the support renormalised; ``table``: another
        wavefront table on this one's wavelengths (default :meth:`table`; e.g. the aberration-free pupil)."""
        if not self.lens.is_centred:
            _check_misaligned(phi_rad, distortion)
        k = min(n, int(support_px))
        k = min(n, k + (n - k) % 2)
        small, captured = psfs_from_table(
            self.table() if table is None else table, self.quadrature()[1], alpha_deg, phi_rad, k, self.oversample(),
            self.check_fft_size(k), self.sensor.pixel_pitch_um, self.working_f_number, self.sampling,
            complex_dtype=complex_dtype, distortion=distortion)
        out = torch.zeros(*small.shape[:-2], n, n, dtype=small.dtype, device=small.device)
        o = n // 2 - k // 2
        if pedestal:
            out += ((1 - captured) / (n * n))[..., None, None]
            small = small * captured[..., None, None]
        out[..., o:o + k, o:o + k] += small
        return out

    def fingerprint(self) -> str:
        """A stable description of these PSFs (lens, image plane, sensor, spectrum, sampling, numerics)."""
        d = {"prescription": self.lens.prescription.to_dict(), "image_shift_mm": self.lens.image_shift_mm,
             "sensor": self.sensor.to_dict(), "spectrum": self.light.to_dict(),
             "channels": [c.to_dict() for c in self.colour_channels], "max_field_deg": self.max_field_deg,
             "sampling": self.sampling, "numerics": self.numerics.to_dict()}
        if getattr(self.lens, "index_offsets", None):  # a manufactured copy's glass errors (absent: as before)
            d["index_offsets"] = {str(k): v for k, v in self.lens.index_offsets.items()}
        if not self.lens.is_centred:  # a manufactured copy's decentres and tilts (absent: as before)
            d["lens_cache_key"] = self.lens.cache_key()
        if self.table_max_nodes != TABLE_MAX_NODES:
            d["table_max_nodes"] = self.table_max_nodes
        return json.dumps(d, sort_keys=True, default=str)


def _check_misaligned(phi_rad, distortion: bool) -> None:
    """A misaligned lens (not rotationally symmetric) has PSFs along its ``+y`` field only (image azimuth ``pi/2``;
    other azimuths are :meth:`SequentialLens.rotated`'s ``+y``), about the chief ray's point (its boresight shift is
    not a radial distortion)."""
    phi = tensor_of(phi_rad, torch.float64)
    if phi.numel() and bool(((phi - math.pi / 2).abs() > 1e-12).any()):
        raise ValueError("a decentred or tilted lens's PSFs are defined along its +y field only (image azimuth 90 "
                         "deg): take the other azimuths from SequentialLens.rotated")
    if distortion:
        raise ValueError("a decentred or tilted lens's PSFs are about the chief ray's point only (distortion=False)")


def _paraxial_image_heights(seq: SequentialLens, lam: float, z_img: float, tan_field: float):
    """The paraxial marginal ray's and the chief ray's (at ``tan_field``) heights (mm) on the plane ``z_img`` at
    ``lam``."""
    par = seq.paraxial(lam)
    z_last = float(seq.prescription.vertex_z_mm[-1])
    r_ep = par.epd_mm / 2
    mh, mu = seq._ynu(r_ep, 0.0, lam)
    ch, cu = seq._ynu(-par.entrance_pupil_z_mm * tan_field, tan_field, lam)
    d = z_img - z_last
    return mh[-1] + mu[-1] * d, ch[-1] + cu[-1] * d


def image_scale_mm(seq: SequentialLens) -> float:
    """Paraxial chief-ray height on the image plane per unit tangent of the field angle (primary wavelength)."""
    lam = seq.primary_wavelength_um
    return _paraxial_image_heights(seq, lam, seq.image_z_mm, 1.0)[1]


def psfs_from_table(table: WavefrontTable, channel_weights, alpha_deg, phi_rad, n: int, s: int, N: int,
                    pitch_um: float, working_f_number: float, sampling: str,
                    complex_dtype=torch.complex64, distortion: bool = True) -> torch.Tensor:
    """PSFs ``(P, C, n, n)`` (unit sum) at field angles ``alpha_deg`` and image-plane azimuths ``phi_rad`` ``(P,)``
    from ``table``, with each channel's weights ``(C, K)`` at the table's wavelengths; ``s`` samples per pixel, an
    ``N``-point FFT (see the module docstring). Returns them and the fraction of each one's light the ``n x n``
    window holds, ``(P, C)``. ``distortion=False``: each PSF about the primary wavelength's chief-ray point instead of
    the paraxial point (the image registered, as for a criterion that scores blur, not the geometric mapping)."""
    P = alpha_deg.numel()
    C = len(channel_weights)
    real = torch.float64 if complex_dtype == torch.complex128 else torch.float32
    dev = table.opd_waves.device
    out = torch.zeros(P, C, n, n, dtype=torch.float64, device=dev)
    held = torch.zeros(P, C, dtype=torch.float64, device=dev)
    fine = pitch_um / s
    half = N // 2
    per = max(1, CHUNK_BYTES // (N * N * (16 if complex_dtype == torch.complex128 else 8) * 3))
    lo = half - (n // 2) * s - s // 2
    if lo < 0:
        raise ValueError(f"FFT size {N} is smaller than the {n} px PSF at {s} samples per pixel")
    rows = (torch.arange(n * s, device=dev) + (lo - half)) % N  # the window's samples, frequency 0 at index 0
    for i0 in range(0, P, per):
        a = alpha_deg[i0:i0 + per].to(torch.float64)
        ph = phi_rad[i0:i0 + per].to(torch.float64)
        m = a.numel()
        dist_um = table.distortion_at(a) * 1e3 if distortion else torch.zeros_like(a)
        acc = torch.zeros(m, C, n, n, dtype=torch.float64, device=dev)
        for k, lam in enumerate(table.wavelengths_um):
            wk = [row[k] for row in channel_weights]
            if not any(wk):
                continue
            R = N * fine / (2 * lam * working_f_number)
            h = int(math.ceil(R)) + 1
            j = torch.arange(-h, h + 1, dtype=torch.float64, device=dev) / R
            gy, gx = torch.meshgrid(j, j, indexing="ij")  # pupil [row, col] = [py, px], image-plane frame
            sp, cp = torch.sin(ph)[:, None, None], torch.cos(ph)[:, None, None]
            mx = gx * sp - gy * cp  # the meridional frame of each PSF's azimuth (field along +y)
            my = gx * cp + gy * sp
            W, V = table.sample(k, a, mx, my)
            # the distortion as a tilt: with PHASE_SIGN -1, W = -delta rho_y / (2 lambda N_w) moves the PSF by +delta
            W = W - (dist_um / (2 * lam * working_f_number))[:, None, None] * my
            amp = ((gx**2 + gy**2 <= 1)[None] & (V <= 1)).to(real)
            # the pupil's patch at the FFT's corner (a shifted pupil changes the field's phase only, not |FFT|^2); the
            # 2-D FFT one axis at a time, keeping only the window's columns, then its rows: the pupil's 2h + 1 rows
            # are all that is nonzero before the first pass
            field_ = torch.polar(amp, (PHASE_SIGN * 2 * math.pi) * W.to(real)).to(complex_dtype)
            spec = torch.fft.fft(field_, n=N, dim=-1).index_select(-1, rows)
            spec = torch.fft.fft(spec, n=N, dim=-2).index_select(-2, rows)
            win = spec.real**2 + spec.imag**2
            total = (N * N) * amp.sum(dim=(-2, -1), keepdim=True)  # Parseval: the light of the whole FFT grid
            if sampling == "area":
                pix = win.reshape(m, n, s, n, s).sum(dim=(2, 4))
            else:
                pix = win[:, s // 2::s, s // 2::s]
            pix = (pix / total).to(torch.float64)
            for c, w in enumerate(wk):
                if w:
                    acc[:, c] += w * pix
        wsum = torch.tensor([sum(row) for row in channel_weights], dtype=torch.float64, device=dev)
        inside = acc.sum(dim=(-2, -1))
        held[i0:i0 + m] = inside / wsum
        out[i0:i0 + m] = acc / inside[..., None, None]
    return out, held
