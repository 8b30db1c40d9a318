"""Calibration: its parameters and bounds, its residuals on real runs, its random starts,
and the TOML it writes.

The fit itself runs for minutes (`wpam calibrate`); the search is the engine of
`wpam fit`, checked in tests/test_fitting.py (including resuming from a journal)."""

import math
from pathlib import Path

import numpy as np
import pytest

from wpam_mj import paper
from wpam_mj.reproduction import findings
from wpam_mj.fitting import estimation
from wpam_mj.reproduction.calibrate import (FREE, KEPT, READINGS, WEIGHTS, CalibrationResult,
                                            PaperTargets, calibrate, random_starts)
from wpam_mj.physics.params import apply_overrides, plausible_range, preset
from wpam_mj.errors import ParameterError, load_toml
from wpam_mj.units import MPA
from wpam_mj.reproduction.report import GIVEN_UP

# what `wpam reproduce` passes on the shipped point (docs/physics.md, "The shipped plant")
HELD = ("table2_po_row", "table2_feedback_row", "table2_shape", "pressures_rise_with_load",
        "gain_falls_lag_grows", "lag_order_low_freq", "pid_leads_pi", "po_reaches_cap",
        "po_cap_light_slow")


@pytest.mark.parametrize("name", FREE)
def test_fitted_parameters_are_bounded_by_their_plausible_range(name):
    p = estimation.FreeParameter.of(name)
    assert (p.lo, p.hi) == plausible_range(name)


@pytest.fixture(scope="module")
def shipped_runs():
    """PaperTargets' runs at the shipped parameters (39 runs, ~6 s)."""
    params, model = preset("wpam"), PaperTargets()
    return params, model, [t.run() for t in model.tasks(params)]


@pytest.fixture(scope="module")
def shipped(shipped_runs):
    """PaperTargets' scores and residuals at the shipped parameters."""
    params, model, results = shipped_runs
    return (model.scores(params, results), model.residual_groups(params, results),
            model.residuals(params, results))


def test_calibrated_targets_score_the_model_fitted_to_the_plants_own_loops():
    """`wpam calibrate`'s default scores each set as `wpam reproduce` does: its six open
    loops first, the controller's model fitted to them (the model `calibrate_one` fits),
    then its closed-loop runs; the residuals are PaperTargets' of that model on them."""
    from wpam_mj.experiments.protocol import SHIPPED
    from wpam_mj.reproduction import feedforward_fit
    from wpam_mj.reproduction.calibrate import CalibratedTargets

    params = preset("wpam")
    targets = CalibratedTargets(PaperTargets())
    (task,) = targets.tasks(params)
    model, loops, runs = result = task.run()
    assert model == feedforward_fit.calibrate_one(params, SHIPPED, 1e-3, 2).params
    assert model != params  # the controller reads the fit; the plant stays the plant:
    for name in feedforward_fit.FEEDFORWARD_MODEL:
        assert model.plant.value(name) == pytest.approx(params.value(name), rel=1e-12)
    reproduce = PaperTargets(open_loops=loops)
    assert np.array_equal(targets.residuals(params, [result]), reproduce.residuals(model, runs))
    assert targets.scores(params, [result]).text() == reproduce.scores(model, runs).text()


def test_the_shipped_point_holds_its_findings_and_explains_the_rest(shipped_runs):
    """Golden: the findings `wpam reproduce` passes on the shipped point still pass (both
    Table 2 rows, its shape, the staircases' plateau-mean Pi and Po rising with load, the
    gain's fall, the lag order at Fig. 17's resolution, PID's visible lead, the cap), and
    every finding it fails is one the report explains (`report.GIVEN_UP`)."""
    params, model, results = shipped_runs
    scores, table2 = model.scores_and_table2(params, results)
    checks = [*findings.table2_checks(table2), *scores.sweep_checks]
    passed = {c.finding for c in checks if c.passed}
    assert passed == {c.finding for c in checks if c.name in HELD}
    for c in checks:
        explained = c.name in GIVEN_UP
        assert explained != c.passed, c.finding


def test_residuals_are_the_log_errors_of_table2_and_hinges_of_the_targets(shipped):
    scores, groups, res = shipped
    assert np.array_equal(res, np.concatenate(list(groups.values())))
    row = [paper.TABLE2["open_po"][f] for f in paper.LOADS_N]
    assert np.allclose(groups["table2"],
                       [math.log(v / p) for v, p in zip(scores.table2_po_row, row)])
    assert set(scores.step_error_mm) == {"pi"}  # the paper ran its steps with PI only
    expected = [WEIGHTS.step * max(0.0, e - WEIGHTS.step_error_share * lim)
                for e, lim in zip(scores.step_error_mm["pi"], scores.step_limit_mm)]
    expected += [WEIGHTS.step * max(0.0, p - WEIGHTS.step_pp_mm)
                 for p in scores.step_pp_mm["pi"]]
    assert np.allclose(groups["steps"], expected)
    po = scores.po_plateau_mpa  # plateau-mean Po: costs only where it falls with load
    assert all((r > 0) == (a > b) for r, a, b in zip(groups["po_rise"], po, po[1:]))
    for name, r in groups.items():
        assert name == "table2" or np.all(r >= 0.0), name  # the rest are hinges


def test_po_cap_residual_is_the_shortfall_of_the_papers_margin(shipped):
    """Po reaches the cap at 150 N, 0.5 Hz: its margin costs its shortfall (plus the
    headroom) in units of 0.1 cap, computed here by hand from the sine's Po maximum."""
    scores, groups, _ = shipped
    cap = preset("wpam").controller.po_cap / MPA
    margin = (scores.po_max_mpa[(paper.FIG18_LOAD_N, paper.FIG18_FREQ_HZ)]
              - (1 - paper.PO_CAP_RTOL) * cap)
    expected = max(0.0, paper.CALIBRATION_HEADROOM - margin / (0.1 * cap))
    assert groups["sweep.po_reaches_cap"] == pytest.approx([expected], abs=1e-9)


def test_the_cost_asks_the_papers_sentences_and_no_extra(shipped):
    """An extra (a reading no sentence states) is reported, never fitted to: no residual
    group is one; every counted §4.2 finding is, and costs wherever it fails."""
    scores, groups, _ = shipped
    sweep = {k[len("sweep."):]: v for k, v in groups.items() if k.startswith("sweep.")}
    assert set(sweep) == {c.name for c in scores.sweep_checks if c.counted}
    assert not any(findings.FINDINGS[name].counted is False for name in sweep)
    for c in scores.sweep_checks:
        if c.counted:
            assert (sweep[c.name] > 0.0).any() or c.passed, c.name


def test_random_starts_are_seeded_inside_the_plausible_ranges():
    start = preset("wpam")
    a, b, c = (random_starts(start, 20, s) for s in (3, 3, 4))
    assert a == b and a != c and a[0] == start and len(a) == 21
    for p in a[1:]:
        assert p.controller.command_scale in READINGS
        for name in FREE:
            lo, hi = plausible_range(name)
            assert lo <= estimation.FreeParameter.of(name).value(p) <= hi


@pytest.mark.parametrize("kwargs, match", [
    (dict(samples=-1), "samples"), (dict(max_nfev=0), "max_nfev"), (dict(seed=-2), "seed")])
def test_bad_settings_are_refused_in_one_line(kwargs, match):
    with pytest.raises(ParameterError, match=match):
        calibrate(out=None, progress=False, **kwargs)


def test_resume_without_a_journal_is_refused(tmp_path):
    with pytest.raises(ParameterError, match="no journal"):
        calibrate(out=tmp_path / "fit.toml", progress=False, resume=True)


def test_written_toml_reproduces_the_fitted_parameters(tmp_path, shipped):
    free = [estimation.FreeParameter.of(n) for n in FREE[:5]]  # the static ones
    params = estimation.with_values(preset("wpam"), free, [0.36, 0.7, 0.2, 3.0, 1e-3])
    fitted = {n: params.value(n) for n in (*FREE, *KEPT)}
    result = CalibrationResult(params, fitted, 1.0, 2.0, shipped[0], 10, 60.0)
    path = tmp_path / "fit.toml"
    path.write_text(result.toml())
    assert apply_overrides(preset("wpam"), load_toml(path)) == params
    assert "Table 2 'Po = 0.04' row" in result.table()


class _Values:
    """A cheap stand-in for the simulator runs: the free values themselves."""

    def __init__(self, params):
        self.values = [params.value(n) for n in FREE]

    def run(self):
        return self.values


class _Quadratic:
    """A stand-in for PaperTargets whose optimum is known: each free parameter's scaled
    distance from a target point; counts the parameter sets it is asked to run."""

    runs = 0
    stop_after: int | None = None

    def __init__(self, dt, protocol):
        self.target = [estimation.FreeParameter.of(n).from_z(0.3) for n in FREE]

    def tasks(self, params):
        type(self).runs += 1
        if self.stop_after is not None and type(self).runs > self.stop_after:
            raise KeyboardInterrupt  # Ctrl-C in the middle of the fit
        return [_Values(params)]

    def residuals(self, params, results):
        free = [estimation.FreeParameter.of(n) for n in FREE]
        return np.array([(v - t) / (p.hi - p.lo)
                         for p, v, t in zip(free, results[0], self.target)])

    def scores(self, params, results):
        return "scores"


def test_an_interrupted_calibration_resumes_from_its_journal(tmp_path, monkeypatch):
    """Ctrl-C mid-fit keeps the journal; --resume replays it without running those sets
    again and ends exactly where an uninterrupted calibration does."""
    import wpam_mj.reproduction.calibrate as cal

    monkeypatch.setattr(cal, "PaperTargets", _Quadratic)
    out = tmp_path / "fit.toml"
    _Quadratic.runs, _Quadratic.stop_after = 0, 15
    with pytest.raises(KeyboardInterrupt):
        cal.calibrate(out=out, jobs=1, progress=False, max_nfev=4, feedforward="nominal")
    assert cal.journal_path(out).exists() and not out.exists()
    journaled = estimation.ResidualJournal(cal.journal_path(out), keep=True).size
    _Quadratic.runs, _Quadratic.stop_after = 0, None
    resumed = cal.calibrate(out=out, jobs=1, progress=False, max_nfev=4, resume=True,
                            feedforward="nominal")
    rerun = _Quadratic.runs
    assert not cal.journal_path(out).exists()  # removed once the fit is written
    _Quadratic.runs = 0
    whole = cal.calibrate(out=tmp_path / "whole.toml", jobs=1, progress=False, max_nfev=4,
                          feedforward="nominal")
    assert resumed.fitted == whole.fitted
    assert out.read_text() == (tmp_path / "whole.toml").read_text()
    assert rerun == _Quadratic.runs - journaled  # the journaled sets were not run again


def test_the_plateau_limit_is_the_split_that_meets_the_papers_feedback_cell():
    """A PI staircase whose way down sits `plateau_error_limit` above its way up encloses
    the paper's own feedback cell of the open-loop area (the loop of the plateau means,
    Fig. 16)."""
    from types import SimpleNamespace

    from wpam_mj.experiments.analysis import loop_area

    levels = np.array(paper.STEP_LEVELS_MM, dtype=float) * 1e-3
    pi_mean = 0.05e6 + 2e6 * levels  # Pi rises with the target, 0.05-0.15 MPa
    open_area = 3.5e3  # Pa m, the order of the 150 N loop
    t2 = SimpleNamespace(open_loops=[SimpleNamespace(load=150.0, area=open_area)],
                         feedback_runs=[SimpleNamespace(pi_mean=pi_mean)])
    (limit,) = findings.plateau_error_limit(t2).values()
    down = np.arange(levels.size) > int(np.argmax(levels))
    x_mean = levels + np.where(down, limit, 0.0)
    x_mean[int(np.argmax(levels))] += limit / 2  # the turning plateau halfway
    area = loop_area(pi_mean, x_mean)
    assert area / open_area == pytest.approx(paper.TABLE2["feedback"][150.0], rel=0.15)


class _PlantValue:
    """A model whose one task is its parameter set and whose residual is the friction
    coefficient of the plant it simulates."""

    def tasks(self, params):
        return [params]

    def residuals(self, params, results):
        return np.array([results[0].plant.value("muscle.friction_coeff")])


def test_a_robust_fit_stacks_the_residuals_of_the_point_and_its_sampled_plants():
    """`--robust K`: the point's residuals, then each sampled plant's (the plant deviated,
    its feedforward nominal), in the order of the seeded sample."""
    import wpam_mj.reproduction.calibrate as cal
    from wpam_mj.reproduction import robustness

    deviations = robustness.sample_deviations(3, robustness.ROBUST_SEED)
    model = cal.RobustTargets(_PlantValue(), deviations)
    params = preset("wpam")
    tasks = model.tasks(params)
    assert len(tasks) == 4 and tasks[0] is params
    mu = params.muscle.friction_coeff
    column = list(robustness.UNMEASURED).index("muscle.friction_coeff")
    expected = [mu, *(mu * (1.0 + d) for d in deviations[:, column])]
    assert model.residuals(params, tasks) == pytest.approx(expected, rel=1e-12)
    assert cal.journal_path(Path("fit.toml"), 3) != cal.journal_path(Path("fit.toml"))
