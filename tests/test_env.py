"""The dm_env environment: interface contract, same physics as simulate(), a PI reaches."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from absl.testing import absltest
from dm_env import test_utils

import wpam_mj
from wpam_mj import paper
from wpam_mj.control.controllers import PIControl
from wpam_mj.environments.dm_env_task import OBSERVATIONS, dm_control_runs, make_env
from wpam_mj.experiments.feasibility import max_liftable_load
from wpam_mj.errors import ParameterError
from wpam_mj.units import MM, MPA, STANDARD_GRAVITY
from wpam_mj.simulation.simulate import Drive

# Code defaults, not the calibration file: these tests pin the environment, not the fit.
PARAMS = wpam_mj.preset("wpam", calibration=None)

if not dm_control_runs():  # mujoco 4: make_env refuses (tests/test_gym_env.py checks how)
    pytest.skip("dm_control does not run on this mujoco", allow_module_level=True)


class EnvironmentConformanceTest(test_utils.EnvironmentTestMixin, absltest.TestCase):
    """dm_env's reusable checks (specs, FIRST/MID/LAST sequence, reset behaviour)."""

    def make_object_under_test(self):
        # 0.1 s episodes: the mixin's 20-action sequence crosses an episode end
        return make_env(PARAMS, seed=0, time_limit=0.1)


class BothActionsConformanceTest(test_utils.EnvironmentTestMixin, absltest.TestCase):
    def make_object_under_test(self):
        return make_env(PARAMS, action="both", seed=0, time_limit=0.1)


class FlatObservationConformanceTest(test_utils.EnvironmentTestMixin, absltest.TestCase):
    def make_object_under_test(self):
        return make_env(PARAMS, seed=0, time_limit=0.1, flat_observation=True)


def test_specs_carry_units_and_bounds() -> None:
    env = make_env(PARAMS)
    assert list(env.observation_spec()) == list(OBSERVATIONS)
    spec = env.action_spec()
    assert spec.shape == (1,)
    assert spec.minimum[0] == PARAMS.pneumatics.p_min
    assert spec.maximum[0] == PARAMS.controller.po_cap == pytest.approx(0.08 * MPA)
    both = make_env(PARAMS, action="both").action_spec()
    np.testing.assert_array_equal(both.maximum, [PARAMS.pneumatics.p_max,
                                                 PARAMS.controller.po_cap])
    assert env.control_timestep() == pytest.approx(0.01)


def test_episode_length_and_load_mass() -> None:
    env = make_env(PARAMS, seed=1, time_limit=0.5)
    ts = env.reset()
    load = ts.observation["load_n"][0]
    assert 50.0 <= load <= 150.0
    assert 0.0 <= ts.observation["target_m"][0] <= 50 * MM
    assert env.physics.model.body("load").mass[0] == pytest.approx(load / STANDARD_GRAVITY)
    steps = 0
    while not ts.last():
        ts = env.step([0.02 * MPA])
        steps += 1
    assert steps == 50
    assert env.physics.time() == pytest.approx(0.5, abs=1e-9)


def test_steps_match_simulate_exactly() -> None:
    """Plant advanced once per physics step, same order as the reference loop."""
    load, pi_cmd, po_cmd, n_ctrl = 100.0, 0.4 * MPA, 0.005 * MPA, 80
    env = make_env(PARAMS, action="both", target=0.02, load=load, time_limit=n_ctrl * 0.01)
    env.reset()
    obs = [env.step([pi_cmd, po_cmd]).observation for _ in range(n_ctrl)]
    n = 10 * n_ctrl + 1
    ref = wpam_mj.simulation.simulate.simulate(
        PARAMS, load, Drive(np.full(n, pi_cmd), np.full(n, po_cmd), np.full(n, np.nan)),
        dt=1e-3, control="open", record_dt=0.01, engine="python")
    # the env observes after each control step; simulate records before each step
    for name, field in (("x_m", "x"), ("velocity_m_s", "velocity"), ("pi_pa", "pi"),
                        ("po_pa", "po")):
        got = np.array([o[name][0] for o in obs])
        np.testing.assert_array_equal(got, getattr(ref, field)[1:n_ctrl + 1], err_msg=name)
    assert ref.x[n_ctrl] > 1 * MM, "the comparison should include motion"


def run_pi_episode(env, params) -> tuple[float, list[dict]]:
    """Run one episode with the library's PI on Po, started as `simulate` starts it (the
    loop at rest at po_feedforward); returns (final |error| [m], observations)."""
    ts = env.reset()
    pid = PIControl.for_run(params, env.control_timestep())
    history = [ts.observation]
    while not ts.last():
        o = ts.observation
        ts = env.step([pid.update(o["x_m"][0], o["target_m"][0])])
        history.append(ts.observation)
    o = ts.observation
    return abs(o["x_m"][0] - o["target_m"][0]), history


# The PI policy for a 10 s episode at the 10 ms control step, on the shipped plant: the
# paper's Kp with ten times its Ki (gains read as volts on the regulator's input,
# `Controller.command_scale`). On the shipped protocol the paper's own Ki ends every case
# of `python scripts/env_pi_gains.py` about as close (0.32-0.57 mm: the muscle on its contracting
# branch, Po near the regulator minimum); the tenfold Ki is kept for the environments whose
# Po works deeper in the band, where the paper's Ki is too slow within an episode.
PI_GAINS = {"ki": 10 * paper.KI}
SHIPPED = wpam_mj.preset()


@pytest.mark.parametrize("target, load", [(20 * MM, 100.0), (40 * MM, 50.0),
                                          (10 * MM, 150.0)])
def test_pi_policy_reaches_the_target(target, load) -> None:
    params = SHIPPED.replace(controller=PI_GAINS)
    env = make_env(params, target=target, load=load, time_limit=10.0)
    error, history = run_pi_episode(env, params)
    x = np.array([o["x_m"][0] for o in history])
    assert abs(x[0] - target) > 5 * MM, "the episode starts away from the target"
    assert error < 0.5 * MM, (f"|x - x_r| = {error / MM:.3f} mm after 10 s (target "
                              f"{target / MM:.0f} mm, {load:.0f} N), limit 0.5 mm")
    assert np.ptp(x[-200:]) < 0.2 * MM, "settled, not hunting, over the last 2 s"


def test_same_seed_same_episodes() -> None:
    params = PARAMS.replace(controller=PI_GAINS)
    runs = []
    for _ in range(2):
        env = make_env(params, seed=7, time_limit=1.0)
        runs.append([run_pi_episode(env, params)[1] for _ in range(2)])  # two episodes each
    for ep_a, ep_b in zip(*runs):
        assert len(ep_a) == len(ep_b)
        for a, b in zip(ep_a, ep_b):
            for name in OBSERVATIONS:
                np.testing.assert_array_equal(a[name], b[name], err_msg=name)
    first, second = runs[0]
    assert first[0]["target_m"][0] != second[0]["target_m"][0], "reset draws a new target"
    other = make_env(params, seed=8).reset().observation
    assert other["target_m"][0] != first[0]["target_m"][0]


def test_actions_are_clipped_to_the_bounds() -> None:
    env = make_env(PARAMS, action="both", target=0.02, load=100.0)
    env.reset()
    env.step([10 * MPA, 10 * MPA])
    assert env.physics.pi_cmd == PARAMS.pneumatics.p_max
    assert env.physics.po_cmd == PARAMS.controller.po_cap


@pytest.mark.parametrize("kwargs, message", [
    ({"action": "pi"}, "valid actions: po, both"),
    ({"control_timestep": 0.0105}, "whole multiple of dt"),
    ({"time_limit": 0.0}, "time_limit"),
    ({"target": 0.2}, "target = 0.2"),
    ({"load": 0.0}, "load = 0.0"),
    ({"load_range": (150.0, 50.0)}, "low <= high"),
    ({"reward": "dense"}, "valid rewards: tolerance, tracking"),
    ({"randomize": 1.5}, "relative spread must be a number in (0, 1)"),
])
def test_bad_options_raise_parameter_error(kwargs, message) -> None:
    with pytest.raises(ParameterError) as err:
        make_env(PARAMS, **kwargs)
    assert message in str(err.value)


def test_a_load_the_muscle_cannot_lift_is_refused_naming_the_largest() -> None:
    largest = max_liftable_load(PARAMS)
    for kwargs in ({"load": largest + 10}, {"load_range": (50.0, largest + 10)}):
        with pytest.raises(ParameterError, match=rf"cannot lift .* \[1, {largest:.1f}\] N"):
            make_env(PARAMS, **kwargs)
    make_env(PARAMS, load=largest - 10)


def test_staircase_targets_go_up_and_down_and_the_tracking_reward_is_linear() -> None:
    env = make_env(PARAMS, reference="staircase", reward="tracking", seed=0, time_limit=10.0)
    ts = env.reset()
    targets, rewards = [], []
    while not ts.last():
        ts = env.step([PARAMS.pneumatics.p_min])
        targets.append(ts.observation["target_m"][0])
        error = ts.observation["x_m"][0] - targets[-1]
        rewards.append((ts.reward, max(0.0, 1 - abs(error) / (1 * MM))))
    levels = np.unique(targets)
    # 2.5 s per level, the new one from t = 2.5 s on; the last observation, at 10 s, the 5th
    assert len(levels) == 5 and len(np.unique(targets[:249])) == 1
    assert targets[249] != targets[248]
    steps = np.diff([t for i, t in enumerate(targets) if i % 250 == 249])
    assert (steps > 0).any() and (steps < 0).any()
    np.testing.assert_allclose(*np.array(rewards).T, rtol=0, atol=1e-12)


def test_bad_action_raises_parameter_error() -> None:
    env = make_env(PARAMS)
    env.reset()
    with pytest.raises(ParameterError, match="1 finite number"):
        env.step([np.nan])
    with pytest.raises(ParameterError, match="po_cmd_pa"):
        env.step([0.01 * MPA, 0.02 * MPA])


def test_physics_copy_continues_identically() -> None:
    env = make_env(PARAMS, action="both", target=0.02, load=100.0)
    env.reset()
    env.step([0.4 * MPA, 0.01 * MPA])
    twin = env.physics.copy()
    env.physics.step(50)
    twin.step(50)
    assert twin.contraction() == env.physics.contraction()
    assert twin.pressures() == env.physics.pressures()


def _sine_rms_error_mm(controller: str) -> float:
    """RMS tracking error [mm] over the last 4 s of an 8 s, 0.25 Hz sine at 100 N, with
    the paper's PI as the agent commanding Po around `controller`'s feedforward."""
    env = make_env(controller=controller, reference="sine", sine_freq=0.25, load=100.0,
                   time_limit=8.0, seed=0)
    ts = env.reset()
    pi = PIControl.for_run(env.physics.params, env.control_timestep())
    errors = []
    while not ts.last():
        o = ts.observation
        ts = env.step([pi.update(float(o["x_m"][0]), float(o["target_m"][0]))])
        if env.physics.time() > 4.0:
            errors.append(float(ts.observation["x_m"][0] - ts.observation["target_m"][0]))
    return float(np.sqrt(np.mean(np.square(errors)))) / MM


def test_every_controller_runs_in_the_environment_and_pi_ff_halves_the_sine_error():
    """pi_ff needs the target ahead of time: the environment feeds it the episode's whole
    target path, and its air-flow feedforward (the regulators' dead time and lag led)
    takes the lag out that the PI alone leaves: measured 5.0 mm against 10.7 mm RMS."""
    assert _sine_rms_error_mm("pi_ff") < 0.5 * _sine_rms_error_mm("pi")
    for controller in ("open", "pid"):
        assert np.isfinite(_sine_rms_error_mm(controller))


def test_a_controller_with_both_commands_is_refused_by_name():
    with pytest.raises(ParameterError, match="controller = 'pi_ff'.*action=\"po\""):
        make_env(controller="pi_ff", action="both")
    with pytest.raises(ParameterError, match="unknown control 'bang'"):
        make_env(controller="bang")


@pytest.mark.parametrize("action, message", [
    (["0.02"], "dtype <U4"),
    ([True], "dtype bool"),
    ([np.inf], "action[0] = inf must be finite"),
    ([-np.inf], "action[0] = -inf must be finite"),
    ([[1.0], [2.0, 3.0]], "must be 1 finite number [Pa] (po_cmd_pa)"),
])
def test_strings_booleans_and_infinities_are_refused_in_one_line(action, message) -> None:
    """Only finite real numbers are an action: a string is no number even where numpy
    would parse it, and an infinity is refused as NaN is (out-of-range finite numbers
    are clipped, test_actions_are_clipped_to_the_bounds)."""
    env = make_env(PARAMS)
    env.reset()
    with pytest.raises(ParameterError) as err:
        env.step(action)
    assert message in str(err.value) and "\n" not in str(err.value)


def test_the_tolerance_reward_is_dm_controls_bit_for_bit() -> None:
    """The task's own reward (scalar, every step; arrays, the vector env) is
    dm_control's `rewards.tolerance` with the documented band, margin and tail."""
    from dm_control.utils import rewards  # noqa: PLC0415

    task = make_env(PARAMS)._task
    errors = np.concatenate([np.linspace(-8 * MM, 8 * MM, 4001), [0.5 * MM, -0.5 * MM]])
    expected = rewards.tolerance(errors, bounds=(-0.5 * MM, 0.5 * MM), margin=2 * MM,
                                 sigmoid="gaussian", value_at_margin=0.1)
    np.testing.assert_array_equal(task.rewards(errors), expected)
    np.testing.assert_array_equal([task.reward(float(e)) for e in errors], expected)


def test_renders_a_readable_frame_from_the_front_camera() -> None:
    """The physics is built on the rendering scene (light, backdrop, cameras): a frame is
    bright and shows the rig, not the near-black frame of a model without lights (mean
    pixel 1.9 before). MUJOCO_GL is read once per process: a fresh one with EGL."""
    code = ("import numpy as np\n"
            "from wpam_mj.environments.dm_env_task import make_env\n"
            "env = make_env(seed=0); env.reset()\n"
            "for camera in ('front', -1):\n"
            "    px = env.physics.render(120, 160, camera_id=camera) if camera != 'front' "
            "else env.physics.render(120, 160)\n"
            "    print(px.mean(), px.std())\n")
    env = {**os.environ, "MUJOCO_GL": "egl"}
    proc = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                          text=True, timeout=120)
    if proc.returncode and "EGL" in proc.stderr:
        pytest.skip(f"no EGL context here: {proc.stderr.strip().splitlines()[-1]}")
    assert proc.returncode == 0, proc.stderr
    (front_mean, front_std), (free_mean, _) = (map(float, line.split())
                                               for line in proc.stdout.split("\n")[:2])
    assert front_mean > 100 and front_std > 20  # lit, and something drawn on the backdrop
    assert free_mean > 50


def test_each_environment_module_stays_under_600_lines() -> None:
    """One job per module: dm_env_task.py (635 lines) was split into the task and
    muscle_physics.py, the physics it steps."""
    folder = Path(wpam_mj.__file__).parent / "environments"
    sizes = {p.name: len(p.read_text().splitlines()) for p in folder.glob("*.py")}
    assert max(sizes.values()) < 600, sizes
