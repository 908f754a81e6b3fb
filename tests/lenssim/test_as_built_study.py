"""``lenssim study as-built`` (issue 19, item 4) at a tiny size: its outputs, and its resumption."""

from __future__ import annotations

import pytest

import lenssim_studies.as_built as ab
from lenssim.validate import ResumeWarning
from lenssim_studies.as_built import STRATEGIES, AsBuiltStudy, as_built_study
from lenssim_studies.paper import PAPER_CAMERA, PAPER_DESIGNS, PAPER_RHO0

STUDY = AsBuiltStudy(PAPER_CAMERA, PAPER_RHO0, 27.6, n_lenses=4, levels=(4e-4, 1e-3), s_step=0.25,
                     field_angles_deg=(0.0, 5.0), robust_points=1)


def test_the_study_writes_its_table_figure_and_robust_design_and_resumes(tmp_path, monkeypatch):
    r = as_built_study(STUDY, tmp_path, reference=PAPER_DESIGNS["end_to_end_paper"], log=lambda m: None,
                       show_progress=False)
    assert len(r["table"]) == 2 * len(STRATEGIES)
    for t in r["table"]:
        assert t["nominal_restoration"]["p90"] >= t["calibrated"]["p90"] * (1 - 1e-6)
    assert r["robust_best"]["nominal_restoration"]["p90"] <= r["reference"]["nominal_restoration"]["p90"]
    text = (tmp_path / "report.md").read_text()
    assert "As-built Table 1" in text and "Robust design" in text
    for f in ("fig6_as_built.png", "fig6_as_built.svg", "as_built.json"):
        assert (tmp_path / f).is_file()
    # a second run reads every design's Monte Carlo back (verified), computing nothing
    files = sorted((tmp_path / "designs").glob("*.npz"))
    files[0].write_bytes(files[0].read_bytes()[:-30])  # one damaged file is computed again
    calls = []
    real = ab.as_built_criteria
    monkeypatch.setattr(ab, "as_built_criteria", lambda *a, **k: calls.append(1) or real(*a, **k))
    with pytest.warns(ResumeWarning, match="damaged or of another design"):
        again = as_built_study(STUDY, tmp_path, reference=PAPER_DESIGNS["end_to_end_paper"], log=lambda m: None,
                               show_progress=False)
    assert len(calls) == 1 and again["table"] == r["table"]


def test_the_command_refuses_too_few_lenses(tmp_path, capsys):
    from lenssim_cli.main import main

    rc = main(["study", "as-built", "--lenses", "1", "--out", str(tmp_path / "o")])
    assert rc == 2 and "--lenses 1 is not allowed" in capsys.readouterr().err
