"""Results carry their context: the parameters, dt, load and controller a run was made
with travel with its result, so findings, figures and writers read the Po cap (and the
rest) from it; a bad dt is refused where a run is made, once, in the same one line at
every public entry."""

from __future__ import annotations

import re
import sys

import numpy as np
import pytest

from wpam_mj import paper
from wpam_mj.environments.dm_env_task import dm_control_runs, make_env
from wpam_mj.environments.gym_env import WPAMEnv
from wpam_mj.errors import ParameterError
from wpam_mj.experiments import figures, paper_studies, writers
from wpam_mj.experiments.drives import sine_run, SineSpec
from wpam_mj.experiments.paper_studies import StepTask
from wpam_mj.physics.params import preset
from wpam_mj.reproduction import findings
from wpam_mj.simulation import context
from wpam_mj.simulation.context import RunContext, StudyContext
from wpam_mj.simulation.execution import execute
from wpam_mj.simulation.live import LiveRig
from wpam_mj.simulation.simulate import Drive, simulate
from wpam_mj.units import MPA
from wpam_mj.visualisation.viewer import LiveRig as ViewerRig

CAP = 0.06 * MPA  # not the paper's 0.08 MPa: nothing may fall back on the default
PARAMS = preset("wpam").replace(controller={"po_cap": CAP})
KEY = (150.0, 0.5, "pi")  # the run the Po-cap finding reads (paper Figs. 18-19)


@pytest.fixture(scope="module")
def sweep():
    """One PI run at 150 N, 0.5 Hz (the Po-cap finding's), at the lowered cap."""
    return paper_studies.sweep(PARAMS, (KEY[0],), (KEY[1],), (KEY[2],), keep=[KEY], dt=2e-3)


def test_a_sweep_carries_the_cap_it_ran_with(sweep) -> None:
    assert sweep.context == StudyContext(PARAMS, 2e-3)
    run = sweep.series[KEY].context
    assert (run.params, run.dt, run.load, run.control) == (PARAMS, 2e-3, 150.0, "pi")
    # the controller held Po at the lowered cap: the context is what ran
    assert sweep.series[KEY].po_cmd.max() == pytest.approx(CAP)


def test_findings_read_the_cap_from_the_sweep(sweep) -> None:
    (cap,) = [c for c in findings.sweep_checks(sweep) if c.name == "po_reaches_cap"]
    assert "Po reaches the 0.06 MPa cap" in cap.finding, cap.finding
    (margin,) = cap.margins
    assert margin.limit == pytest.approx((1.0 - paper.PO_CAP_RTOL) * CAP)
    assert margin.scale == pytest.approx(0.1 * CAP)


def test_figures_and_writers_draw_the_cap_of_the_run(sweep, tmp_path) -> None:
    fig = figures.sine_figure(sweep.series[KEY], KEY[1])
    labels = [line.get_label() for ax in fig.axes for line in ax.get_lines()]
    assert "Po cap 0.06 MPa" in labels, labels
    written = writers.write_sweep_outputs(tmp_path, sweep, KEY)
    assert {p.name for p in written} >= {"sweep.json", "sine_150N_0.5Hz_pi.png"}


def test_a_run_carries_its_context() -> None:
    n = 20
    drive = Drive(np.full(n, 0.2 * MPA), np.zeros(n), np.full(n, np.nan))
    r = simulate(PARAMS, 80.0, drive, dt=5e-4, record_dt=5e-3)
    assert r.context == RunContext(PARAMS, 5e-4, 80.0, "open", 5e-3)
    assert (r.load, r.dt, r.control, r.preset) == (80.0, 5e-4, "open", "wpam")
    assert r.metadata()["dt_s"] == 5e-4 and r.metadata()["load_n"] == 80.0


DT_REFUSED = "dt = 0.01 s is outside the allowed range [1e-05, 0.005] s"
BAD_DT = 0.01
N = 20
ENTRIES = {
    "simulate": lambda: simulate(PARAMS, 100.0, Drive(np.zeros(N), np.zeros(N),
                                                      np.full(N, np.nan)), dt=BAD_DT),
    "sine_run": lambda: sine_run(PARAMS, 100.0, "pi", SineSpec(1.0), dt=BAD_DT),
    "sweep": lambda: paper_studies.sweep(PARAMS, (100.0,), (1.0,), ("pi",), dt=BAD_DT),
    "table2": lambda: paper_studies.table2(PARAMS, loads=(100.0,), dt=BAD_DT),
    "execute": lambda: execute([StepTask(PARAMS, 100.0, "pi", BAD_DT)]),
    "live rig": lambda: LiveRig.build(RunContext(PARAMS, BAD_DT, 100.0)),
    "viewer": lambda: ViewerRig(PARAMS, 100.0, "pi", "step", dt=BAD_DT),
    "gymnasium": lambda: WPAMEnv(PARAMS, dt=BAD_DT),
    "dm_control": lambda: make_env(PARAMS, dt=BAD_DT),
}


@pytest.mark.parametrize("entry", ENTRIES)
def test_a_bad_dt_is_refused_in_the_same_line_at_every_entry(entry) -> None:
    if entry == "dm_control" and not dm_control_runs():
        pytest.skip("dm_control does not run on this mujoco")
    with pytest.raises(ParameterError, match=f"^{re.escape(DT_REFUSED)}$"):
        ENTRIES[entry]()


@pytest.fixture
def dt_checks(monkeypatch):
    """Counts every check of a dt, wherever the package calls it from."""
    calls = []
    original = context.check_dt

    def counted(*args, **kwargs):
        calls.append(args)
        return original(*args, **kwargs)

    for module in list(sys.modules.values()):
        if module.__name__.startswith("wpam_mj") and \
                getattr(module, "check_dt", None) is original:
            monkeypatch.setattr(module, "check_dt", counted)
    return calls


def test_a_run_checks_its_dt_once(dt_checks) -> None:
    """One run, one check (the run and its rig each checked it: twice); a live rig, one
    (the environments' rig and its spec each checked it: twice)."""
    drive = Drive(np.full(N, 0.2 * MPA), np.zeros(N), np.full(N, np.nan))
    simulate(PARAMS, 100.0, drive, dt=1e-3)
    assert len(dt_checks) == 1
    LiveRig.build(RunContext(PARAMS, 1e-3, 100.0))
    assert len(dt_checks) == 2
