"""scripts/train_sb3.py, smoke only (the `learn` extra; no training in the suite): it
trains exactly the steps it is given, writes its curve and scores, refuses a step count
that is no whole number of rollouts."""

from __future__ import annotations

import csv
import json
import subprocess
import sys
from pathlib import Path

import pytest

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
