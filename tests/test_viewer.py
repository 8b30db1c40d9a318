"""`wpam view`: the live rig, its keys, headless errors, and the viewer under Xvfb."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

import wpam_mj
from wpam_mj import paper
from wpam_mj.visualisation import viewer
from wpam_mj.errors import ParameterError
from wpam_mj.units import MM

# The shipped plant under the PI policy of tests/test_env.py (the paper's Kp, ten times its
# Ki): 0.22 mm off 1.5 s after the pull below (the paper's Ki: 0.33 mm).
GAINS = {"ki": 10 * paper.KI}
PARAMS = wpam_mj.preset().replace(controller=GAINS)
PACKAGE_ROOT = str(Path(wpam_mj.__file__).resolve().parents[1])
X_TOOLS = ("Xvfb", "xwd", "convert")
# N along +z: a pull down on the 100 N load from 2 to 3 s. The muscle's dry friction
# (F_f0 + mu dP S) and the Po the integral gathers hold a 120 N pull (130 N moves it
# 2 mm), so the pull is 200 N, twice the load, to move it surely more than 1 mm
PULL = -200.0


def pull(t: float) -> float:
    return PULL if 2.0 <= t < 3.0 else 0.0


def assert_rejected(time_s: np.ndarray, x: np.ndarray, x_ref: np.ndarray) -> None:
    """A pull from 2 to 3 s moves the load by more than 1 mm; from 4.5 s (1.5 s after it
    ends) to 5 s x is back within 0.5 mm."""
    error = np.abs(x - x_ref)
    during = error[(time_s > 2.0) & (time_s <= 3.5)].max()
    after = error[(time_s >= 4.5) & (time_s < 5.0)].max()
    assert during > 1 * MM, f"the pull moved the load only {during / MM:.2f} mm"
    assert after < 0.5 * MM, f"|x - x_r| = {after / MM:.2f} mm after the pull, limit 0.5 mm"


def test_feedback_rejects_a_pull_on_the_load() -> None:
    rig = viewer.LiveRig(PARAMS, 100.0, "pi", 20 * MM)
    rows = []
    for k in range(1, 61):
        rig.advance(k * 0.1, pull)
        rows.append((rig.time, rig.x))
    t, x = np.array(rows).T
    assert_rejected(t, x, np.full_like(x, 20 * MM))


def test_keys_change_target_and_controller() -> None:
    rig = viewer.LiveRig(PARAMS, 100.0, "pi", "step")
    rig.advance(0.5)
    assert rig.target(rig.time) == 0.0 and rig.mode == "step"
    rig.press(viewer.KEY_UP)
    rig.press(viewer.KEY_UP)
    assert rig.mode == "fixed" and rig.target(rig.time) == pytest.approx(10 * MM)
    rig.press(viewer.KEY_DOWN)
    assert rig.target(rig.time) == pytest.approx(5 * MM)
    rig.press(viewer.KEY_HOME)  # fixed -> step, restarted now
    assert rig.mode == "step" and rig.target(rig.time + viewer.STEP_HOLD_S + 0.1) == 10 * MM
    rig.press(viewer.KEY_HOME)
    assert rig.mode == "sine"
    rig.advance(rig.time + 1.0)
    assert 0.0 < rig.target(rig.time) < 50 * MM
    po = rig.po_cmd
    rig.press(viewer.KEY_END)
    assert rig.control == "pid"
    rig.advance(rig.time + 0.001)
    assert abs(rig.po_cmd - po) < 0.01 * po + 2e3, "switching is bumpless"
    rig.press(viewer.KEY_END)
    assert rig.control == "open"
    rig.press(viewer.KEY_END)
    assert rig.control == "pi"
    rig.press(ord("A"))  # the viewer's own keys are ignored here
    assert rig.control == "pi"


def test_viewer_offers_the_controllers_that_need_no_target_ahead() -> None:
    """End cycles open, pi, pid; pi_ff (its feedforward leads the regulators' dead time on
    the target's future) is refused with the valid names, not run as a plain PI."""
    assert set(viewer.VIEW_CONTROLS) == {"open", "pi", "pid"}
    with pytest.raises(ParameterError, match="control 'pi_ff' .* valid: open, pi, pid"):
        viewer.LiveRig(PARAMS, 100.0, "pi_ff", "step")


def test_bad_target_is_a_parameter_error() -> None:
    with pytest.raises(ParameterError, match="target = 200.0 mm"):
        viewer.LiveRig(PARAMS, 100.0, "pi", 0.2)
    with pytest.raises(ParameterError, match="valid: step, sine"):
        viewer.LiveRig(PARAMS, 100.0, "pi", "ramp")


def run_cli(args: list[str], env: dict) -> subprocess.CompletedProcess:
    env = {**env, "PYTHONPATH": PACKAGE_ROOT}
    return subprocess.run([sys.executable, "-m", "wpam_mj", *args], env=env,
                          capture_output=True, text=True, timeout=60)


@pytest.mark.parametrize("display, message", [
    (None, "DISPLAY is not set"),
    (":1999", "cannot open a window on display ':1999'"),  # no such X server
])
def test_headless_gets_one_line_error(display, message) -> None:
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    if display is not None:
        env["DISPLAY"] = display
    proc = run_cli(["view", "--duration", "1"], env)
    assert proc.returncode == 1
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and message in lines[0], proc.stderr
    assert "Traceback" not in proc.stderr


def _missing_x_tools() -> str | None:
    """Why the Xvfb tests cannot run here, or None. Tests install nothing: `.ci/run`
    installs these as root (apt-get install xvfb x11-apps imagemagick)."""
    missing = [tool for tool in X_TOOLS if not shutil.which(tool)]
    if missing:
        return (f"{', '.join(missing)} not installed (apt-get install xvfb x11-apps "
                "imagemagick, as .ci/run does)")
    return None


def _free_display() -> int:
    for n in range(90, 400):
        if not (os.path.exists(f"/tmp/.X11-unix/X{n}") or os.path.exists(f"/tmp/.X{n}-lock")):
            return n
    raise RuntimeError("no free X display number in 90-399")


@pytest.fixture(scope="module")
def xvfb():
    """A virtual X server on a free display: yields ":N"."""
    if not sys.platform.startswith("linux"):
        pytest.skip("Xvfb test: Linux only")
    why = _missing_x_tools()
    if why:
        pytest.skip(f"Xvfb test: {why}")
    n = _free_display()
    server = subprocess.Popen(["Xvfb", f":{n}", "-screen", "0", "1280x960x24", "-nolisten",
                               "tcp"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 20
    while not os.path.exists(f"/tmp/.X11-unix/X{n}"):
        if server.poll() is not None or time.monotonic() > deadline:
            server.kill()
            pytest.skip(f"Xvfb :{n} did not start")
        time.sleep(0.05)
    yield f":{n}"
    server.terminate()
    server.wait(timeout=10)


# Runs in its own process: MUJOCO_GL must be chosen before mujoco is imported. The scripted
# PULL from 2 to 3 s (`perturb`), then from 5 to 6 s a drag through the viewer's own
# perturbation struct (what Ctrl + right drag fills in) towards a point 200 mm below the
# load: MuJoCo's spring on the selected body then pulls with about twice the load's weight.
VIEWER_SCRIPT = textwrap.dedent("""
    import json, subprocess, sys
    import mujoco
    import wpam_mj
    from wpam_mj.visualisation import viewer

    from PIL import Image, ImageStat

    display, shot = sys.argv[1], sys.argv[2]
    next_shot = [1.5]  # s; retaken a second later while the window is still blank

    def script(t, handle):
        if next_shot and t >= next_shot[0]:
            subprocess.run(f"xwd -root -display {display} -silent | convert xwd:- {shot}",
                           shell=True, check=True)
            drawn = max(ImageStat.Stat(Image.open(shot).convert("RGB")).stddev) > 20
            next_shot[:] = [] if drawn or t > 8.0 else [t + 1.0]
        pert, load = handle.perturb, handle.m.body("load").id
        if 5.0 <= t < 6.0 and not pert.active:
            pert.select, pert.localpos[:] = load, 0.0
            pert.localmass = handle.m.body_subtreemass[load]
            pert.refselpos[:] = handle.d.xpos[load] - [0.0, 0.0, 0.20]
            pert.active = int(mujoco.mjtPertBit.mjPERT_TRANSLATE)
        elif t >= 6.0:
            pert.active = 0

    params = wpam_mj.preset().replace(controller=json.loads(sys.argv[3]))
    trace = viewer.view(params, load=100.0, control="pi", target=0.02,
                        duration=9.0, realtime=False, on_frame=script,
                        perturb=lambda t: float(sys.argv[4]) if 2.0 <= t < 3.0 else 0.0)
    print(json.dumps({k: v.tolist() for k, v in vars(trace).items()}))
""")


def test_viewer_shows_the_rig_and_rejects_a_pull(xvfb, tmp_path) -> None:
    shot = tmp_path / "shot.png"
    env = {**os.environ, "DISPLAY": xvfb, "MUJOCO_GL": "glfw", "PYTHONPATH": PACKAGE_ROOT}
    proc = subprocess.run([sys.executable, "-c", VIEWER_SCRIPT, xvfb, str(shot),
                           json.dumps(GAINS), str(PULL)], env=env,
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-2000:]
    trace = json.loads(proc.stdout.strip().splitlines()[-1])
    t, x, x_ref, force = (np.array(trace[k]) for k in ("time", "x", "x_ref", "force"))
    assert t[-1] == pytest.approx(9.0)
    assert force[(t > 2.0) & (t < 3.0)].min() == pytest.approx(PULL)
    assert_rejected(t, x, x_ref)
    assert force[(t > 5.1) & (t < 6.0)].max() < 0.5 * PULL, "the viewer's drag pulls down"
    assert_rejected(t - 3.0, x, x_ref)  # the drag: 5-6 s
    image = np.asarray(Image.open(shot).convert("RGB")).astype(int)
    assert image.std() > 20, "the screenshot is blank"
    r, g, b = image[..., 0], image[..., 1], image[..., 2]
    brown = (r - b > 60) & (r > g) & (g > b)  # the hanging mass (material "mass")
    assert brown.sum() > 500, "the screenshot does not show the load"
    beige = (r > 200) & (g > 170) & (r - b > 40)  # the sleeve `wpam render` draws
    assert beige.sum() > 500, "the viewer does not draw the braided sleeve"


def test_cli_runs_the_viewer_in_real_time(xvfb) -> None:
    env = {**os.environ, "DISPLAY": xvfb, "MUJOCO_GL": "glfw"}
    start = time.monotonic()
    proc = run_cli(["view", "--duration", "1", "--target", "sine", "--control", "pid",
                    "--load", "50"], env)
    wall = time.monotonic() - start
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "viewed 1.0 s of simulated time" in proc.stdout
    assert wall >= 1.0, f"1 s of simulated time took {wall:.2f} s: not paced in real time"
