"""MuJoCo's own viewer on a model using the plugin (`wpam_mj.visualisation.native_viewer`):
without a display it says so in one line, and a viewer that fails leaves no
MUJOCO_LOG.TXT in the working folder."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
MODEL = ROOT / "models" / "arm" / "arm.xml"
LOG = "MUJOCO_LOG.TXT"


def _headless(display: str | None = None) -> dict:
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    env["PYTHONPATH"] = str(ROOT)
    if display is not None:
        env["DISPLAY"] = display
    return env


def _run(args: list[str], env: dict, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, *args], env=env, cwd=cwd, capture_output=True,
                          text=True, timeout=60)


@pytest.mark.parametrize("display, message", [
    (None, "DISPLAY is not set"),
    (":1999", "cannot open a window on display ':1999'"),  # no such X server
])
def test_headless_native_viewer_is_one_line_and_leaves_no_log(tmp_path, display, message):
    proc = _run(["-m", "wpam_mj.visualisation.native_viewer", str(MODEL)],
                _headless(display), tmp_path)
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 1 and len(lines) == 1 and message in lines[0], proc.stderr
    assert not (tmp_path / LOG).exists()


def test_a_missing_model_is_one_line(tmp_path):
    proc = _run(["-m", "wpam_mj.visualisation.native_viewer", "nothing.xml"],
                _headless(), tmp_path)
    assert proc.returncode == 2 and "model file nothing.xml: no such file" in proc.stderr
    assert proc.stderr.count("\n") == 1, proc.stderr


LAUNCH = """
import sys
import mujoco.viewer
from wpam_mj.visualisation.viewer import console_log_only
if sys.argv[1] == "quiet":
    with console_log_only():
        mujoco.viewer.launch_from_path(sys.argv[2])
else:
    mujoco.viewer.launch_from_path(sys.argv[2])
"""


def test_a_viewer_that_fails_in_mujoco_logs_to_the_console_only(tmp_path):
    """Past the display check (here: skipped), MuJoCo's viewer thread ends the process on
    a fatal error; its default handler also writes MUJOCO_LOG.TXT into the working
    folder, which `console_log_only` turns off."""
    for mode, (here, logged) in {"default": (tmp_path / "a", True),
                                 "quiet": (tmp_path / "b", False)}.items():
        here.mkdir()
        proc = _run(["-c", LAUNCH, mode, str(MODEL)], _headless(), here)
        assert proc.returncode != 0 and "could not initialize GLFW" in proc.stderr, proc.stderr
        assert (here / LOG).exists() == logged, mode
