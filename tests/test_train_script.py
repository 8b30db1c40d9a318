"""scripts/train_sb3.py, smoke only (the `learn` extra; no training in the suite): it
trains exactly the steps it is given, writes its curve and scores, refuses a step count
that is no whole number of rollouts, and refuses a backend, device or episode length it
cannot use in one line before it scores anything."""

from __future__ import annotations

import csv
import importlib.util
import json
import subprocess
import sys
from pathlib import Path

import pytest

from wpam_mj.simulation import warp_muscle

pytest.importorskip("stable_baselines3", reason="the `learn` extra is not installed")

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "train_sb3.py"
SMALL = ["--n-envs", "4", "--n-steps", "32", "--batch-size", "64", "--epochs", "1",
         "--curve-seeds", "1", "--test-seeds", "1"]


def test_trains_exactly_the_given_steps_and_writes_the_curve(tmp_path) -> None:
    proc = subprocess.run([sys.executable, str(SCRIPT), *SMALL, "--steps", "256",
                           "--eval-every", "128", "--out", str(tmp_path)],
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    scores = json.loads((tmp_path / "scores.json").read_text())
    assert scores["steps"] == 256
    with open(tmp_path / "learning_curve.csv") as f:
        rows = list(csv.DictReader(f))
    assert [int(r["steps"]) for r in rows] == [128, 256]
    assert (tmp_path / "learning_curve.png").stat().st_size > 0
    assert scores["scores"]["pi"] == pytest.approx(scores["scores"]["zero action"], rel=1e-3)
    for name in ("best.zip", "last.zip"):
        assert (tmp_path / name).exists()


@pytest.mark.parametrize("option", ["--steps", "--eval-every"])
def test_refuses_steps_that_are_no_whole_number_of_rollouts(option, tmp_path) -> None:
    args = {"--steps": "256", "--eval-every": "128", option: "200"}
    proc = subprocess.run([sys.executable, str(SCRIPT), *SMALL, *sum(args.items(), ()),
                           "--out", str(tmp_path)], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2
    assert f"{option} 200 must be a positive multiple of 128" in proc.stderr


@pytest.fixture(scope="module")
def script():
    """scripts/train_sb3.py as a module (its imports once, for the refusals)."""
    spec = importlib.util.spec_from_file_location("train_sb3", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _refusal(script, monkeypatch, capsys, args: list[str]) -> str:
    """The script's refusal of `args`, before anything runs: exit status 2, one line."""
    monkeypatch.setattr(sys, "argv", [str(SCRIPT), *args])
    with pytest.raises(SystemExit) as stop:
        script.parse_args()
    assert stop.value.code == 2
    return capsys.readouterr().err.strip().splitlines()[-1]


@pytest.mark.parametrize("args, message", [
    (["--device", "cuda"], "--device cuda needs --backend warp (mujoco.batch runs on the CPU)"),
    (["--backend", "jax"], "argument --backend: invalid choice: 'jax'"),
    (["--time-limit", "0"], "--time-limit 0 must be in (0, 10] s"),
], ids=["device-without-warp", "unknown-backend", "time-limit"])
def test_refuses_options_it_cannot_use_in_one_line(script, monkeypatch, capsys, args,
                                                    message) -> None:
    assert message in _refusal(script, monkeypatch, capsys, args)


def test_refuses_the_warp_backend_without_the_gpu_extra(script, monkeypatch, capsys,
                                                       without_warp) -> None:
    line = _refusal(script, monkeypatch, capsys, ["--backend", "warp", "--device", "cpu"])
    assert "--backend warp --device cpu: backend = 'warp' needs NVIDIA Warp" in line
    assert "pip install 'wpam-mj[gpu]'" in line


@pytest.mark.skipif(not warp_muscle.warp_available(), reason="needs the gpu extra")
def test_refuses_a_device_warp_does_not_have(script, monkeypatch, capsys) -> None:
    line = _refusal(script, monkeypatch, capsys, ["--backend", "warp", "--device", "tpu"])
    assert "--backend warp --device tpu: device = 'tpu'; valid: cpu, cuda, cuda:N" in line
