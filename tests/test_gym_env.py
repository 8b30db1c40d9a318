"""The Gymnasium environment: API contract, same trajectories as dm_control, a PI reaches."""

from __future__ import annotations

import re
import time
import warnings
from pathlib import Path

import mujoco
import numpy as np
import pytest

gymnasium = pytest.importorskip("gymnasium", reason="gymnasium (the `rl` extra) not installed")
from gymnasium.utils.env_checker import check_env  # noqa: E402

import wpam_mj  # noqa: E402
from wpam_mj import paper  # noqa: E402
from wpam_mj.control.controllers import PIControl  # noqa: E402
from wpam_mj.environments.dm_env_task import (OBSERVATIONS, dm_control_runs,  # noqa: E402
                                              make_env)
from wpam_mj.environments.gym_env import ENV_ID, WPAMEnv  # noqa: E402
from wpam_mj.errors import ParameterError  # noqa: E402
from wpam_mj.units import MM, MPA  # noqa: E402
from wpam_mj.environments.policies import mean_return  # noqa: E402
from wpam_mj.environments.registry import VARIANTS  # noqa: E402
from wpam_mj.simulation.context import RunContext  # noqa: E402
from wpam_mj.simulation.live import LiveRig  # noqa: E402

# Code defaults, not the calibration file: these tests pin the environment, not the fit.
PARAMS = wpam_mj.preset("wpam", calibration=None)
README = Path(__file__).resolve().parents[1] / "README.md"


def checked(env) -> None:
    """gymnasium's checker; its advice on unbounded and non-normalized Boxes is by design."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # any other warning fails the test
        warnings.filterwarnings("ignore", message=".*(infinity|symmetric and normalized)")
        check_env(env)


@pytest.mark.parametrize("kwargs", [{}, {"action": "both"}, {"reference": "sine"},
                                    {"frame_skip": 1, "load": 80.0}])
def test_passes_gymnasium_env_checker(kwargs) -> None:
    checked(gymnasium.make(ENV_ID, params=PARAMS, **kwargs).unwrapped)  # with its spec


def test_registered_on_import_with_si_spaces() -> None:
    env = gymnasium.make(ENV_ID, params=PARAMS, time_limit=0.05)
    assert isinstance(env.unwrapped, WPAMEnv)
    space = env.action_space
    assert space.low[0] == PARAMS.pneumatics.p_min
    assert space.high[0] == PARAMS.controller.po_cap == pytest.approx(0.08 * MPA)
    obs, info = env.reset(seed=1)
    assert obs.shape == (len(OBSERVATIONS),) and info["time_s"] == 0.0
    steps, truncated = 0, False
    while not truncated:
        obs, _, terminated, truncated, info = env.step(space.high)
        assert not terminated
        steps += 1
    assert steps == 5 and info["time_s"] == pytest.approx(0.05)
    with pytest.raises(RuntimeError, match="time limit; call reset"):
        env.unwrapped.step(space.high)


@pytest.mark.parametrize("frame_skip, dt", [(1, 1e-3), (4, 5e-4), (25, 2e-3)])
def test_frame_skip_sets_the_control_step(frame_skip, dt) -> None:
    env = WPAMEnv(PARAMS, frame_skip=frame_skip, dt=dt)
    env.reset(seed=0)
    _, _, _, _, info = env.step([0.02 * MPA])
    assert env.physics.model.opt.timestep == dt
    assert info["time_s"] == pytest.approx(frame_skip * dt, rel=1e-9)
    assert env.metadata["render_fps"] == pytest.approx(1 / (frame_skip * dt))


@pytest.mark.skipif(not dm_control_runs(), reason="dm_control does not run on this mujoco")
@pytest.mark.parametrize("reference, action", [("step", "po"), ("sine", "po"),
                                               ("step", "both")])
def test_same_trajectory_as_dm_control(reference, action) -> None:
    """Same seed and actions: identical observations and rewards, two episodes each."""
    gym_env = WPAMEnv(PARAMS, action=action, reference=reference, time_limit=0.5)
    dm_env = make_env(PARAMS, action=action, reference=reference, time_limit=0.5, seed=3,
                      flat_observation=True)
    rng = np.random.default_rng(0)
    space = gym_env.action_space
    obs, _ = gym_env.reset(seed=3)
    for episode in range(2):
        if episode:
            obs, _ = gym_env.reset()
        ts = dm_env.reset()
        np.testing.assert_array_equal(obs, ts.observation["observations"])
        truncated = False
        while not truncated:
            action = rng.uniform(space.low, space.high)
            obs, reward, _, truncated, _ = gym_env.step(action)
            ts = dm_env.step(action)
            np.testing.assert_array_equal(obs, ts.observation["observations"])
            assert reward == ts.reward
        assert ts.last()
    assert obs[0] > 1 * MM, "the comparison should include motion"


def test_same_seed_same_episode_other_seed_other_task() -> None:
    env = WPAMEnv(PARAMS, reference="sine", time_limit=0.3)
    actions = np.random.default_rng(1).uniform(env.action_space.low, env.action_space.high,
                                               (30, 1))

    def episode(seed):
        obs, _ = env.reset(seed=seed)
        return np.array([obs] + [env.step(a)[0] for a in actions])

    a, b, c = episode(5), episode(5), episode(6)
    np.testing.assert_array_equal(a, b)
    assert a[0, 5] != c[0, 5], "another seed draws another load"
    assert len(np.unique(a[:, 4])) > 10, "the sine target moves"


def test_sine_target_follows_the_paper_sinusoid() -> None:
    """x_r(t) = 25 mm - 25 mm cos(2 pi f t), observed at each control step (paper §4.2)."""
    env = WPAMEnv(PARAMS, reference="sine", sine_freq=0.5, time_limit=2.0)
    obs, _ = env.reset(seed=0)
    targets, times = [obs[4]], [0.0]
    truncated = False
    while not truncated:
        obs, _, _, truncated, info = env.step([0.02 * MPA])
        targets.append(obs[4])
        times.append(info["time_s"])
    expected = 25 * MM - 25 * MM * np.cos(2 * np.pi * 0.5 * np.array(times))
    np.testing.assert_allclose(targets, expected, rtol=0, atol=1e-12)
    assert max(targets) == pytest.approx(50 * MM)


# The PI policy of tests/test_env.py (the paper's Kp, ten times its Ki; why there), on the
# shipped plant.
PI_GAINS = {"ki": 10 * paper.KI}


@pytest.mark.parametrize("target, load", [(20 * MM, 100.0), (40 * MM, 50.0),
                                          (10 * MM, 150.0)])
def test_pi_policy_reaches_a_step_target(target, load) -> None:
    params = wpam_mj.preset().replace(controller=PI_GAINS)
    env = gymnasium.make(ENV_ID, params=params, target=target, load=load, time_limit=10.0)
    obs, _ = env.reset(seed=0)
    pid = PIControl.for_run(params, env.unwrapped.physics.model.opt.timestep * 10)
    xs = [obs[0]]
    done = False
    while not done:
        obs, _, terminated, truncated, _ = env.step([pid.update(obs[0], obs[4])])
        xs.append(obs[0])
        done = terminated or truncated
    assert not terminated
    assert abs(xs[0] - target) > 5 * MM, "the episode starts away from the target"
    error = abs(obs[0] - obs[4])
    assert error < 0.5 * MM, (f"|x - x_r| = {error / MM:.3f} mm after 10 s (target "
                              f"{target / MM:.0f} mm, {load:.0f} N), limit 0.5 mm")
    assert np.ptp(xs[-200:]) < 0.2 * MM, "settled, not hunting, over the last 2 s"


def test_a_chamber_too_fast_for_dt_is_refused_naming_the_dt_it_needs() -> None:
    params = PARAMS.replace(pneumatics={"inner_conductance": 1e-6})
    with pytest.raises(ParameterError, match=r"use dt <= 7.96e-05 s"):
        WPAMEnv(params, action="both", frame_skip=1, dt=5e-3)


def test_divergence_ends_the_episode_cleanly(monkeypatch) -> None:
    """A divergence reported by the physics step (stood in for: the step raises after
    20 steps) ends the episode with the last valid observation."""
    from wpam_mj.simulation import live  # noqa: PLC0415
    from wpam_mj.simulation.loop_contract import SimulationDiverged  # noqa: PLC0415

    real_step, calls = live.LiveRig.step, []

    def failing(self, data, nstep=1):
        calls.append(nstep)
        if len(calls) > 20:
            raise SimulationDiverged("chamber pressure Pi = -1 Pa (stand-in)")
        real_step(self, data, nstep)

    env = WPAMEnv(PARAMS, action="both", frame_skip=1)
    last, _ = env.reset(seed=0)
    monkeypatch.setattr(live.LiveRig, "step", failing)
    for _ in range(100):
        obs, reward, terminated, truncated, info = env.step([0.5 * MPA, 0.05 * MPA])
        if terminated:
            break
        last = obs
    assert terminated and not truncated and reward == 0.0
    assert "chamber pressure" in info["diverged"]
    np.testing.assert_array_equal(obs, last)  # the last valid observation
    assert obs in env.observation_space
    with pytest.raises(RuntimeError, match="diverged .* call reset"):
        env.step([0.5 * MPA, 0.05 * MPA])
    monkeypatch.setattr(live.LiveRig, "step", real_step)
    env.reset()
    env.step([0.1 * MPA, 0.05 * MPA])  # a new episode runs


def test_step_before_reset_and_bad_options() -> None:
    env = WPAMEnv(PARAMS)
    with pytest.raises(RuntimeError, match="no episode has started"):
        env.step([0.02 * MPA])
    for kwargs, message in (({"frame_skip": 0}, "frame_skip = 0"),
                            ({"frame_skip": 2.5}, "frame_skip = 2.5"),
                            ({"render_mode": "human"}, "render_mode = 'human'"),
                            ({"reference": "ramp"}, "valid references: step, sine"),
                            ({"sine_freq": -1.0}, "freq = -1"),
                            ({"dt": 1.0}, "dt = 1")):
        with pytest.raises(ParameterError, match=re.escape(message)):
            WPAMEnv(PARAMS, **kwargs)


def test_rgb_array_render_follows_the_load() -> None:
    env = WPAMEnv(PARAMS, action="both", render_mode="rgb_array", render_size=(160, 120),
                  target=0.04, load=100.0)
    env.reset(seed=0)
    try:
        rest = env.render()
    except RuntimeError as err:  # wpam_mj.visualisation.render: no OpenGL context here
        pytest.skip(str(err))
    for _ in range(100):  # 1 s at full Pi: the muscle contracts
        obs, *_ = env.step([0.5 * MPA, 0.0])
    moved = env.render()
    env.close()
    assert rest.shape == (120, 160, 3) and rest.dtype == np.uint8
    assert rest.std() > 10, "the frame shows the rig"
    assert obs[0] > 20 * MM
    assert np.abs(rest.astype(int) - moved).mean() > 1, "the frame follows the load"


def test_readme_gymnasium_example_runs(capsys) -> None:
    text = README.read_text(encoding="utf-8")
    section = text.split("## Gymnasium", 1)[1].split("\n## ", 1)[0]
    code = re.search(r"```python\n(.*?)```", section, re.S).group(1)
    assert len(code.strip().splitlines()) <= 12
    exec(compile(code, "README.md", "exec"), {})
    assert "mm" in capsys.readouterr().out


# ---------------------------------------------------------------- learning variants

TRACK_IDS = [i for i in VARIANTS if i != ENV_ID]


@pytest.mark.parametrize("env_id", TRACK_IDS)
def test_normalised_variants_pass_the_checker_without_any_warning(env_id) -> None:
    env = gymnasium.make(env_id, params=PARAMS)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_env(env.unwrapped)
    assert env.spec.max_episode_steps == 1000
    assert env.action_space.dtype == env.observation_space.dtype == np.float32
    assert np.all(env.action_space.low == -1) and np.all(env.observation_space.high == 1)


def test_info_carries_error_commands_and_success() -> None:
    env = gymnasium.make("wpam_mj/WPAMTrack-v0", params=PARAMS)
    _, info = env.reset(seed=0)
    _, _, _, _, info = env.step(np.array([1.0], dtype=np.float32))  # Po at its cap
    assert info["po_cmd_pa"] == PARAMS.controller.po_cap and info["pi_cmd_pa"] > 0
    assert info["error_m"] == info["x_m"] - info["target_m"]
    assert info["is_success"] == (abs(info["error_m"]) <= 0.5 * MM)


def test_constant_po_scores_far_below_the_paper_pi() -> None:
    """On the learning task holding Po at 5 kPa (the Pi feedforward alone) earns under 30 %
    of what the paper's PI earns (docs/learning.md), mean of 10 seeds."""
    scores = {p: mean_return("wpam_mj/WPAMTrack-v0", p, range(10)) for p in ("constant", "pi")}
    assert scores["constant"] < 0.3 * scores["pi"], scores


def test_make_accepts_randomize_and_draws_a_plant_per_episode(tmp_path) -> None:
    ranges = tmp_path / "ranges.toml"
    ranges.write_text("[muscle]\nfriction_coeff = [0.1, 0.4]\n", encoding="utf-8")
    env = gymnasium.make(ENV_ID, params=PARAMS, randomize=str(ranges))
    drawn = set()
    for seed in range(3):
        env.reset(seed=seed)
        drawn.add(env.unwrapped.physics.params.muscle.friction_coeff)
    assert len(drawn) == 3 and all(0.1 <= mu <= 0.4 for mu in drawn)
    relative = gymnasium.make("wpam_mj/WPAMTrackRandomized-v0", params=PARAMS)
    relative.reset(seed=0)
    assert relative.unwrapped.physics.params != PARAMS


def test_reset_options_fix_one_episode_and_refuse_the_unknown() -> None:
    env = WPAMEnv(PARAMS)
    _, info = env.reset(seed=0, options={"target": 0.02, "load": 60.0})
    assert info["target_m"] == 0.02 and env.physics.load() == pytest.approx(60.0)
    _, info = env.reset()
    assert info["target_m"] != 0.02
    for options, message in (({"targt": 0.02}, "reset option(s) 'targt' unknown"),
                             ({"load": "heavy"}, "reset option load = 'heavy' must be"),
                             ({"target": 1.0}, "target = 1"), ([1], "must be a dict")):
        with pytest.raises(ParameterError, match=re.escape(message)):
            env.reset(options=options)


def test_params_by_preset_name_or_refused_in_one_line() -> None:
    env = gymnasium.make(ENV_ID, params="wpam")
    assert env.unwrapped.physics.params.preset == "wpam"
    for params, message in (("wpm", "unknown preset 'wpm'"), (3, "params = 3 must be"),
                            ("rlam", "the rlam preset has no outer chamber for the Po command")):
        with pytest.raises(ParameterError, match=re.escape(message)):
            gymnasium.make(ENV_ID, params=params)


def test_vector_env_refuses_a_time_limit_its_max_episode_steps_would_cut() -> None:
    with pytest.raises(ParameterError, match="pass max_episode_steps=2000"):
        gymnasium.make_vec(ENV_ID, num_envs=2, params=PARAMS, time_limit=20.0)
    gymnasium.make_vec(ENV_ID, num_envs=2, params=PARAMS, time_limit=20.0,
                       max_episode_steps=2000)


def test_the_dm_control_env_refuses_mujoco_4_naming_the_versions_that_work(
        monkeypatch) -> None:
    """dm-control 1.0.50 fails on mujoco 4 (MjModel has no flex_vertedge): make_env says
    so in one line, while the Gymnasium environment runs without dm_control's Physics."""
    import mujoco  # noqa: PLC0415

    monkeypatch.setattr(mujoco, "__version__", "4.0.0")
    with pytest.raises(RuntimeError, match=r"^the dm_control environment needs mujoco "
                       r">= 3.17, < 4 \(dm-control fails on mujoco 4.0.0\)[^\n]*$"):
        make_env(PARAMS)
    env = gymnasium.make("wpam_mj/WPAMTrack-v0", params=PARAMS)
    env.reset(seed=0)
    env.step(env.action_space.sample())


def test_a_normalised_env_refuses_infinities_strings_and_a_fractional_seed() -> None:
    """The single env checks what it is given as the vector env does (one check,
    `check_actions`): an infinity is refused rather than clipped to the bound, a string
    is no number, a seed must be an integer of numpy's range; each in one line."""
    env = WPAMEnv(PARAMS, normalize=True)
    for seed, message in ((1.5, "seed = 1.5 must be None or an integer in [0, 4294967295]"),
                          (2**32, "seed = 4294967296 must be None or an integer")):
        with pytest.raises(ParameterError, match=re.escape(message)):
            env.reset(seed=seed)
    env.reset(seed=0)
    for action, message in (([np.inf], "action[0] = inf must be finite: action must be 1 "
                                       "finite number in [-1, 1] (po_cmd_pa as fractions"),
                            (np.array(["0.5"]), "dtype <U3"),
                            (np.zeros(2, np.float32), "got shape (2,)")):
        with pytest.raises(ParameterError, match=re.escape(message)):
            env.step(action)
    env.step(np.array([2.0], np.float32))  # a finite number out of range: clipped
    assert env.physics.po_cmd == PARAMS.controller.po_cap


def _step_seconds(step, n: int) -> float:
    start = time.perf_counter()
    for _ in range(n):
        step()
    return time.perf_counter() - start


def test_an_env_step_costs_little_beside_its_physics() -> None:
    """benchmarks/bench_env.py measures it (Gymnasium and dm_control >= 0.5 of the bare
    rig's steps per second): here a loose floor, best of interleaved runs, that the env
    layers once missed by far (0.12 and 0.45: per-step warning lists, dm_control's
    reward and flattening, the observation built twice)."""
    rig = LiveRig.build(RunContext(PARAMS, 1e-3, 100.0))
    data = mujoco.MjData(rig.model)
    env = WPAMEnv(PARAMS, target=20 * MM, load=100.0, time_limit=100.0)
    env.reset(seed=0)
    action = np.array([0.03 * MPA])

    def direct() -> None:
        rig.set_commands(data, 1e5, 0.03 * MPA)
        rig.step(data, 10)

    rows = {"direct": direct, "gym": lambda: env.step(action)}
    if dm_control_runs():
        dm = make_env(PARAMS, target=20 * MM, load=100.0, time_limit=100.0,
                      flat_observation=True)
        dm.reset()
        rows["dm_control"] = lambda: dm.step(action)
    best = dict.fromkeys(rows, np.inf)
    for _ in range(5):
        for name, step in rows.items():
            best[name] = min(best[name], _step_seconds(step, 200))
    ratios = {name: best["direct"] / best[name] for name in rows}
    assert min(ratios.values()) > 0.3, ratios
