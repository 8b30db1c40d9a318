"""Inputs inside their ranges that ask for absurd work, results that
mean nothing, odd files and messages. Bad input is one line naming the value and the
allowed range, exit status 2, no traceback, no folder left behind."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from wpam_mj.experiments.feasibility import max_liftable_load

from wpam_mj.infra import budget
from wpam_mj.design import metrics, study
from wpam_mj.experiments import writers
from wpam_mj.cli import main
from wpam_mj.fitting.measured_fit import check_replay
from wpam_mj.experiments.drives import SineSpec, sine_run, step_run
from wpam_mj.fitting.measurements import Experiment, experiment_files, read_experiment
from wpam_mj.physics.params import preset
from wpam_mj.errors import ParameterError, check_range, load_toml
from wpam_mj.units import MPA
from wpam_mj.simulation.execution import Failed, execute

ROOT = Path(__file__).resolve().parents[1]
PARAMS = preset()
FAST = ("--dt", "0.005", "--no-progress", "--jobs", "1")
SLOW_LINE = "[pneumatics]\ninner_conductance = 1e-15\n"  # the inner chamber never fills


def _refused(capsys, *argv) -> str:
    """Run the CLI: exit 2, exactly one line on stderr; returns it."""
    code = main([str(a) for a in argv])
    err = capsys.readouterr().err
    assert code == 2, err
    assert err.count("\n") == 1 and err.startswith("wpam: error: "), err
    return err


@pytest.fixture
def here(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    return tmp_path


def _experiment(name: str = "run", t_end: float = 2.0, n: int = 21) -> Experiment:
    t = np.linspace(0.0, t_end, n)
    return Experiment(name=name, load=100.0, time=t, pi=np.full(n, 0.1 * MPA),
                      po=np.zeros(n), x=np.linspace(0.0, 0.01, n))


# ------------------------------------------------------------------ 3: absurd work

@pytest.mark.parametrize("argv", [
    ["sweep", "--freqs", "1e-6", "--loads", "100"],
    ["render", "--experiment", "sweep", "--freq", "1e-6"],
], ids=["sweep", "render"])
def test_a_frequency_asking_for_years_of_simulation_is_refused(here, capsys, argv):
    err = _refused(capsys, *argv, "--out", "o" if argv[0] == "sweep" else "o/v.mp4")
    assert "1e-06 Hz" in err and "at most 10000 s" in err and "0.0007 Hz" in err  # 7 cycles
    assert not (here / "o").exists()


def test_a_run_needing_more_memory_than_the_bound_is_refused_before_it_starts(here, capsys):
    err = _refused(capsys, "static", "--load", "100", "--ramp-time", "3600", "--dt", "1e-5",
                   "--jobs", "1", "--out", "o")
    assert "2 GB" in err and "7.2e+08 steps" in err
    assert not (here / "o").exists()


def test_a_gif_that_would_not_fit_in_memory_is_refused_before_rendering(here, capsys):
    err = _refused(capsys, "render", "--out", "v/x.gif", "--fps", "50", "--size", "1280x960",
                   "--dt", "0.005")
    assert "5500 frames" in err and "at most 2 GB" in err
    assert not (here / "v").exists()
    budget.check_video(3600.0, 120.0, (4096, 4096), ".mp4")  # streamed: no bound


def test_a_study_row_at_an_absurd_frequency_is_infeasible_not_a_crash():
    inputs = {"load": 100.0, "frequency": 1e-6, "amplitude": 0.025, "controller": "pi"}
    with pytest.raises(ParameterError, match="at most 10000 s"):
        metrics.MetricsTask("sine", PARAMS, inputs, 1e-3).run()


@pytest.mark.parametrize("line, text", [
    ("frequency = [0.5, 1e-6]", "at most 10000 s"),
    ("duration = [110, 36000]", "duration = 36000 s is outside the allowed range [33, 10000] s"),
], ids=["frequency", "duration"])
def test_a_study_file_asking_for_absurd_runs_is_refused_when_read(here, capsys, line, text):
    experiment = "sine" if "frequency" in line else "step"
    (here / "s.toml").write_text(f'experiment = "{experiment}"\n[vary.values]\n{line}\n')
    assert text in _refused(capsys, "study", "s.toml", "--out", "o")
    assert not (here / "o").exists()


def test_a_measurement_spanning_absurd_time_is_refused_on_reading(tmp_path):
    exp = _experiment(t_end=10.0, n=12)
    exp = Experiment(**{**exp.__dict__, "time": np.r_[exp.time[:-1], 5e6]})
    path = exp.to_csv(tmp_path / "long.csv")
    with pytest.raises(ParameterError, match=r"long\.csv .*5e\+06 s.* at most 10000 s"):
        read_experiment(path, PARAMS)


def test_a_replay_beyond_the_memory_bound_is_refused():
    check_replay(_experiment(t_end=5000.0, n=50), 1e-3)  # 5e6 steps: fine
    with pytest.raises(ParameterError, match="one run may use at most 2 GB"):
        check_replay(_experiment(t_end=5000.0, n=50), 1e-5)


def test_the_budget_passes_every_shipped_protocol_at_the_default_dt():
    for duration in (2 * 3600 + 2.0, 110.0, SineSpec(0.1).duration):
        assert budget.check_run("run", duration, 1e-3) == duration


# ------------------------------------------------------------------ 4: silent nonsense

@pytest.mark.parametrize("call, match", [
    (lambda: step_run(PARAMS, 1900.0, "pi"),
     rf"1900 N.*cannot lift.*\[1, {max_liftable_load(PARAMS):.1f}\] N"),
    (lambda: step_run(PARAMS, 100.0, "pi", levels_mm=(0, 500)), r"\[0, 500\] mm.*stroke"),
    (lambda: step_run(PARAMS, 100.0, "open", levels_mm=(-5, 10)), r"\[-5, 10\] mm"),
    (lambda: sine_run(PARAMS, 100.0, "pi", SineSpec(0.5, amplitude=0.03)), r"\[-5, 55\] mm"),
], ids=["unliftable", "500mm", "negative", "sine-beyond"])
def test_runs_that_cannot_mean_anything_are_refused(call, match):
    with pytest.raises(ParameterError, match=match):
        call()


def test_a_study_row_at_an_unliftable_load_is_infeasible():
    batch = study.RunBatch(PARAMS, "step", 5e-3, ("load",),
                           ((0, {"load": 100.0, "controller": "pi", "duration": 11.0}),
                            (1, {"load": 1900.0, "controller": "pi", "duration": 11.0})))
    ok, heavy = batch.rows(execute(batch.tasks(), failed=Failed))
    assert not ok["infeasible"] and np.isfinite(ok["plateau_error_max_mm"])
    assert heavy["infeasible"] and np.isnan(heavy["plateau_error_max_mm"])
    assert "cannot lift" in heavy["error"]


def test_a_study_row_whose_load_never_moved_is_infeasible():
    params = PARAMS.replace(pneumatics={"inner_conductance": 1e-15})
    inputs = {"load": 100.0, "controller": "pi", "duration": 11.0}
    with pytest.raises(ParameterError, match="never moved"):
        metrics.MetricsTask("step", params, inputs, 5e-3).run()


def test_a_feedback_step_whose_load_never_moved_is_flagged(here, capsys):
    (here / "slow.toml").write_text(SLOW_LINE)
    assert main(["step", "--control", "pi", "--config", "slow.toml", "--out", "o", "--json",
                 *FAST]) == 0
    out, err = capsys.readouterr()
    assert json.loads(out)["load_moved"] is False
    assert "never moved" in err and "step wpam 100 N pi" in err


def test_a_sweep_point_whose_load_never_moved_is_flagged_in_csv_json_and_text(here, capsys):
    (here / "slow.toml").write_text(SLOW_LINE)
    assert main(["sweep", "--loads", "100", "--freqs", "1", "--controllers", "pi",
                 "--config", "slow.toml", "--out", "o", *FAST]) == 0
    out = capsys.readouterr().out
    assert "note: sweep 100 N 1 Hz pi, analysed cycles: the load never moved" in out
    assert json.loads((here / "o" / "sweep.json").read_text())[0]["load_moved"] is False
    header, row = (here / "o" / "sweep.csv").read_text().splitlines()
    assert header.endswith(",load_moved") and row.endswith(",False")


def test_figures_carry_the_flag():
    from matplotlib.figure import Figure
    fig = writers.mark_still_on_figure(Figure(), ["static wpam 100 N"])
    assert any("never moved" in t.get_text() and "100 N" in t.get_text() for t in fig.texts)
    assert not writers.mark_still_on_figure(Figure(), []).texts


def test_a_muscle_that_lifts_nothing_says_so_instead_of_an_empty_range(here, capsys):
    (here / "weak.toml").write_text("[pneumatics]\np_max = 0.01e6\n[controller]\n"
                                    "po_cap = 0.005e6\npo_feedforward = 0.005e6\n")
    err = _refused(capsys, "step", "--load", "1", "--config", "weak.toml")
    assert "lifts no load of [1, 2000] N" in err and "[1, 0" not in err


# ------------------------------------------------------------------ 5: messages, odd files

def test_numpy_scalars_and_crossed_bounds_never_reach_a_message():
    with pytest.raises(ParameterError) as err:
        check_range("po", np.float64(-100.0), 0.0, 1.0, "Pa")
    assert "np." not in str(err.value) and "-100.0 Pa" in str(err.value)
    with pytest.raises(ParameterError, match=r"no value is allowed") as err:
        check_range("load", 5.0, 1.0, 0.0, "N")
    assert "[1, 0" not in str(err.value)


@pytest.fixture
def fifo(tmp_path):
    path = tmp_path / "pipe"
    os.mkfifo(path)
    return path


def test_a_named_pipe_as_config_is_refused_at_once(fifo):
    """Before: open() waited forever for a writer."""
    proc = subprocess.run([sys.executable, "-m", "wpam_mj", "step", "--config", str(fifo)],
                          capture_output=True, text=True, timeout=60,
                          env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert proc.returncode == 2
    assert proc.stderr == f"wpam: error: parameter file {fifo} is a named pipe, not a " \
                          "regular file\n"


@pytest.mark.parametrize("kind", ["fifo", "device", "folder"])
def test_odd_files_are_named_for_what_they_are(fifo, tmp_path, kind):
    path = {"fifo": fifo, "device": Path("/dev/zero"), "folder": tmp_path}[kind]
    what = {"fifo": "named pipe", "device": "device", "folder": "folder"}[kind]
    with pytest.raises(ParameterError, match=f"is a {what}, not a regular file"):
        load_toml(path)
    if kind != "folder":  # a folder of data is its *.csv
        with pytest.raises(ParameterError, match=f"is a {what}, not a regular file"):
            experiment_files([path])


def test_fit_data_that_is_a_device_is_one_line(capsys):
    assert "/dev/zero is a device" in _refused(capsys, "fit", "--data", "/dev/zero")


@pytest.mark.parametrize("argv, text", [
    (["synth", "--seed", "-1"], "--seed = -1 must be an integer in [0, "),
    (["synth", "--out", ""], "'' is empty"),
    (["fit", "--data", "x.csv", "--out", ""], "'' is empty"),
], ids=["seed", "synth-out", "fit-out"])
def test_bad_synth_and_fit_arguments_are_one_line_and_create_nothing(here, capsys, argv,
                                                                     text):
    assert text in _refused(capsys, *argv)
    assert not list(here.iterdir())


def test_the_same_file_as_data_and_holdout_is_refused(here, capsys):
    path = _experiment().to_csv(here / "run.csv")
    other = _experiment().to_csv(here / "elsewhere" / "run.csv")
    for holdout in (path, other):  # the same file; another file of the same name
        err = _refused(capsys, "fit", "--data", path, "--holdout", holdout, "--out",
                       "fit/p.toml")
        assert "'run' is given twice" in err
    assert not (here / "fit").exists()


@pytest.mark.parametrize("dt, text", [
    ("0.003", "dt = 0.003 s must divide the 0.01 s recording period"),
    ('"0.001"', "dt = '0.001' is not a number"),
    ("true", "dt = True is not a number"),
], ids=["not-dividing", "string", "bool"])
def test_a_study_file_dt_is_checked_as_the_command_line_checks_it(here, capsys, dt, text):
    (here / "s.toml").write_text(f'experiment = "step"\ndt = {dt}\n'
                                 "[vary.values]\nload = [100]\n")
    assert text in _refused(capsys, "study", "s.toml", "--out", "o")
    assert not (here / "o").exists()


def test_a_closed_stdout_at_start_writes_the_files_and_exits_141(tmp_path):
    proc = subprocess.run([sys.executable, "-m", "wpam_mj", "step", "--out", "o", *FAST],
                          cwd=tmp_path, preexec_fn=lambda: os.close(1), stderr=subprocess.PIPE,
                          text=True, timeout=120, env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert (proc.returncode, proc.stderr) == (141, "")
    assert {p.suffix for p in (tmp_path / "o").iterdir()} == {".csv", ".png", ".json"}


@pytest.mark.parametrize("kp, note", [(50.0, True), (None, False)])
def test_a_step_run_that_never_settles_says_so(here, capsys, kp, note):
    """Before: a limit cycle of 9 mm peak to peak (73 mm with other in-range settings)
    exited 0 with plateau means and nothing else."""
    if kp is not None:
        (here / "lc.toml").write_text(f"[controller]\nkp = {kp}\n")
    config = ("--config", "lc.toml") if kp is not None else ()
    assert main(["step", "--load", "100", "--control", "pi", *config, "--json", "--out", "o",
                 *FAST]) == 0
    out, err = capsys.readouterr()
    assert json.loads(out)["plateaus_settled"] is not note
    lines = [line for line in err.splitlines() if "never settled" in line]
    assert len(lines) == int(note)
    if note:
        assert lines[0].startswith("note: step wpam 100 N pi: x never settled on its plateaus")
