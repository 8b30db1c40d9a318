"""At the command line: outputs a person and a script can trust (manifests, run
ids, --json, flags), runs that cannot mean anything refused, signals and pipes handled.

Runs are short (2 ms step, 1-2 s ramps, one load) so the file adds seconds.
"""

import json
import os
import signal
import subprocess
import sys
import time
import types
from pathlib import Path

import numpy as np
import pytest

from wpam_mj import paper
from wpam_mj.reproduction import findings
from wpam_mj.infra import manifest
from wpam_mj.infra import pool
from wpam_mj.experiments import paper_studies
from wpam_mj.cli import JOBS_PER_CPU, main
from wpam_mj.errors import ParameterError
from wpam_mj.units import MPA
from wpam_mj.physics.params import preset
from wpam_mj.simulation.context import RunContext, StudyContext
from wpam_mj.simulation.loop_contract import REC_FIELDS
from wpam_mj.simulation.results import SimResult
from wpam_mj.simulation.simulate import Drive, SimulationDiverged
from wpam_mj.experiments.responses import StepRun, SweepPoint, SweepResult

ROOT = Path(__file__).resolve().parents[1]
FAST = ("--dt", "0.002", "--no-progress")
ABOVE_CAP = JOBS_PER_CPU * pool.default_jobs() + 1


def _run(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture
def here(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "slowline.toml").write_text("[pneumatics]\ninner_conductance = 1e-15\n")
    return tmp_path


# ---- bad input: exit 2, one line naming the value and the allowed range (items 6, 15, 16, 19)

REFUSED = {  # argv: text the one line must contain
    "empty --out": (["step", "--out", ""], ["''", "empty"]),
    "empty render --out": (["render", "--out", ""], ["''", "empty"]),
    "repeated load": (["sweep", "--loads", "100,100"], ["100", "once"]),
    "repeated frequency": (["sweep", "--freqs", "0.5,0.50"], ["0.5", "once"]),
    "repeated controller": (["sweep", "--controllers", "pi,pi"], ["pi", "once"]),
    # one above the cap: code without the cap would start that many processes
    "jobs above the cap": (["table2", "--jobs", str(ABOVE_CAP)], [str(ABOVE_CAP), "[1, "]),
    "study jobs above the cap": (["study", "spec.toml", "--jobs", str(ABOVE_CAP)],
                                 [str(ABOVE_CAP)]),
    "unliftable step load": (["step", "--load", "1000"], ["1000 N", "50 mm", "0.5 MPa",
                                                         "[1, "]),
    "unliftable static load": (["static", "--load", "1000"], ["1000 N", "[1, "]),
    "unliftable sweep load": (["sweep", "--loads", "100,1000"], ["1000 N", "[1, "]),
    "unliftable render load": (["render", "--load", "1000"], ["1000 N", "[1, "]),
    "fps outside the video's range": (["render", "--fps", "0"], ["0", "[1, 120]"]),
    "gif fps outside its range": (["render", "--fps", "60", "--out", "v.gif"],
                                  ["60", "[1, 50]"]),
    "dt not dividing the record period": (["step", "--dt", "0.003"], ["--dt", "0.003",
                                                                     "0.01"]),
    "ramp time too short": (["static", "--ramp-time", "0.5"], ["--ramp-time", "0.5",
                                                                "[1, 3600]"]),
    "calibration ramp time": (["robustness", "--calibration-ramp-time", "0"],
                              ["--calibration-ramp-time", "0 s", "[1, 3600]"]),
    "ramp time not finite": (["table2", "--ramp-time", "nan"], ["nan", "[1, 3600]"]),
}


@pytest.mark.parametrize("argv, words", REFUSED.values(), ids=REFUSED.keys())
def test_refused_with_one_line_naming_value_and_range(here, capsys, argv, words):
    code, out, err = _run(capsys, *argv)
    assert code == 2, err
    assert out == "" and len(err.strip().splitlines()) == 1, err
    assert err.startswith("wpam: error: ")
    for word in words:
        assert word in err, (word, err)
    assert not (here / "out").exists(), "nothing written before refusing"


def test_largest_liftable_load_is_the_boundary(here, capsys):
    from wpam_mj.experiments.feasibility import max_liftable_load
    from wpam_mj.physics.params import preset
    limit = max_liftable_load(preset("wpam"))
    code, _, err = _run(capsys, "step", "--load", f"{limit * 1.01:.3f}", *FAST)
    assert code == 2 and f"{limit:.1f}" in err
    from wpam_mj.experiments.feasibility import check_liftable
    assert check_liftable(preset("wpam"), [limit * 0.99]) == (limit * 0.99,)


# ---- outputs: manifest, run id in every file, --json (items 8, 18)


def _manifest_of(folder: Path) -> tuple[str, dict]:
    (path,) = folder.glob("manifest-*.json")
    return path.stem.removeprefix("manifest-"), json.loads(path.read_text())


def test_static_json_manifest_and_ramp_time(here, capsys):
    code, out, err = _run(capsys, "static", "--load", "100", "--ramp-time", "2", "--json",
                          "--out", "st", *FAST)
    assert code == 0, err
    (loop,) = json.loads(out)  # stdout is JSON only
    run_id, man = _manifest_of(here / "st")
    assert loop["run_id"] == run_id and loop["load_moved"] is True
    assert loop["load_n"] == 100.0 and loop["area_mpa_mm"] > 0.0
    assert man["settings"]["ramp_time_s"] == 2.0 and man["command"] == "static"
    assert manifest.check_files(here / "st" / f"manifest-{run_id}.json") == {
        "static_wpam.png": "ok", "static_wpam_100N.csv": "ok"}
    assert manifest.png_run_id(here / "st" / "static_wpam.png") == run_id
    table = np.genfromtxt(here / "st" / "static_wpam_100N.csv", delimiter=",", names=True)
    # the ramp reached the run: 1 s dwell + 2 s up + 2 s down + 1 s dwell
    assert table["time_s"][-1] == pytest.approx(6.0)


def test_run_id_is_stable_and_follows_the_settings(here, capsys):
    ids = []
    for ramp in ("1", "1", "2"):
        out = here / f"r{len(ids)}"
        assert _run(capsys, "static", "--load", "100", "--ramp-time", ramp, "--out", out,
                    *FAST)[0] == 0
        ids.append(_manifest_of(out)[0])
    assert ids[0] == ids[1] != ids[2]
    assert (here / "r0" / "static_wpam_100N.csv").read_bytes() == \
        (here / "r1" / "static_wpam_100N.csv").read_bytes()


def test_step_json_and_manifest(here, capsys):
    code, out, err = _run(capsys, "step", "--load", "100", "--control", "pi", "--json",
                          "--out", "sp", *FAST)
    assert code == 0, err
    data = json.loads(out)
    run_id, man = _manifest_of(here / "sp")
    assert data["run_id"] == run_id and data["load_moved"] is True
    assert [p["target_mm"] for p in data["plateaus"]] == list(paper.STEP_LEVELS_MM)
    entry = man["files"]["step_wpam_100N_pi.csv"]
    assert entry["load_n"] == 100.0 and entry["control"] == "pi" and entry["load_moved"]
    assert manifest.png_run_id(here / "sp" / "step_wpam_100N_pi.png") == run_id


def test_open_loop_that_never_moves_is_flagged(here, capsys):
    """A line so restricted that the chamber never fills: the load hangs still."""
    code, out, err = _run(capsys, "static", "--load", "100", "--ramp-time", "1",
                          "--config", "slowline.toml", "--out", "still", *FAST)
    assert code == 0, err
    assert "never moved" in out and "static wpam 100 N" in out
    _, man = _manifest_of(here / "still")
    assert man["files"]["static_wpam_100N.csv"]["load_moved"] is False
    code, out, err = _run(capsys, "static", "--load", "100", "--ramp-time", "1", "--json",
                          "--config", "slowline.toml", "--out", "still", *FAST)
    assert json.loads(out)[0]["load_moved"] is False and "never moved" in err


def test_table2_ramp_time_reaches_the_study(here, capsys, monkeypatch):
    """`wpam table2 --ramp-time` runs the shipped protocol's ramps at that rate."""
    from wpam_mj.cli import experiments as cli_experiments

    seen = {}

    def execute(batches, jobs, **kwargs):
        seen["ramp_times"] = [t.protocol.ramp_time for t in batches[0].tasks
                              if hasattr(t, "protocol")]
        raise SimulationDiverged("stopped by the test")

    monkeypatch.setattr(cli_experiments, "execute", execute)
    code, _, err = _run(capsys, "table2", "--ramp-time", "240", *FAST)
    assert code == 1 and "stopped by the test" in err
    assert seen["ramp_times"] == [240.0] * 6  # the open loops with and without Po


def test_jobs_never_exceed_the_runs(here, capsys, monkeypatch):
    seen = {}

    def execute(tasks, jobs, **kwargs):
        seen["jobs"] = jobs
        raise SimulationDiverged("stopped by the test")

    monkeypatch.setattr(paper_studies, "execute", execute)
    code, _, _ = _run(capsys, "static", "--load", "100", "--jobs", "2", *FAST)
    assert code == 1 and seen["jobs"] == 1  # one run: no pool


# ---- help and text (items 2, 10)


def test_help_lists_each_command_once(capsys):
    code, out, _ = _run(capsys, "--help")
    assert code == 0
    for command in ("static", "step", "table2", "sweep", "reproduce", "calibrate", "render",
                    "view", "linear", "study"):
        firsts = [line.split()[0] for line in out.splitlines() if line.strip()]
        assert firsts.count(command) == 1, command


def test_step_text_has_no_negative_zero():
    from wpam_mj.experiments.tables import step_text
    z = np.zeros(2)
    result = SimResult(**{name: z for name in REC_FIELDS},
                       context=RunContext(preset(), 1e-3, 100.0, "open"))
    run = StepRun(settle=5.0, target=np.array([0.0]), x_mean=np.array([-1e-9]),
                  pi_mean=np.array([0.05 * MPA]), po_mean=np.array([-3e-3]), result=result)
    text = step_text(run)
    assert "-0.0" not in text and "0.0000" in text


def _sweep(gains):
    pts = tuple(SweepPoint(load=load, freq=f, controller="pi", gain=g, phase_lag_deg=10.0,
                           po_max=0.05 * MPA)
                for (load, f), g in zip([(50.0, 0.1), (50.0, 0.5), (150.0, 0.1),
                                         (150.0, 0.5)], gains))
    return SweepResult(points=pts, context=StudyContext(preset(), 1e-3))


def test_checks_print_one_decimal_and_no_bare_dash():
    t2 = types.SimpleNamespace(loads=(50.0,), open_po={50.0: 0.7042 * 0.845},
                               feedback={50.0: 0.001},
                               paper=lambda: {"open_po": {50.0: 0.7042}},
                               context=StudyContext(preset(), 1e-3))
    row = findings.check(findings.FINDINGS["table2_po_row"], t2)
    assert "-15.5%" in row.detail
    spread = next(c for c in findings.sweep_checks(_sweep([np.nan] * 4))
                  if "within" in c.finding)
    assert "(-)" not in spread.detail and "no finite gain" in spread.detail


def test_report_and_figure_say_what_they_show():
    from wpam_mj.experiments.figures import sweep_figure
    from wpam_mj.reproduction.report import _sweep_table
    sw = _sweep([0.9, 0.5, 0.9, 0.5])
    table = _sweep_table(sw)
    assert "regulator gauge" in table and "chamber Po" not in table
    fig = sweep_figure(sw)
    texts = " ".join(t.get_text() for t in fig.findobj(lambda a: hasattr(a, "get_text")))
    assert "Paper (Fig. 17" in texts and "no numbers" in texts


# ---- library (item 20): a drive of fewer than two samples


@pytest.mark.parametrize("n", [0, 1])
def test_drive_needs_two_samples(n):
    with pytest.raises(ParameterError, match=f"{n} sample"):
        Drive(pi_cmd=np.zeros(n), po_cmd=np.zeros(n), x_ref=np.zeros(n))


# ---- pipes and signals (items 9, 12), as real processes


def _env():
    return {**os.environ, "PYTHONPATH": str(ROOT), "MUJOCO_GL": "egl"}


def test_closed_stdout_exits_quietly(tmp_path):
    """`wpam static ... | head -1` with head gone before the first write."""
    proc = subprocess.Popen([sys.executable, "-m", "wpam_mj", "static", "--load", "100",
                             "--ramp-time", "1", "--out", "o", *FAST], cwd=tmp_path,
                            env=_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    proc.stdout.close()  # the reader has exited
    err = proc.stderr.read().decode()
    assert proc.wait(timeout=120) in (0, 141)
    assert err == ""


def _children(pid: int) -> list[int]:
    path = Path(f"/proc/{pid}/task/{pid}/children")
    return [int(c) for c in path.read_text().split()] if path.exists() else []


def _running(pid: int) -> bool:
    try:
        status = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return False
    return "\nState:\tZ" not in status


@pytest.mark.skipif(not Path("/proc/self/task").exists(), reason="needs Linux /proc")
def test_sigterm_stops_workers_and_cleans_up(tmp_path):
    proc = subprocess.Popen([sys.executable, "-m", "wpam_mj", "synth", "--jobs", "2",
                             "--out", "o"],  # its tasks are no simulations: a process pool
                            cwd=tmp_path, env=_env(), stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 60
    while len(_children(proc.pid)) < 2 and time.monotonic() < deadline:
        time.sleep(0.05)
    workers = _children(proc.pid)
    assert len(workers) >= 2, "the pool never started"
    proc.send_signal(signal.SIGTERM)
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 143
    assert err.strip() == "wpam: terminated"
    time.sleep(0.2)
    assert not any(_running(w) for w in workers), "pool workers survived"
    assert not [p for p in (tmp_path / "o").rglob(".*")], "temporary files left"
