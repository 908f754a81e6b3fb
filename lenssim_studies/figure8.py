"""A Fig. 8-style mosaic: crops at several field angles, two designs, three noise levels.

Columns (as the paper's Fig. 8): ideal | RMS_W design, noise-free sensor image | its restoration at
ISO 25 | end-to-end design, noise-free sensor image | its restorations at ISO 400, 100 and 25.
Each restored tile is labelled with its PSNR (dB, sRGB). Written as PNG and SVG (headless).
"""

from __future__ import annotations

from pathlib import Path

import torch

from lenssim import Camera, Design, LensPSF

from lenssim_studies.paper import PAPER_CAMERA, PAPER_DESIGNS
from lenssim.io.files import atomic_write
from lenssim_studies.paper import ISO_FOR_SNR, PAPER_FIG8_ANGLES_DEG

from pipeline.camera_chain import CameraChain
from pipeline.colour_space import linear_to_srgb
from pipeline.figures import tile_label
from pipeline.restoration import Restoration
from pipeline.simulate import crop_at_field_angle, simulate_crops

__all__ = ["PAPER_FIG8_ANGLES", "figure8", "lens_mosaic", "chain_isos"]

PAPER_FIG8_ANGLES = PAPER_FIG8_ANGLES_DEG


def figure8(ideal: torch.Tensor, out_dir, *, camera: Camera = PAPER_CAMERA,
            rms_w: Design = PAPER_DESIGNS["rms_w_paper"], e2e: Design = PAPER_DESIGNS["end_to_end_paper"],
            angles=PAPER_FIG8_ANGLES, crop: int = 128, seed: int = 0, method="wiener", chain=None,
            blur_zones="auto") -> tuple[Path, list[dict]]:
    """The mosaic for ``camera`` with a conventional (``rms_w``) and an end-to-end (``e2e``) design,
    restored with ``method`` (a name, ``"NAME:key=value,..."`` or a :class:`pipeline.restoration.Restoration`);
    writes ``fig8_mosaic.png`` and ``.svg`` in ``out_dir``. ``chain`` (a :class:`pipeline.camera_chain.CameraChain`)
    runs the camera chain; its sensor's ISO table then sets the full wells (:func:`chain_isos`). ``blur_zones``: as
    :func:`pipeline.simulate.simulate_crops` takes it (default ``"auto"``, as ``lenssim simulate``)."""
    spec = Restoration.of(method)
    method = spec.name
    boxes = [crop_at_field_angle(ideal.shape, a, crop, camera.geometry) for a in angles]
    isos = tuple(ISO_FOR_SNR.values())  # low, expected, high light: ISO 400, 100, 25
    table = camera.sensor if chain is None else chain.sensor
    isos = chain_isos(table, isos)
    low_noise = isos[-1]
    well = table.full_well_for_iso
    runs = {("rms_w", low_noise): simulate_crops(ideal, LensPSF(camera, rms_w), well(low_noise), boxes, seed=seed,
                                                 methods=(spec,), sensor=chain or camera.sensor,
                                                 blur_zones=blur_zones)}
    per_iso = simulate_crops(ideal, LensPSF(camera, e2e), [well(i) for i in isos], boxes, seed=seed,  # one blur
                             methods=(spec,), sensor=chain or camera.sensor, blur_zones=blur_zones)
    runs.update({("e2e", iso): res for iso, res in zip(isos, per_iso)})
    img = lambda key, kind: (lambda i: runs[key][i].images[kind])  # noqa: E731
    cols = [("ideal", img(("e2e", low_noise), "ideal"), None),
            ("RMS_W: sensor (no noise)", img(("rms_w", low_noise), "blurred"), None),
            (f"RMS_W: restored, ISO {low_noise}", img(("rms_w", low_noise), method), ("rms_w", low_noise)),
            ("end-to-end: sensor (no noise)", img(("e2e", low_noise), "blurred"), None)]
    cols += [(f"end-to-end: restored, ISO {iso}", img(("e2e", iso), method), ("e2e", iso)) for iso in isos]
    title = (f"Fig. 8: RMS_W design ({rms_w.label()}) vs end-to-end design ({e2e.label()}); restoration: "
             f"{spec.method.label}; PSNR / SSIM in sRGB against the ideal image")
    if chain is not None:
        title += f"\ncamera chain: {chain.label()}"
    return _mosaic(runs, cols, runs[("e2e", low_noise)], title, method, out_dir, "fig8_mosaic")


def chain_isos(sensor, preferred) -> tuple[int, ...]:
    """The ISOs of a mosaic: ``preferred`` (highest first) if ``sensor``'s table has them all, else the table's three
    highest, highest first."""
    if all(i in sensor.isos for i in preferred):
        return tuple(preferred)
    return tuple(sorted(sensor.isos, reverse=True)[:3])


def lens_mosaic(ideal: torch.Tensor, out_dir, psf, label: str, *, angles, crop: int = 128, seed: int = 0,
                method="wiener", isos=None, sensor=None, blur_zones="auto", about: str = ""
                ) -> tuple[Path, list[dict]]:
    """Fig. 8's mosaic for one lens of any kind (a PSF provider ``psf``, e.g. a
    :class:`lenssim.optics.psf_provider.SequentialPSF`, named ``label``): ideal | sensor image without noise | its
    restorations with ``method`` at each ISO of ``isos`` (default the paper's 400, 100, 25; full wells of ``sensor``,
    a :class:`lenssim.Sensor` or a :class:`pipeline.camera_chain.CameraChain`, default the provider's sensor), one row
    per field angle of ``angles`` (crops of ``crop`` px at the provider's geometry).
    Writes ``lens_mosaic.png`` and ``.svg`` in ``out_dir``; returns the PNG's path and a row per restored tile.
    ``blur_zones``: as for :func:`figure8`; ``about``: words the title adds after the label (e.g. the pixel pitch)."""
    spec = Restoration.of(method)
    method = spec.name
    chain = CameraChain.of(psf.sensor if sensor is None else sensor)
    boxes = [crop_at_field_angle(ideal.shape, a, crop, psf.geometry) for a in angles]
    isos = tuple(ISO_FOR_SNR.values()) if isos is None else tuple(isos)
    table = chain.sensor
    isos = chain_isos(table, isos)
    per_iso = simulate_crops(ideal, psf, [table.full_well_for_iso(i) for i in isos], boxes, seed=seed,  # one blur
                             methods=(spec,), sensor=chain, blur_zones=blur_zones)
    runs = {(label, iso): res for iso, res in zip(isos, per_iso)}
    first = runs[(label, isos[0])]
    img = lambda key, kind: (lambda i: runs[key][i].images[kind])  # noqa: E731
    cols = [("ideal", img((label, isos[0]), "ideal"), None),
            ("sensor (no noise)", img((label, isos[0]), "blurred"), None)]
    cols += [(f"restored, ISO {iso}", img((label, iso), method), (label, iso)) for iso in isos]
    title = (f"{label}{', ' + about if about else ''}\nthe sensor image and its restoration ({spec.method.label}) at ISO "
             f"{', '.join(str(i) for i in isos)}; PSNR / SSIM in sRGB against the ideal image")
    if isinstance(sensor, CameraChain):
        title += f"\ncamera chain: {chain.label()}"
    return _mosaic(runs, cols, first, title, method, out_dir, "lens_mosaic")


def _mosaic(runs: dict, cols: list, first: list, title: str, method: str, out_dir, stem: str) -> tuple[Path, list[dict]]:
    """Draw the tiles ``cols`` (``(title, image of row i, key of runs for its scores or None)``), a row per crop of
    ``first`` (its field angles label the rows); write ``STEM.png`` and ``.svg``; the restored tiles' scores."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(len(first), len(cols), figsize=(2.0 * len(cols), 2.05 * len(first) + 0.6),
                             squeeze=False, constrained_layout=True)
    table = []
    for i in range(len(first)):
        for j, (head, get, key) in enumerate(cols):
            ax = axes[i, j]
            img = linear_to_srgb(get(i).clamp(0, 1))[0]
            ax.imshow(img.permute(1, 2, 0).squeeze(-1).cpu().numpy(), cmap="gray" if img.shape[0] == 1 else None,
                      vmin=0, vmax=1, interpolation="nearest")
            ax.set_xticks([])
            ax.set_yticks([])
            if i == 0:
                ax.set_title(head, fontsize=7)
            if j == 0:
                ax.set_ylabel(f"field {first[i].field_deg:.1f} deg", fontsize=8)
            if key is not None:
                sc = runs[key][i].scores[method]
                ax.text(0.02, 0.03, tile_label(sc), transform=ax.transAxes, color="yellow", fontsize=6,
                        backgroundcolor=(0, 0, 0, 0.55))
                table.append({"field_deg": runs[key][i].field_deg, "design": key[0], "iso": key[1],
                              "psnr_restored_db": sc["psnr_db"], "ssim_restored": sc["ssim"]})
    fig.suptitle(title, fontsize=8)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    png = out / f"{stem}.png"
    for path in (png, out / f"{stem}.svg"):
        atomic_write(path, lambda tmp: fig.savefig(tmp, dpi=150))
    plt.close(fig)
    return png, table
