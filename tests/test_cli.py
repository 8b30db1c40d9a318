"""The `wpam` command line: bad arguments give exit status 2 and one line, runs write files.

Most cases call `wpam_mj.cli.main` in-process (the imports are paid once); one test runs
the installed entry point as a subprocess.
"""

import csv
import json
import math
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from wpam_mj.reproduction import findings
from wpam_mj.cli import main
from wpam_mj.physics.params import CALIBRATION_FILE, preset


def _run(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def _assert_one_line_error(code, err):
    assert code == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("wpam: error: "), err
    assert "Traceback" not in err


@pytest.fixture
def files(tmp_path, monkeypatch):
    """Work in a temporary folder holding a plain file and some broken TOML files."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "afile").write_text("not a folder\n")
    (tmp_path / "malformed.toml").write_text("[muscle\nfriction_coeff = \n")
    (tmp_path / "unknown.toml").write_text("[muscle]\nno_such_field = 1.0\n")
    (tmp_path / "wrongtype.toml").write_text('[muscle]\nfriction_coeff = "high"\n')
    return tmp_path


BAD_ARGUMENTS = {
    "negative load": ["step", "--load", "-5"],
    "NaN load": ["step", "--load", "nan"],
    "non-numeric load": ["static", "--load", "heavy"],
    "zero frequency": ["sweep", "--freqs", "0"],
    "zero frequency in a list": ["sweep", "--freqs", "0.5,0"],
    "render frequency": ["render", "--freq", "0"],
    "Po above the regulator range": ["static", "--po-down", "0.7"],
    "Po below the regulator range": ["static", "--po-down", "0.001"],
    "unknown controller": ["step", "--control", "bangbang"],
    "unknown controller in a list": ["sweep", "--controllers", "pi,bangbang"],
    "unwritable --out": ["step", "--out", "afile/sub"],
    "unwritable table2 --out": ["table2", "--out", "afile"],
    "unwritable render --out": ["render", "--out", "afile/video.mp4"],
    "malformed TOML": ["step", "--config", "malformed.toml"],
    "unknown TOML field": ["step", "--config", "unknown.toml"],
    "wrongly typed TOML value": ["step", "--config", "wrongtype.toml"],
    "missing TOML": ["step", "--config", "missing.toml"],
    "unknown preset": ["step", "--preset", "hydraulic"],
    "bad time step": ["sweep", "--dt", "0.5"],
    "zero jobs": ["table2", "--jobs", "0"],
    "bad video size": ["render", "--size", "640by480"],
    "bad video suffix": ["render", "--out", "video.avi"],
    "unknown command": ["fly"],
    "no command": [],
}


@pytest.mark.parametrize("argv", BAD_ARGUMENTS.values(), ids=BAD_ARGUMENTS.keys())
def test_bad_arguments_exit_2_with_one_line(files, capsys, argv):
    code, out, err = _run(capsys, *argv)
    _assert_one_line_error(code, err)
    assert out == ""


def test_bad_argument_names_the_value(files, capsys):
    _, _, err = _run(capsys, "static", "--po-down", "0.7")
    assert "0.7" in err and "MPa" in err
    _, _, err = _run(capsys, "step", "--control", "bangbang")
    assert "bangbang" in err and "pid" in err


def test_help_lists_commands_and_units(capsys):
    code, out, _ = _run(capsys, "--help")
    assert code == 0
    for command in ("static", "step", "table2", "sweep", "reproduce", "calibrate", "render"):
        assert command in out
    code, out, _ = _run(capsys, "sweep", "--help")
    assert code == 0
    for unit in ("[N]", "[Hz]", "[s]", "[MPa]"):
        assert unit in out


def test_entry_point_help_runs_as_a_program():
    proc = subprocess.run([sys.executable, "-m", "wpam_mj.cli", "step", "--help"],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert "--load N" in proc.stdout


def _read_csv(path):
    with open(path) as fh:
        rows = list(csv.reader(line for line in fh if not line.startswith("#")))
    head, body = rows[0], np.array(rows[1:], dtype=float)
    return {name: body[:, i] for i, name in enumerate(head)}


def test_step_writes_csv_and_png_and_tracks(files, capsys):
    code, out, err = _run(capsys, "step", "--load", "100", "--control", "pi", "--out", "tmp")
    assert code == 0, err
    csv_path = files / "tmp" / "step_wpam_100N_pi.csv"
    assert csv_path.is_file() and csv_path.with_suffix(".png").is_file()
    data = _read_csv(csv_path)
    t, err_mm = data["time_s"], data["x_mm"] - data["x_ref_mm"]
    last = t >= t[-1] - 5.0  # settled part of the last plateau (target 0 mm)
    assert abs(err_mm[last].mean()) < 0.5, "last-plateau mean error [mm]"


def test_sweep_json(files, capsys):
    code, out, err = _run(capsys, "sweep", "--loads", "100", "--freqs", "0.5",
                          "--controllers", "pi", "--json", "--out", "sw")
    assert code == 0, err
    (point,) = json.loads(out)
    assert set(point) == {"load_n", "freq_hz", "controller", "gain", "phase_lag_deg",
                          "po_max_mpa", "load_moved"}
    assert (point["load_n"], point["freq_hz"], point["controller"]) == (100.0, 0.5, "pi")
    assert 0.0 < point["gain"] <= 1.2
    assert point["phase_lag_deg"] > 0.0
    assert 0.0 < point["po_max_mpa"] <= 0.5
    with open(files / "sw" / "sweep.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == 1 and math.isclose(float(rows[0]["gain"]), point["gain"],
                                           rel_tol=1e-5)
    for name in ("sweep_gain_phase.png", "sine_100N_0.5Hz_pi.png", "sine_100N_0.5Hz_pi.csv"):
        assert (files / "sw" / name).is_file(), name


def test_static_compare_presets(files, capsys):
    code, out, err = _run(capsys, "static", "--load", "100", "--compare-presets",
                          "--out", "st", "--jobs", "2")
    assert code == 0, err
    for name in ("wpam", "rlam", "mckibben"):
        assert (files / "st" / f"static_{name}_100N.csv").is_file()
        assert f"{name}    100 N:" in out
    assert (files / "st" / "static_presets.png").is_file()


def test_config_overrides_reach_the_run(files, capsys):
    (files / "stiff.toml").write_text("[controller]\nkp = 0.0\nki = 0.0\n")
    code, out, err = _run(capsys, "step", "--load", "100", "--config", "stiff.toml",
                          "--out", "cfg")
    assert code == 0, err
    po = _read_csv(files / "cfg" / "step_wpam_100N_pi.csv")["po_cmd_mpa"]
    # zero gains: the controller output sits at the regulator minimum, 0.005 MPa
    assert np.allclose(po[1:], 0.005, atol=1e-6)


class _FakeCalibration:
    def table(self):
        return "fitted values"


def test_calibrate_calls_the_library(files, capsys, monkeypatch):
    import types

    seen = {}

    def calibrate(*, out, jobs, dt, progress, start, samples, seed, max_nfev, resume):
        seen.update(out=out, jobs=jobs, dt=dt, progress=progress, resume=resume,
                    samples=samples, seed=seed, max_nfev=max_nfev)
        seen["start"] = start
        return _FakeCalibration()

    monkeypatch.setitem(sys.modules, "wpam_mj.reproduction.calibrate",
                        types.SimpleNamespace(calibrate=calibrate))
    code, out, err = _run(capsys, "calibrate", "--out", "fit.toml", "--jobs", "3",
                          "--dt", "0.0005", "--no-progress", "--samples", "5", "--seed", "3",
                          "--max-steps", "2")
    assert code == 0, err
    assert out.splitlines()[0] == "fitted values"
    assert "--config fit.toml" in out  # where the fit went and how to use it
    start = seen.pop("start")
    assert seen == {"out": Path("fit.toml"), "jobs": 3, "dt": 0.0005, "progress": False,
                    "resume": False, "samples": 5, "seed": 3, "max_nfev": 2}
    assert start == preset("wpam")  # the search starts from the preset (plus --config)
    _run(capsys, "calibrate", "--no-progress", "--resume")
    # the current folder, never the installed package's file
    assert seen["out"] == Path("calibrated.toml") != CALIBRATION_FILE and seen["resume"]


def test_calibrate_robust_fits_the_sampled_plants_too(files, capsys, monkeypatch):
    import types

    seen = {}

    def calibrate(**kwargs):
        seen.update(kwargs)
        return _FakeCalibration()

    monkeypatch.setitem(sys.modules, "wpam_mj.reproduction.calibrate",
                        types.SimpleNamespace(calibrate=calibrate))
    code, _, err = _run(capsys, "calibrate", "--out", "fit.toml", "--robust", "2",
                        "--no-progress")
    assert code == 0, err
    assert seen["robust"] == 2 and "feedforward" not in seen  # the default: calibrated
    code, _, err = _run(capsys, "calibrate", "--out", "fit.toml", "--no-progress",
                        "--feedforward-model", "nominal")
    assert code == 0, err
    assert seen["feedforward"] == "nominal"


def test_calibrate_refuses_other_presets(files, capsys):
    code, _, err = _run(capsys, "calibrate", "--preset", "mckibben")
    assert code == 2
    assert err.startswith("wpam: error: --preset mckibben") and len(err.strip().splitlines()) == 1


def test_render_simulates_only_what_it_shows(files, capsys, monkeypatch):
    import wpam_mj.visualisation.render

    calls = []

    def render_video(result, params, out, *, fps, size, run_id):
        calls.append((result, out, fps, size))
        Path(out).write_bytes(run_id.encode())  # the manifest records the file's digest
        return out

    monkeypatch.setattr(wpam_mj.visualisation.render, "render_video", render_video)
    code, out, err = _run(capsys, "render", "--experiment", "sweep", "--freq", "1",
                          "--duration", "1.5", "--fps", "24", "--size", "320x240",
                          "--out", "v.gif")
    assert code == 0, err
    (result, path, fps, size), = calls
    assert str(path) == "v.gif" and fps == 24 and size == (320, 240)
    assert result.time[-1] == pytest.approx(1.5, abs=result.time[1])
    assert np.all(np.isfinite(result.x_ref))  # the sinusoid, under feedback


def test_reproduce_writes_every_output(files, capsys):
    """Smoke test of the main job (coarser 2 ms step to stay quick): every figure, CSV,
    summary and the report, from one pool of two workers."""
    code, out, err = _run(capsys, "reproduce", "--dt", "0.002", "--jobs", "2", "--out", "rep")
    assert code == 0, err
    rep = files / "rep"
    figures = {"fig03_presets.png", "fig08_static_po0.png", "fig09_static_po.png",
               "fig12_13_step_100N.png", "fig14_15_step_pi.png",
               "fig16_closed_loop_static.png", "fig17_frequency_response.png",
               "fig18_19_sine.png", "table2.png"}
    summaries = {"report.md", "checks.json", "table2.json", "table2.csv", "sweep.json",
                 "sweep.csv"}
    manifests = [p.name for p in rep.glob("manifest-*.json")]
    assert len(manifests) == 1
    assert {p.name for p in rep.iterdir() if p.is_file()} == figures | summaries | {
        manifests[0]}
    # the manifest lists every file of the run, unchanged; every figure carries its id
    from wpam_mj.infra import manifest
    written = {p.relative_to(rep).as_posix() for p in rep.rglob("*")
               if p.is_file() and p.name != manifests[0]}
    assert manifest.check_files(rep / manifests[0]) == dict.fromkeys(written, "ok")
    run_id = manifests[0].removeprefix("manifest-").removesuffix(".json")
    assert {manifest.png_run_id(rep / f) for f in figures} == {run_id}
    data = {p.name for p in (rep / "data").iterdir()}
    assert {"static_wpam_50N.csv", "static_wpam_150N_po0.04MPa.csv",
            "static_mckibben_100N.csv", "static_rlam_100N.csv", "step_wpam_100N_open.csv",
            "step_wpam_150N_pi.csv", "sine_150N_0.5Hz_pi.csv"} <= data
    assert len(data) == 13
    assert not list(rep.rglob(".*")), "temporary files left behind"
    checks = json.loads((rep / "checks.json").read_text())
    assert [c["name"] for c in checks] == list(findings.FINDINGS)  # every finding, once
    assert all(set(c) == {"name", "sentence", "finding", "counted", "passed", "worst_margin",
                          "detail"} for c in checks)
    assert all(c["sentence"] for c in checks)  # each prints the paper's words
    # golden (docs/physics.md, "The shipped plant"): with the controller's model fitted to
    # the plant's own Figs. 8-9 loops, 9 of the paper's 13 sentences hold, the lag order
    # below 0.5 Hz and PID's visible lead among them (not at every frequency: an extra)
    counted = [c for c in checks if c["counted"]]
    assert (sum(c["passed"] for c in counted), len(counted)) == (9, 13)
    verdict = {c["name"]: c["passed"] for c in checks}
    assert verdict["lag_order_low_freq"] and verdict["pid_leads_pi"]
    assert verdict["lag_order_low_freq_strict"]  # and in every pair: an extra
    assert not verdict["pid_leads_pi_everywhere"]
    report = (rep / "report.md").read_text()
    assert "9 of 13 of the paper's sentences hold" in report
    assert "The controller's equilibrium model, fitted to the plant's own" in report
    # golden (docs/physics.md, "A plateau is decided where it lands"): the PI steps miss at
    # their landings, which at 50 and 100 N leave more than the 0.11/0.13 mm the paper's
    # cells allow
    steps = next(c for c in checks if c["name"] == "steps_settle")
    floors = re.search(r"gets below ([\d.]+)/([\d.]+)/([\d.]+) mm", steps["detail"]).groups()
    assert float(floors[0]) > 0.11 and float(floors[1]) > 0.13, steps["detail"]
    assert "Table 2" in (rep / "report.md").read_text() and "Table 2" in out
    assert len(_read_csv(rep / "data" / "step_wpam_100N_pi.csv")["x_mm"]) > 1000


def test_a_sweep_with_the_calibrated_controller_model_matches_the_report(files, capsys):
    """`--feedforward-model calibrated` on a single experiment fits the controller's model
    to the plant's own loops first, as `wpam reproduce` does: golden, the 0.1 Hz PI lags of
    50 and 100 N in the report's order (6.8 < 7.3 deg; with the plant's own values 8.3 >
    7.9 deg, docs/physics.md "The shipped plant")."""
    lags = {}
    for model in ("calibrated", "nominal"):
        code, out, err = _run(capsys, "sweep", "--loads", "50,100", "--freqs", "0.1",
                              "--controllers", "pi", "--feedforward-model", model, "--json",
                              "--out", f"sw_{model}")
        assert code == 0, err
        lags[model] = [p["phase_lag_deg"] for p in json.loads(out)]
    assert lags["calibrated"][0] < lags["calibrated"][1]
    assert lags["nominal"][0] > lags["nominal"][1]
    manifest = json.loads(next((files / "sw_calibrated").glob("manifest-*.json")).read_text())
    assert manifest["settings"]["feedforward_model"] == "calibrated"
