"""`wpam linear` with points whose load never moved: they are reported as such and left out
of the agreement with the models (a hand-made sweep beside the real linear models)."""

import json
import math

import pytest

from wpam_mj.cli import main
from wpam_mj.design import linear, linear_study
from wpam_mj.experiments.responses import SweepPoint, SweepResult
from wpam_mj.physics.params import preset
from wpam_mj.simulation.context import StudyContext
from wpam_mj.units import MM, MPA

LOAD = 150.0
FREQS = (0.1, 0.25)


def _sweep(amplitude_mm: float, moved: bool) -> SweepResult:
    """PI and PID at FREQS; a load that never moved has a vanishing gain and a lag of
    +-180 deg (what the analysis of a still load gives)."""
    gain, lag = (0.9, 30.0) if moved else (1e-15, 180.0)
    return SweepResult(tuple(SweepPoint(LOAD, f, c, gain, lag, 0.1 * MPA, load_moved=moved)
                             for c in linear.CONTROLLERS for f in FREQS),
                       StudyContext(preset("wpam"), 1e-3), amplitude=amplitude_mm * MM)


@pytest.fixture(scope="module")
def comparison():
    params = preset("wpam").with_values({"controller.po_feedforward": 0.02 * MPA})
    loops = tuple(linear.linear_loop(params, LOAD, 25 * MM, c, m)
                  for m in linear.MODELS for c in linear.CONTROLLERS)
    return linear_study.LinearComparison(LOAD, 25 * MM, loops,
                                         {5 * MM: _sweep(5, True), 0.5 * MM: _sweep(0.5, False)})


def test_still_points_are_left_out_of_the_agreement(comparison):
    moving, still = (comparison.agreement(a * MM) for a in (5, 0.5))
    assert moving["still_points"] == 0 and math.isfinite(moving["worst_gain_db"])
    assert still["still_points"] == 2 * len(linear.CONTROLLERS)
    assert math.isnan(still["worst_gain_db"]) and math.isnan(still["worst_lag_deg"])
    assert not still["agrees"]
    assert comparison.as_json()["agreement"][2]["worst_gain_db"] is None  # 0.5 mm, paper


def test_text_marks_still_rows_and_prints_no_figure_for_them(comparison):
    text = comparison.text()
    rows = [ln for ln in text.splitlines() if ln.split()[:1] == ["0.5"]]
    assert len(rows) == 2 * len(linear.CONTROLLERS)
    assert all("still" in ln and "-2" not in ln for ln in rows), rows
    (summary,) = [ln for ln in text.splitlines() if ln.startswith("at 0.5 mm")]
    assert "never moved" in summary and "dB" not in summary, summary
    assert comparison.still_points() == [f"150 N 0.5 mm {c} at 0.1, 0.25 Hz"
                                         for c in linear.CONTROLLERS]


@pytest.mark.parametrize("as_json", [False, True])
def test_wpam_linear_notes_points_whose_load_never_moved(comparison, monkeypatch, tmp_path,
                                                         capsys, as_json):
    monkeypatch.setattr(linear_study, "compare", lambda *a, **k: [comparison])
    code = main(["linear", "--load", "150", "--amplitudes", "5,0.5", "--jobs", "1",
                 "--out", str(tmp_path), *(["--json"] if as_json else [])])
    out, err = capsys.readouterr()
    assert code == 0, err
    notes = [ln for ln in (err if as_json else out).splitlines() if ln.startswith("note:")]
    assert notes == [f"note: linear 150 N 0.5 mm {c} at 0.1, 0.25 Hz: the load never moved "
                     "(x spanned < 0.5 mm); its numbers mean nothing"
                     for c in linear.CONTROLLERS], notes
    if as_json:
        rows = json.loads(out)["comparison"]
        assert {r["amplitude_mm"] for r in rows if not r["load_moved"]} == {0.5}
    else:
        assert "worst" not in next(ln for ln in out.splitlines() if ln.startswith("at 0.5"))
    csv_head = (tmp_path / "linear_150N.csv").read_text().splitlines()[0]
    assert "load_moved" in csv_head.split(",")
    (manifest,) = tmp_path.glob("manifest-*.json")
    assert json.loads(manifest.read_text())["files"]["linear_150N.csv"]["load_moved"] is False
