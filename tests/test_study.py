"""Design-space studies: sampling, flagged rows, executors, resume (wpam_mj.design.study)."""

from __future__ import annotations

import csv
import sys
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest

from wpam_mj.infra import pool
from wpam_mj.design import sampling, study, study_spec, study_table
from wpam_mj.cli import main
from wpam_mj.infra.pool import Workers, open_workers
from wpam_mj.physics.params import preset
from wpam_mj.errors import ParameterError
from wpam_mj.simulation.execution import execute
from wpam_mj.experiments.paper_studies import StepTask

# A small study: 6 seeded random step runs of 33 s (3 s plateaus, the shortest a study
# takes), 2 runs per task, varying the load, a model parameter and the controller.
SMALL = {
    "experiment": "step",
    "batch_size": 2,
    "fixed": {"duration": 33.0},
    "vary": {"method": "random", "n": 6, "seed": 7,
             "ranges": {"load": [50.0, 150.0], "muscle": {"damping": [300.0, 900.0]}},
             "values": {"controller": ["pi", "open"]}},
}


def _run(tmp_path, name, workers, spec=SMALL, **kw):
    return study.run_study(study_spec.parse_spec(spec), tmp_path / name, workers, **kw)


def _bytes(path):
    """The table files (study.csv, and study.parquet when pyarrow is installed)."""
    return {p.name: p.read_bytes() for p in path.glob("study.*")}


def test_grid_order_and_list_pairs():
    spec = study_spec.parse_spec({"experiment": "sine", "vary": {"method": "grid", "values": {
        "load": [50, 150], "controller": {"po_cap": [6e4, 8e4, 1e5]}}}})
    runs = sampling.sample(spec)
    assert len(runs) == 6
    assert [r["controller.po_cap"] for r in runs[:3]] == [6e4, 8e4, 1e5]  # last varies fastest
    assert [r["load"] for r in runs] == [50.0] * 3 + [150.0] * 3
    spec = study_spec.parse_spec({"experiment": "sine", "vary": {"method": "list", "values": {
        "load": [50, 150], "frequency": [0.2, 1.0]}}})
    assert sampling.sample(spec) == [{"load": 50.0, "frequency": 0.2},
                                  {"load": 150.0, "frequency": 1.0}]


def test_latin_hypercube_fills_every_stratum_once():
    n = 20
    spec = study_spec.parse_spec({"experiment": "step", "vary": {
        "method": "lhs", "n": n, "seed": 3,
        "ranges": {"load": [50.0, 150.0], "pneumatics.dead_time": [0.0, 0.01]}}})
    runs = sampling.sample(spec)
    for name, (lo, hi) in spec.ranges.items():
        strata = np.floor((np.array([r[name] for r in runs]) - lo) / (hi - lo) * n)
        assert sorted(strata) == list(range(n))
    assert sampling.sample(spec) == runs  # the seed fixes the sample


def test_random_sample_stays_in_range_and_depends_on_seed():
    data = {"experiment": "sine", "vary": {"method": "random", "n": 50, "seed": 1,
                                           "ranges": {"frequency": [0.1, 1.0]},
                                           "values": {"controller": ["pi", "pid"]}}}
    runs = sampling.sample(study_spec.parse_spec(data))
    f = np.array([r["frequency"] for r in runs])
    assert f.min() >= 0.1 and f.max() < 1.0
    assert {r["controller"] for r in runs} == {"pi", "pid"}
    data["vary"]["seed"] = 2
    assert sampling.sample(study_spec.parse_spec(data)) != runs


@pytest.mark.parametrize("data, words", [
    ({"experiment": "step", "vary": {"values": {"muscle.stiffness": [1.0]}}},
     "muscle.stiffness"),
    ({"experiment": "step", "vary": {"values": {"load": [5000.0]}}}, "load = 5000.0"),
    ({"experiment": "step", "vary": {"values": {"frequency": [0.5]}}}, "frequency"),
    ({"experiment": "step", "vary": {"method": "lhs", "ranges": {"load": [50, 60]}}}, "vary.n"),
    ({"experiment": "step", "vary": {"values": {"load": [50, 60], "controller": ["pi"]},
                                     "method": "list"}}, "one length"),
    ({"experiment": "walk", "vary": {"values": {"load": [50]}}}, "experiment"),
])
def test_bad_study_files_name_the_problem(data, words):
    with pytest.raises(ParameterError, match=words.replace(".", r"\.")):
        study_spec.parse_spec(data)


def test_diverged_and_infeasible_runs_are_flagged_rows(tmp_path):
    spec = {"experiment": "sine", "dt": 0.005, "fixed": {"frequency": 2.0},
            "vary": {"method": "list", "values": {
                "pneumatics.inner_conductance": [1e-6, 3.851e-9, 3.851e-9],
                "pneumatics.tube_volume": [1e-7, 2e-5, 2e-5],
                "controller.po_feedforward": [5e3, 2e4, 5e3],
                "controller.po_cap": [8e4, 8e3, 8e4]}}}  # 8 kPa < po_feedforward
    rows = _run(tmp_path, "out", Workers(None, 1, "here"), spec).rows
    # a chamber too fast for dt is refused up front (it used to diverge), naming the dt
    assert [(r["diverged"], r["infeasible"]) for r in rows] == \
        [(False, True), (False, True), (False, False)]
    assert np.isnan(rows[0]["gain"]) and np.isnan(rows[1]["gain"])
    assert "use dt <=" in rows[0]["error"] and "po_feedforward" in rows[1]["error"]
    assert 0.0 < rows[2]["gain"] < 1.5 and rows[2]["error"] == ""


def test_identical_tables_from_one_two_jobs_and_dask(tmp_path):
    distributed = pytest.importorskip("distributed")
    with open_workers(1) as w:
        one = _run(tmp_path, "jobs1", w)
    with open_workers(2) as w:
        _run(tmp_path, "jobs2", w)
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as cluster, \
            open_workers(1, cluster.scheduler_address) as w:
        assert w.slots == 2
        _run(tmp_path, "dask2", w)
    assert len(one.rows) == 6 and not any(r["diverged"] or r["error"] for r in one.rows)
    # the controller matters: open-loop plateaus miss by more than PI ones
    err = {c: max(r["plateau_error_rms_mm"] for r in one.rows if r["controller"] == c)
           for c in ("pi", "open")}
    assert err["open"] > err["pi"]
    assert _bytes(tmp_path / "jobs1") == _bytes(tmp_path / "jobs2") == _bytes(tmp_path / "dask2")


def test_resume_redoes_only_missing_runs_and_ends_with_the_same_table(tmp_path):
    workers = Workers(None, 1, "here")
    full = _run(tmp_path, "out", workers)
    before = _bytes(tmp_path / "out")
    parts = sorted((tmp_path / "out" / study_table.PARTS).glob("runs_*.csv"))
    assert len(parts) == 3  # batch_size 2
    parts[1].unlink()  # as if interrupted before this batch finished
    (tmp_path / "out" / "study.csv").unlink()
    again = _run(tmp_path, "out", workers, resume=True)
    assert (again.ran, again.reused) == (2, 4)
    assert _bytes(tmp_path / "out") == before and again.rows == full.rows
    assert "study.csv" in before
    changed = {**SMALL, "fixed": {"duration": 44.0}}
    with pytest.raises(ParameterError, match="different study"):
        _run(tmp_path, "out", workers, changed, resume=True)


def test_tasks_run_on_any_executor():
    params = preset("wpam")
    tasks = [StepTask(params, load, "pi", 5e-3) for load in (60.0, 140.0)]
    with ThreadPoolExecutor(2) as pool:
        on_pool = execute(tasks, pool)
    serial = execute(tasks)
    for a, b in zip(on_pool, serial):
        np.testing.assert_array_equal(a.x_mean, b.x_mean)


def test_scheduler_without_dask_is_one_line(monkeypatch):
    monkeypatch.setitem(sys.modules, "distributed", None)  # import fails
    with pytest.raises(ParameterError, match=r'pip install "\.\[cluster\]"'):
        with open_workers(2, "tcp://127.0.0.1:1"):
            pass
    monkeypatch.setenv(pool.SCHEDULER_ENV, "tcp://example:8786")
    assert pool.scheduler_address(None) == "tcp://example:8786"


def test_cli_study_writes_table_and_plots(tmp_path, capsys):
    spec = tmp_path / "s.toml"
    spec.write_text('experiment = "step"\n[fixed]\nduration = 33.0\n'
                    '[vary]\nvalues = {load = [60, 120]}\n')
    assert main(["study", str(spec), "--out", str(tmp_path / "o"), "--jobs", "1"]) == 0
    with open(tmp_path / "o" / "study.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert [r["load_n"] for r in rows] == ["60.0", "120.0"]
    assert (tmp_path / "o" / "plots" / "load_n.png").stat().st_size > 0
    spec.write_text('experiment = "step"\n[vary]\nvalues = {load = [0.5]}\n')
    assert main(["study", str(spec), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "load = 0.5" in err


def test_without_pyarrow_the_table_is_csv_only(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "pyarrow", None)
    res = _run(tmp_path, "out", Workers(None, 1, "here"), {**SMALL, "vary": {
        "method": "grid", "values": {"load": [80.0]}}})
    assert [p.name for p in res.files] == ["study.csv"]
    assert not (tmp_path / "out" / "study.parquet").exists()
