"""A resumable tolerance Monte Carlo of any sequential lens (``lenssim tolerance --lens``; issue 29).

The copies (:mod:`lenssim.sequential_tolerance`) are computed in chunks of :data:`CHUNK_COPIES`, each written to
``out.partial/chunk_NNNNN.npz`` with its index, the run's digest and a SHA-256 of its arrays, as the singlet's
Monte Carlo (:mod:`lenssim_studies.tolerance`) does: a killed run resumes where it stopped, every resumed chunk is
verified (a chunk that fails is reported as a :class:`lenssim.validate.ResumeWarning` and computed again), and the
finished dataset is the same, byte for byte, as an uninterrupted run's.
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
import xarray as xr

from lenssim import __version__
from lenssim.model.numerics import Numerics
from lenssim.model.tolerances import SurfaceTolerances
from lenssim.optics.sequential_psf import SequentialPSF
from lenssim.sequential_tolerance import (CRITERIA, copy_criteria, lens_tolerance_dataset, nominal_criteria,
                                          tolerance_angles)

from .chunks import (finish_resumable, open_resumable, partial_folder, read_stamped_chunk, result_mismatch, resume_chunks,
                     write_stamped_chunk)

__all__ = ["LensToleranceRun", "run_lens_tolerance_resumable", "CHUNK_COPIES"]

CHUNK_COPIES = 5
"""Copies per chunk file (each copy traces its own wavefront tables: a chunk is seconds to a minute)."""
_ROW_KEYS = CRITERIA + ("image_shift_mm", "efl_mm")


@dataclass(frozen=True)
class LensToleranceRun:
    """Everything that sets a Monte Carlo of any lens: the nominal lens's provider (lens, sensor, light, sampling),
    the tolerances, the number of copies and seed, the SNRs (dB), the image model's correlation, the field angles
    (deg; None: :func:`lenssim.sequential_tolerance.tolerance_angles`), the numerics and whether the copies' tables
    are coarse."""

    psf: SequentialPSF
    tolerances: SurfaceTolerances
    n_copies: int
    seed: int
    snr_db: tuple[float, ...]
    rho0: float
    numerics: Numerics
    angles_deg: tuple[float, ...] | None = None
    coarse: bool = True
    chunk_copies: int = CHUNK_COPIES

    @property
    def angles(self) -> tuple[float, ...]:
        return tolerance_angles(self.psf, self.angles_deg)

    def to_dict(self) -> dict:
        return {"psf": json.loads(self.psf.fingerprint()), "lens_cache_key": self.psf.lens.cache_key(),
                "tolerances": self.tolerances.to_dict(), "n_copies": self.n_copies, "seed": self.seed,
                "snr_db": list(self.snr_db), "rho0": self.rho0, "numerics": self.numerics.to_dict(),
                "angles_deg": list(self.angles), "coarse": self.coarse, "chunk_copies": self.chunk_copies,
                "lenssim_version": __version__}

    def digest(self) -> str:
        return hashlib.sha256(json.dumps(self.to_dict(), sort_keys=True, default=str).encode()).hexdigest()[:16]

    def chunks(self) -> list[tuple[int, int]]:
        """Copy ranges ``[k0, k1)`` of the chunks."""
        return [(k, min(k + self.chunk_copies, self.n_copies)) for k in range(0, self.n_copies, self.chunk_copies)]


def _write_chunk(path: Path, chunk: dict, run: LensToleranceRun, i: int) -> None:
    write_stamped_chunk(path, chunk, run.digest(), i)


def _read_chunk(path: Path, run: LensToleranceRun, i: int):
    """The chunk's arrays if ``path`` holds chunk ``i`` of this run intact, else the reason it does not."""
    k0, k1 = run.chunks()[i]
    return read_stamped_chunk(path, _ROW_KEYS, run.digest(), i, run="tolerance run", rows_key="efl_mm",
                              rows=k1 - k0, what="copies")


def run_lens_tolerance_resumable(run: LensToleranceRun, out: str | os.PathLike, *, show_progress: bool = True,
                                 max_chunks: int | None = None, attrs: dict | None = None) -> xr.Dataset | None:
    """Run (or resume) the Monte Carlo and write ``out`` (NetCDF); ``None`` if ``max_chunks`` stopped it early. The
    dataset is :func:`lenssim.sequential_tolerance.lens_tolerance_dataset`'s, with the run's ``config_digest``; an
    existing ``out`` is returned if it is this run's finished result, refused otherwise. ``attrs``: more attributes
    of the dataset (descriptive: not part of the digest)."""
    out = Path(out)
    done = open_resumable(out, run.digest(), "tolerance output", "tolerance run",
                          check=lambda ds: result_mismatch(ds, {"lens": np.arange(run.n_copies), "snr": run.snr_db},
                                                           finite=_ROW_KEYS, dims=("lens",)))
    if done is not None:
        return done
    angles = run.angles
    kw = dict(rho0=run.rho0, angles_deg=angles, numerics=run.numerics)
    pert = run.tolerances.sample(run.psf.lens.prescription, run.n_copies, seed=run.seed)
    nominal, nom, full = nominal_criteria(run.psf, run.snr_db, coarse=run.coarse, **kw)
    part = out.with_name(out.name + ".partial")
    if part.exists():
        for p in part.glob(".*"):
            p.unlink(missing_ok=True)

    def compute(i, progress):
        k0, k1 = run.chunks()[i]
        rows = []
        for k in range(k0, k1):
            rows.append(copy_criteria(run.psf, nominal, pert, k, run.snr_db, coarse=run.coarse, **kw))
            progress(1)
        return {key: np.stack([np.asarray(torch.as_tensor(r[key], dtype=torch.float64)) for r in rows])
                for key in _ROW_KEYS}

    with partial_folder(part, "run.json", run.digest(), {"run": run.to_dict()},
                        f"{str(part)!r} holds chunks of a different tolerance run; remove it or choose another output"):
        ranges = run.chunks()
        paths = [part / f"chunk_{i:05d}.npz" for i in range(len(ranges))]
        chunks = resume_chunks(paths, kind="tolerance", read=lambda p, i: _read_chunk(p, run, i),
                               write=lambda p, chunk, i: _write_chunk(p, chunk, run, i), compute=compute,
                               weight=lambda i: ranges[i][1] - ranges[i][0], desc="manufactured copies",
                               unit="copy", show_progress=show_progress, max_chunks=max_chunks)
        if chunks is None:
            return None
        rows = [{key: torch.from_numpy(np.asarray(c[key][j])) for key in _ROW_KEYS}
                for c in chunks for j in range(c["efl_mm"].shape[0])]
        ds = lens_tolerance_dataset(run.psf, run.tolerances, pert, rows, nom, full, snr_db=run.snr_db, seed=run.seed,
                                    angles_deg=angles, rho0=run.rho0, coarse=run.coarse)
        ds.attrs.update(attrs or {})
        ds.attrs["config_digest"] = run.digest()
        finish_resumable(out, ds, part)
        return ds
