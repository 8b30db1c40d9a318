"""The global search on a cheap stand-in for the paper's targets: seeded and
deterministic, journaled, resumable without rerunning, and its archive a feasibility map;
its quasi-static screen against the simulated Table 2 row. The paper's own targets take
minutes per generation: scripts/global_search.py."""

from __future__ import annotations

import json

import dataclasses

import numpy as np
import pytest

from wpam_mj import paper
from wpam_mj.cli import main
from wpam_mj.reproduction import findings_map
from wpam_mj.reproduction import search, search_outputs
from wpam_mj.reproduction import search_scoring as scoring
from wpam_mj.physics.params import preset
from wpam_mj.errors import ParameterError
from wpam_mj.experiments.protocol import (SHIPPED, ProtocolStaticTask, quasi_static_po_row)


class _Task:
    cost = 1.0

    def __init__(self, value: float) -> None:
        self.value = value

    def run(self) -> float:
        _Task.runs += 1
        return self.value


_Task.runs = 0


class _Targets:
    """Two findings that conflict (a high and a low Kf) and the rest met by a low mu."""

    def __init__(self, protocol) -> None:
        self.protocol = protocol

    def tasks(self, params):
        return [_Task(params.muscle.output_coeff), _Task(params.muscle.friction_coeff)]

    def calibration_tasks(self, params):
        return []  # the controller's model: the nominal values

    def calibrated(self, params, results):
        return params, self

    def score(self, params, results):
        kf, mu = results
        margins = dict.fromkeys(scoring.FINDINGS, 0.2 - mu)
        margins["table2_po_row"] = kf - 0.8
        margins["gain_spread"] = 0.7 - kf
        r = np.array([max(0.0, -m) for m in margins.values()])
        return r, margins, {"step_error_mm": {"pi": [0.1]}, "table2_po_row": [kf, mu, 0.06]}


def _fit(params, protocol):
    """A stand-in static screen: points with F_f0 above 25 N miss the row by 50 %."""
    return params, protocol, 0.5 if params.muscle.friction_const > 25.0 else 0.0


def _search(tmp_path, **kw):
    kw = {"popsize": 1, "maxiter": 2, "targets": _Targets, **kw}
    return search.search(tmp_path, jobs=1, progress=False, fit=_fit, **kw)


def _simulated(records):
    return [r for r in records if not (r.figures or {}).get("static_error")]


def test_search_is_seeded_journaled_and_resumes_without_rerunning(tmp_path):
    _Task.runs = 0
    first = _search(tmp_path / "a")
    simulated = _simulated(first.records)
    assert 0 < len(simulated) < first.evaluations  # the screen spared some points
    assert _Task.runs == 2 * len(simulated)
    assert all(r.cost >= search.STATIC_MISS_COST for r in first.records
               if r not in simulated)
    header, *lines = (tmp_path / "a" / "journal.jsonl").read_text().splitlines()
    assert json.loads(header)["settings"]["seed"] == 20
    assert len(lines) == first.evaluations and json.loads(lines[0])["margins"]
    again = _search(tmp_path / "b")
    assert again.best == first.best  # same seed, same search
    # an interrupted journal (half its lines, the last one cut) resumes to the same end
    cut = [header, *lines[:len(lines) // 2], lines[len(lines) // 2][:10]]
    (tmp_path / "b" / "journal.jsonl").write_text("\n".join(cut) + "\n")
    _Task.runs = 0
    resumed = _search(tmp_path / "b", resume=True)
    assert resumed.best == first.best
    replayed = {json.loads(line)["key"] for line in lines[:len(lines) // 2]}
    rerun = [r for r in _simulated(first.records)
             if search._key(r.u) not in replayed]
    assert _Task.runs == 2 * len(rerun)
    with pytest.raises(ParameterError, match="no journal"):
        _search(tmp_path / "c", resume=True)


def test_the_archive_maps_which_findings_conflict(tmp_path):
    records = _search(tmp_path).records
    pm = findings_map.pair_margins(records)
    i, j = scoring.FINDINGS.index("table2_po_row"), scoring.FINDINGS.index("gain_spread")
    assert pm[i, i] > 0 and pm[j, j] > 0 and pm[i, j] < 0  # each alone, never together
    assert ("table2_po_row", "gain_spread", pm[i, j]) in findings_map.conflicts(pm)
    assert findings_map.best_compromise(records).cost == min(r.cost for r in records)
    assert findings_map.most_findings(records).held == max(r.held for r in records)
    assert "while F1" in findings_map.markdown(pm, records)
    assert findings_map.figure(pm, tmp_path / "map.png", "test").stat().st_size > 1000


def test_the_rest_map_finds_the_finding_the_others_leave_open(tmp_path):
    """With every other finding held, the stand-in's gain spread misses (its Kf must be
    above 0.8 for the row and below 0.7 for the spread): the rest map says so, and says
    the row holds wherever the others do once Kf is low."""
    records = _search(tmp_path).records
    rest = findings_map.rest_margins(records)
    assert rest["gain_spread"] < 0.0
    assert "With every other finding held" in findings_map.rest_verdict(records)
    n, most, missed = findings_map.held_with(records, "gain_spread")
    assert n == sum(r.margins["gain_spread"] >= 0.0 for r in records if r.tracks) > 0
    assert "table2_po_row" in missed and most == len(scoring.PAPER_CHECKS) - len(missed)


def test_the_checks_objective_counts_each_shortfall_once_and_caps_it():
    margins = dict.fromkeys(scoring.FINDINGS, 1.0)
    met = scoring.Record((0.5,), 7.0, margins, {})
    assert scoring.shortfall(met) == 0.0  # calibrate's cost may still be 7
    one = scoring.Record((0.5,), 7.0, {**margins, "gain_spread": -0.4}, {})
    assert scoring.shortfall(one) == pytest.approx(0.4 + paper.CALIBRATION_HEADROOM)
    far = scoring.Record((0.5,), 7.0, {**margins, "steps_settle": -50.0}, {})
    assert scoring.shortfall(far) == scoring.SHORTFALL_CAP
    failed = scoring.Record((0.5,), scoring.FAILED_COST, None, None)
    assert scoring.shortfall(failed) == scoring.FAILED_COST
    falls = scoring.Record((0.5,), 7.0, {**margins, "po_cap_light_slow": -0.5}, {})
    assert scoring.shortfall(falls) == 0.0  # "checks" may trade an extra away ...
    assert scoring.findings_shortfall(falls) == pytest.approx(  # ... "findings" may not
        0.5 + paper.CALIBRATION_HEADROOM)


def test_a_search_on_the_checks_objective_is_seeded_and_converges_on_it(tmp_path):
    first = _search(tmp_path / "a", objective="checks")
    assert first.best == _search(tmp_path / "b", objective="checks").best
    conv = search.convergence(first.records, "checks")
    assert conv[-1][1] == min(scoring.shortfall(r) for r in first.records)
    assert all(a[1] >= b[1] for a, b in zip(conv, conv[1:]))
    with pytest.raises(ParameterError, match="objective = 'count' must be one of"):
        _search(tmp_path / "c", objective="count")
    written = search_outputs.write_outputs(tmp_path / "a", first.records, preset("wpam"),
                                           objective="checks")
    assert {p.name for p in written} >= {"best.toml", "convergence.png", "feasibility.md"}


def test_convergence_is_the_running_best_in_scoring_order(tmp_path):
    records = _search(tmp_path).records
    conv = search.convergence(records)
    assert [c[0] for c in conv] == list(range(1, len(records) + 1))
    assert all(a[1] >= b[1] and a[2] <= b[2] for a, b in zip(conv, conv[1:]))
    assert conv[-1][2] == max(r.held for r in records if r.tracks)
    seconds = [c[3] for c in conv]  # the wall clock each point was scored at
    assert all(t >= 0.0 for t in seconds) and seconds == sorted(seconds)
    assert findings_map.convergence_csv(conv).splitlines()[0].endswith(",seconds")
    # a point whose staircase does not follow its targets meets checks vacuously: not counted
    idle = scoring.Record((0.5,), 0.0, dict.fromkeys(scoring.FINDINGS, 1.0),
                          {"step_error_mm": {"pi": [scoring.TRACK_MM + 1.0]}})
    assert search.convergence([idle])[0][2] == 0
    assert conv[-1][1] == min(r.cost for r in records)


def test_the_quasi_static_row_is_the_slow_ramp_limit_of_the_simulated_one():
    """The screen's premise: the equilibrium model's play operator gives the simulated
    Table 2 "Po = 0.04" row in the limit of slow ramps (the muscle's air has time to follow
    its regulators): 240 s ramps come within 2 % of it, closer than the shipped 60 s ones,
    which stay within the screen's tolerance with room to spare (a few per cent)."""
    params = preset("wpam")
    quasi = quasi_static_po_row(params, SHIPPED)
    for load in paper.LOADS_N:
        errors = []
        for protocol in (SHIPPED, dataclasses.replace(SHIPPED, ramp_time=240.0)):
            areas = [ProtocolStaticTask(params, load, po, 1e-3, protocol).run().area
                     for po in (0.0, paper.PO_DOWN_STATIC_MPA * 1e6)]
            errors.append(abs(areas[1] / areas[0] / quasi[load] - 1.0))
        shipped, slow = errors
        assert slow < 0.02 and slow <= shipped + 1e-3, (load, errors)
        assert shipped < paper.TABLE2_PO_RTOL / 2, (load, errors)


def test_the_static_fit_brings_a_scrambled_point_back_to_the_row():
    """With friction coefficient, axial area and ramp top moved to their range's ends,
    the fit finds values inside the plausible ranges that meet the row on the
    quasi-static loops."""
    params = preset("wpam").with_values({"muscle.friction_coeff": 0.45,
                                         "muscle.axial_area": 1e-4})
    protocol = dataclasses.replace(SHIPPED, ramp_top=0.45e6)
    fitted, fitted_protocol, err = search.static_fit(params, protocol)
    assert err <= paper.TABLE2_PO_RTOL
    assert 0.0 <= fitted.muscle.friction_coeff <= 0.5
    assert 0.0 <= fitted.muscle.axial_area <= 2.8e-3
    assert 0.08e6 <= fitted_protocol.ramp_top <= 0.45e6
    row = quasi_static_po_row(fitted, fitted_protocol)
    assert all(abs(row[f] / paper.TABLE2["open_po"][f] - 1.0) <= err + 1e-9
               for f in paper.LOADS_N)


def test_coordinates_round_trip():
    base = preset("wpam")
    u = search.coordinates_of(base)
    point = search._point_task((tuple(u), base, search.Region(search.GLOBAL.names, _fit)))
    assert point.protocol == SHIPPED
    for d in search.SPACE:
        assert point.params.value(d.name) == pytest.approx(base.value(d.name), rel=1e-12)


def test_a_local_search_varies_only_the_readings_it_frees_and_starts_at_the_base(tmp_path):
    base = preset("wpam")
    free = ("pneumatics.outer_conductance", "controller.po_feedforward")
    r = _search(tmp_path, free=free, radius=0.1)
    z0 = search.coordinates_of(base, search.local_region(free))
    assert r.records[0].u == pytest.approx(tuple(z0))  # DE's first member: the base point
    for rec in r.records:
        assert len(rec.u) == 2 and all(abs(u - z) <= 0.1 + 1e-12 for u, z in zip(rec.u, z0))
    point = search.point_of(r.best.u, base, search.Region(free, _fit))
    changed = {n for n in search.FREE if point.params.value(n) != base.value(n)}
    assert changed <= set(free)
    for bad in ("muscle.friction_coeff", "controller.kp"):
        with pytest.raises(ParameterError, match=f"--free {bad}"):
            search.local_region([bad])


def test_the_command_line_states_the_search_defaults():
    """`wpam search --help` spells these numbers out (wpam_mj/cli/reproduction.py)."""
    assert (search.POPSIZE, search.MAXITER, len(search.SPACE)) == (3, 8, 7)
    assert search.planned_evaluations(search.POPSIZE, search.MAXITER) == 190


@pytest.mark.parametrize("other, differs", [
    ({"seed": 21}, "--seed 20 there, 21 here"),
    ({"free": ("pneumatics.outer_conductance",)},
     "--free not given there, pneumatics.outer_conductance here"),
    ({"feedforward": "nominal"}, "--feedforward-model calibrated there, nominal here"),
    ({"base": preset("wpam").with_values({"muscle.damping": 55.0})},
     "parameter muscle.damping = ")])
def test_resume_refuses_the_journal_of_another_search(tmp_path, other, differs):
    """A journal names the search it holds: resuming it with another seed, region or base
    point would mix two searches in one journal; it is refused and left as it was."""
    _search(tmp_path)
    journal = (tmp_path / "journal.jsonl").read_bytes()
    with pytest.raises(ParameterError, match="--resume: the journal .* is of another "
                       f"search \\({differs}"):
        _search(tmp_path, resume=True, **other)
    assert (tmp_path / "journal.jsonl").read_bytes() == journal
    _search(tmp_path, resume=True, maxiter=3)  # more generations extend the same search
    with pytest.raises(ParameterError, match="--popsize 1 there, 2 here"):
        _search(tmp_path, resume=True, popsize=2)


def test_a_journal_from_before_the_controllers_model_was_recorded_searched_the_nominal(
        tmp_path):
    """Journals written before `wpam search` fitted the controller's model have no
    "feedforward" setting: their points were scored with the nominal model."""
    _search(tmp_path, feedforward="nominal")
    path = tmp_path / "journal.jsonl"
    first, *rest = path.read_text().splitlines()
    settings = json.loads(first)
    del settings["settings"]["feedforward"]
    path.write_text("\n".join([json.dumps(settings), *rest]) + "\n")
    _search(tmp_path, resume=True, feedforward="nominal")
    with pytest.raises(ParameterError, match="--feedforward-model nominal there"):
        _search(tmp_path, resume=True)


def test_radius_without_free_is_refused():
    with pytest.raises(ParameterError, match="--radius 0.1: only a local search"):
        _search(None, radius=0.1)


@pytest.mark.parametrize("argv, says", [
    (["--map-only"], "no journal"),
    (["--resume"], "no journal"),
    (["--radius", "0.1"], "--radius 0.1: only a local search"),
    (["--map-only", "--radius", "0.1"], "--radius 0.1: only a local search")])
def test_search_command_refuses_in_one_line_and_writes_nothing(tmp_path, capsys, argv, says):
    out = tmp_path / "new"
    code = main(["search", *argv, "--out", str(out), "--jobs", "1"])
    _, err = capsys.readouterr()
    assert code == 2 and len(err.strip().splitlines()) == 1 and says in err, err
    assert not out.exists()


def test_search_command_refuses_to_resume_or_map_another_search(tmp_path, capsys):
    _search(tmp_path)  # seed 20 on the wpam preset, as the command's defaults
    journal = (tmp_path / "journal.jsonl").read_bytes()
    for argv, says in ((["--resume", "--seed", "21"], "--seed 20 there, 21 here"),
                       (["--map-only", "--free", "controller.po_feedforward"],
                        "--free not given there, controller.po_feedforward here")):
        code = main(["search", *argv, "--out", str(tmp_path), "--jobs", "1"])
        _, err = capsys.readouterr()
        assert code == 2 and len(err.strip().splitlines()) == 1 and says in err, err
    assert (tmp_path / "journal.jsonl").read_bytes() == journal
    assert sorted(p.name for p in tmp_path.iterdir()) == ["journal.jsonl"]


class _PlantTargets(_Targets):
    """The stand-in, run on the simulated plant (its `plant_deviation` applied)."""

    def tasks(self, params):
        return super().tasks(params.plant)


def test_a_robust_search_keeps_each_findings_worst_margin_over_sampled_plants(tmp_path):
    """--robust K scores a point on itself and K plants within +-5 % of its unmeasured
    values: every margin is the worst of them, so never above the nominal point's, and
    below it where the finding depends on a deviated value (Kf here)."""
    nominal = _search(tmp_path / "n", targets=_PlantTargets)
    robust = _search(tmp_path / "r", targets=_PlantTargets, robust=3)
    first_n, first_r = nominal.records[0], robust.records[0]
    assert first_n.u == first_r.u  # the same seeded first population
    assert all(first_r.margins[f] <= first_n.margins[f] for f in first_n.margins)
    assert first_r.margins["table2_po_row"] < first_n.margins["table2_po_row"]
    with pytest.raises(ParameterError, match="robust"):  # a journal of another search
        _search(tmp_path / "r", targets=_PlantTargets, robust=5, resume=True)


class _FailedRun:
    cost = 1.0

    def run(self):
        raise ParameterError("the calibration ramp failed")


class _CalibratedTargets(_PlantTargets):
    """The stand-in with its controller's model fitted first: one calibration run reads
    the plant's Kf, the model takes it, and "pid_leads_pi" is the model's error."""

    model_kf = None

    def calibration_tasks(self, params):
        kf = params.plant.muscle.output_coeff
        return [_FailedRun() if kf > 0.95 else _Task(kf)]

    def calibrated(self, params, results):
        fitted = _CalibratedTargets(self.protocol)
        fitted.model_kf = results[0]
        return params, fitted

    def score(self, params, results):
        r, margins, figures = super().score(params, results)
        model = params.muscle.output_coeff if self.model_kf is None else self.model_kf
        return r, {**margins, "pid_leads_pi": -abs(model - results[0])}, figures


class _NominalTargets(_CalibratedTargets):
    def calibration_tasks(self, params):
        return []

    def calibrated(self, params, results):
        return params, self


def test_each_plant_of_a_search_is_scored_with_the_model_fitted_to_its_own_runs(tmp_path):
    """The calibrated reading fits every plant's controller model to that plant's own
    runs before its closed-loop runs (here: exactly), a robust search's sampled plants
    too; with the nominal model the sampled plants' Kf is not the model's. A failed
    calibration run fails the point, as a failed closed-loop run does."""
    _Task.runs = 0
    fitted = _search(tmp_path / "c", targets=_CalibratedTargets, robust=3)
    nominal = _search(tmp_path / "n", targets=_NominalTargets, robust=3)
    ran = [r for r in _simulated(fitted.records) if r.margins is not None]
    assert ran and all(r.margins["pid_leads_pi"] == 0.0 for r in ran)
    assert all(r.margins["pid_leads_pi"] < 0.0 for r in _simulated(nominal.records)
               if r.margins is not None)
    failed = [r for r in _simulated(fitted.records) if r.margins is None]
    assert failed and all(r.cost == scoring.FAILED_COST for r in failed)


def test_worst_of_fails_a_point_when_one_plant_fails():
    good = (1.0, {"a": 0.2, "b": -0.1}, {"fig": 1})
    worse = (2.0, {"a": -0.3, "b": 0.4}, {"fig": 2})
    assert scoring.worst_of([good, worse]) == (2.0, {"a": -0.3, "b": -0.1}, {"fig": 1})
    assert scoring.worst_of([good, (scoring.FAILED_COST, None, None)])[1] is None
