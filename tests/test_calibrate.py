"""Calibration plumbing: its parameters and bounds, its Table 2 residuals, and the TOML
it writes.

The full fit runs the simulator for tens of minutes (`wpam calibrate`); the search itself
is the engine of `wpam fit`, checked in tests/test_fitting.py."""

from types import SimpleNamespace

import numpy as np
import pytest

from wpam_mj import fitting, paper
from wpam_mj.calibrate import DYNAMIC_FIT, STATIC_FIT, WEIGHTS, CalibrationResult, StaticStage
from wpam_mj.params import apply_overrides, load_toml, plausible_range, preset


@pytest.mark.parametrize("name", [*STATIC_FIT, *DYNAMIC_FIT])
def test_fitted_parameters_are_bounded_by_their_plausible_range(name):
    p = fitting.FreeParameter.of(name)
    assert (p.lo, p.hi) == plausible_range(name)


def _loops(ratios):
    """Fake static loops with Po = 0 areas 1 and the given Po = 0.04 areas."""
    return [SimpleNamespace(area=a) for r in ratios for a in (1.0, r)]


def test_static_residuals_vanish_at_the_papers_row_and_wall_beyond_the_limit():
    stage, params = StaticStage(), preset()
    paper_row = [paper.TABLE2["open_po"][load] for load in paper.LOADS_N]
    at_paper = stage.residuals(params, _loops(paper_row))
    assert np.allclose(at_paper[:6], 0.0)
    off = 0.2  # one cell 20 % high: relative error 0.2, plus the wall past 12 %
    res = stage.residuals(params, _loops([paper_row[0] * (1 + off), *paper_row[1:]]))
    assert res[0] == pytest.approx(off)
    assert res[3] == pytest.approx(WEIGHTS.table2_wall * (off - WEIGHTS.table2_wall_from))
    assert np.allclose(res[[1, 2, 4, 5]], 0.0)


def test_written_toml_reproduces_the_fitted_parameters(tmp_path):
    free = [fitting.FreeParameter.of(n) for n in STATIC_FIT]
    params = fitting.with_values(preset("wpam"), free, [0.36, 0.7, 0.2, 3.0, 1e-3])
    fitted = {n: fitting.FreeParameter.of(n).value(params) for n in (*STATIC_FIT, *DYNAMIC_FIT)}
    result = CalibrationResult(params, fitted, np.zeros(3), np.zeros(2))
    path = tmp_path / "fit.toml"
    path.write_text(result.toml())
    assert apply_overrides(preset("wpam"), load_toml(path)) == params


def test_an_interrupted_calibration_resumes_after_its_last_finished_stage(tmp_path,
                                                                          monkeypatch):
    """Each finished stage is kept; a resumed run skips those stages and ends where an
    uninterrupted one does (stages replaced by cheap deterministic stand-ins)."""
    import wpam_mj.calibrate as cal
    from wpam_mj import fitting

    calls = []

    def fake_fit(stage, params, free, **_):
        calls.append(type(stage).__name__)
        if len(calls) == 3 and not getattr(fake_fit, "resumed", False):
            raise KeyboardInterrupt  # Ctrl-C in the third stage
        value = free[0].value(params) * 1.01
        name = free[0].name
        section, _, key = name.partition(".")
        return type("R", (), {"params": params.replace(**{section: {key: value}})})()

    monkeypatch.setattr(fitting, "fit", fake_fit)
    monkeypatch.setattr(fitting, "evaluate", lambda stage, ps, ex: [np.zeros(3)])
    out = tmp_path / "cal.toml"
    with pytest.raises(KeyboardInterrupt):
        cal.calibrate(out=out, jobs=1, progress=False)
    assert cal.checkpoint_path(out).exists() and not out.exists()
    fake_fit.resumed = True
    resumed = cal.calibrate(out=out, jobs=1, progress=False, resume=True)
    assert calls[3:] == ["StaticStage", "DynamicStage", "StaticStage"]  # stages 3-5 only
    calls.clear()
    whole = cal.calibrate(out=tmp_path / "whole.toml", jobs=1, progress=False)
    assert len(calls) == 5 and resumed.fitted == whole.fitted
    assert not cal.checkpoint_path(out).exists()  # removed once the fit is written
