"""The vector environment: the batched engine equals the serial one and SyncVectorEnv bit
for bit, autoreset semantics, the reward, the residual task's PI, refusals."""

from __future__ import annotations

import importlib
import re

import numpy as np
import pytest

gymnasium = pytest.importorskip("gymnasium", reason="gymnasium (the `rl` extra) not installed")
from gymnasium.vector import AutoresetMode, SyncVectorEnv  # noqa: E402

import wpam_mj  # noqa: E402
from wpam_mj.environments.gym_env import WPAMEnv  # noqa: E402
from wpam_mj.environments.policies import make_policy  # noqa: E402
from wpam_mj.environments.vector_env import make_vec  # noqa: E402
from wpam_mj.errors import ParameterError  # noqa: E402
from wpam_mj.units import MM  # noqa: E402
from wpam_mj.simulation import plugin  # noqa: E402

PARAMS = wpam_mj.preset("wpam", calibration=None)
needs_plugin = pytest.mark.skipif(not plugin.available(), reason="the compiled plugin is "
                                  "unavailable: no batched engine")


def assert_same(a, b, where: str = "") -> None:
    """Equal bit for bit, with equal dtypes, through dicts and object arrays."""
    if isinstance(a, dict):
        assert a.keys() == b.keys(), where
        for key in a:
            assert_same(a[key], b[key], f"{where}/{key}")
    elif isinstance(a, np.ndarray) and a.dtype == object:
        for x, y in zip(a, b):
            assert (x is None and y is None) or assert_same(x, y, where) is None
    else:
        assert np.asarray(a).dtype == np.asarray(b).dtype, where
        np.testing.assert_array_equal(a, b, err_msg=where)


def rollout(envs, steps: int, seed: int = 5) -> list:
    rng = np.random.default_rng(1)
    out = [envs.reset(seed=seed)]
    space = envs.action_space
    for _ in range(steps):
        out.append(envs.step(rng.uniform(-1, 1, space.shape).astype(space.dtype)))
    return out


def make(env_id: str, n: int, engine: str, mode: str = "NextStep", **kwargs):
    kwargs = {"params": PARAMS, "time_limit": 0.3, "max_episode_steps": 30, **kwargs}
    if engine == "sync":
        return SyncVectorEnv([lambda: gymnasium.make(env_id, **kwargs) for _ in range(n)],
                             autoreset_mode=AutoresetMode(mode))
    return gymnasium.make_vec(env_id, num_envs=n, engine=engine, autoreset_mode=mode,
                              **kwargs)


@needs_plugin
@pytest.mark.parametrize("mode", ["NextStep", "SameStep"])
@pytest.mark.parametrize("env_id, kwargs", [
    ("wpam_mj/WPAMTrack-v0", {}),
    ("wpam_mj/WPAM-v0", {}),
    ("wpam_mj/WPAMTrackResidual-v0", {}),
    ("wpam_mj/WPAMTrackBoth-v0", {}),
    ("wpam_mj/WPAMTrackSine-v0", {}),
    ("wpam_mj/WPAMTrackRandomized-v0", {}),
    ("wpam_mj/WPAMTrack-v0", {"controller": "pi_ff"}),
])
def test_batched_equals_serial_and_sync_vector_env(env_id, kwargs, mode) -> None:
    """Observations, rewards, ends and infos over two autoresets, bit for bit."""
    batch = rollout(make(env_id, 3, "batch", mode, nthread=2, **kwargs), 70)
    serial = rollout(make(env_id, 3, "serial", mode, **kwargs), 70)
    sync = rollout(make(env_id, 3, "sync", mode, **kwargs), 70)
    for k, (a, b, c) in enumerate(zip(batch, serial, sync)):
        for x, y, z in zip(a, b, c):
            assert_same(x, z, f"batch, call {k}")
            assert_same(y, z, f"serial, call {k}")


@needs_plugin
def test_results_do_not_depend_on_the_thread_count() -> None:
    one = rollout(make("wpam_mj/WPAMTrack-v0", 5, "batch", nthread=1), 40)
    two = rollout(make("wpam_mj/WPAMTrack-v0", 5, "batch", nthread=2), 40)
    for a, b in zip(one, two):
        for x, y in zip(a, b):
            assert_same(x, y)


@needs_plugin
def test_next_step_autoreset_and_same_step_autoreset() -> None:
    """Next step: the step after an episode's last resets it (reward 0, not ended, the new
    episode's first observation, time 0). Same step: the last observation goes to
    final_obs and the step returns the new episode's first."""
    envs = make("wpam_mj/WPAMTrack-v0", 2, "batch", time_limit=0.05, max_episode_steps=5)
    first, _ = envs.reset(seed=0)
    zero = np.zeros((2, 1), np.float32)
    for step in range(5):
        obs, rewards, terminated, truncated, infos = envs.step(zero)
        assert not terminated.any() and truncated.all() == (step == 4)
    obs, rewards, terminated, truncated, infos = envs.step(zero)
    assert (rewards == 0).all() and not (terminated | truncated).any()
    assert (infos["time_s"] == 0).all() and infos["_time_s"].all()
    fresh = make("wpam_mj/WPAMTrack-v0", 2, "serial", time_limit=0.05, max_episode_steps=5)
    fresh.reset(seed=0)
    assert_same(obs, np.stack([env.reset()[0] for env in fresh.envs]))  # the next episodes

    same = make("wpam_mj/WPAMTrack-v0", 2, "batch", "SameStep", time_limit=0.05,
                max_episode_steps=5)
    same.reset(seed=0)
    for _ in range(4):
        last, *_ = same.step(zero)
    obs, rewards, terminated, truncated, infos = same.step(zero)
    assert truncated.all() and infos["_final_obs"].all() and (infos["time_s"] == 0).all()
    assert infos["final_info"]["time_s"] == pytest.approx([0.05, 0.05])
    assert not np.array_equal(infos["final_obs"][0], obs[0])
    obs, *_ = same.step(zero)  # the new episodes continue: no reset step in between
    assert same.unwrapped._batch.k.tolist() == [1, 1]


@needs_plugin
def test_tracking_reward_is_linear_in_the_error_within_one_mm() -> None:
    envs = make("wpam_mj/WPAMTrack-v0", 4, "batch", time_limit=2.0, max_episode_steps=200)
    envs.reset(seed=3)
    seen = []
    for _ in range(200):
        _, rewards, _, _, infos = envs.step(np.full((4, 1), 0.1, np.float32))
        np.testing.assert_array_equal(
            rewards, np.maximum(0.0, 1.0 - np.abs(infos["error_m"]) / MM))
        assert (infos["is_success"] == (np.abs(infos["error_m"]) <= 0.5 * MM)).all()
        seen.extend(rewards)
    assert 0.0 < np.mean(seen) < 1.0 and min(seen) == 0.0


def test_residual_task_with_zero_action_is_the_paper_pi() -> None:
    """action="residual" adds the agent's Po to the paper's PI run in the environment: a
    zero action gives, bit for bit, the episode of the reference policy "pi" on Po."""
    kwargs = {"params": PARAMS, "reference": "staircase", "reward": "tracking",
              "time_limit": 3.0}
    residual = WPAMEnv(action="residual", **kwargs)
    po = WPAMEnv(action="po", **kwargs)
    residual.reset(seed=2)
    obs, info = po.reset(seed=2)
    pi = make_policy("pi", po, seed=2)
    for _ in range(300):
        a = residual.step(np.zeros(1))
        b = po.step(pi(obs, info))
        obs, info = b[0], b[4]
        for x, y in zip(a, b):
            assert_same(x, y)
    assert residual.action_space.low[0] == -PARAMS.controller.po_cap


@needs_plugin
def test_a_diverged_environment_ends_alone_with_its_last_valid_observation() -> None:
    """Stood in for: the muscle's status field set as the plugin sets it on a failure."""
    envs = make("wpam_mj/WPAMTrack-v0", 3, "batch", time_limit=1.0, max_episode_steps=100)
    envs.reset(seed=0)
    zero = np.zeros((3, 1), np.float32)
    for _ in range(5):
        last, *_ = envs.step(zero)
    batch = envs.unwrapped._batch
    batch.plugin_state[1, batch.status] = plugin.STATUS_PRESSURE
    obs, rewards, terminated, truncated, infos = envs.step(zero)
    assert terminated.tolist() == [False, True, False] and not truncated.any()
    assert rewards[1] == 0.0
    np.testing.assert_array_equal(obs[1], last[1])
    assert infos["_diverged"].tolist() == [False, True, False]
    assert infos["diverged"][1].startswith("chamber pressure Pi = ")
    obs, rewards, terminated, *_ = envs.step(zero)  # next step: env 1 starts again
    assert rewards[1] == 0.0 and not terminated.any() and infos["time_s"][0] > 0


@pytest.mark.parametrize("kwargs, message", [
    ({"engine": "gpu"}, "engine = 'gpu'; valid engines: auto, batch, serial"),
    ({"nthread": 0}, "nthread = 0 must be an integer >= 1"),
    ({"autoreset_mode": "Disabled"}, "autoreset_mode = 'Disabled'; valid: NextStep, SameStep"),
])
def test_bad_settings_are_refused_in_one_line(kwargs, message) -> None:
    with pytest.raises(ParameterError, match=message.replace("(", r"\(")):
        gymnasium.make_vec("wpam_mj/WPAMTrack-v0", num_envs=2, params=PARAMS, **kwargs)


@needs_plugin
def test_bad_actions_are_refused_in_one_line() -> None:
    envs = make("wpam_mj/WPAMTrack-v0", 2, "batch")
    envs.reset(seed=0)
    with pytest.raises(ParameterError, match=r"actions must be \(2, 1\) finite numbers"):
        envs.step(np.array([[0.1], [np.nan]]))
    with pytest.raises(ParameterError, match=r"got shape \(3,\)"):
        envs.step(np.zeros(3))



ENGINES = [pytest.param("batch", marks=needs_plugin), "serial"]


def _refusal(call) -> tuple[type, str]:
    with pytest.raises((ParameterError, RuntimeError)) as err:
        call()
    assert "\n" not in str(err.value)
    return type(err.value), str(err.value)


@pytest.mark.parametrize("engine", ENGINES)
def test_both_engines_refuse_the_same_bad_input_in_one_line(engine) -> None:
    """One check for both engines: (2, 3) actions for 3 environments x 2 channels are
    not redistributed, a step before reset, infinities, strings and a fractional seed
    are refused, each naming the value and what is allowed."""
    envs = make("wpam_mj/WPAMTrackBoth-v0", 3, engine)
    assert _refusal(lambda: envs.step(np.zeros((3, 2)))) == (
        RuntimeError, "cannot step: no episode has started; call reset() first")
    assert _refusal(lambda: envs.reset(seed=1.5))[1].startswith(
        "seed = 1.5 must be None, an integer")
    assert "seed = -1 must be None or an integer in [0, 4294967295]" in _refusal(
        lambda: envs.reset(seed=[0, -1, 2]))[1]
    envs.reset(seed=0)
    cases = {"shape (2, 3)": np.array([[0.5, 0.7, 0.1], [0.1, 0.5, 0.7]]),
             "actions[1, 0] = inf must be finite": np.array([[0, 0], [np.inf, 0], [0, 0]]),
             "actions[2, 1] = -inf must be finite": np.array([[0, 0], [0, 0], [0, -np.inf]]),
             "dtype <U3": np.full((3, 2), "0.5")}
    for message, actions in cases.items():
        kind, text = _refusal(lambda: envs.step(actions))
        assert kind is ParameterError and message in text, text
        assert "(3, 2) finite numbers, one row of 2 finite numbers in [-1, 1]" in text
    obs, *_ = envs.step(np.zeros((3, 2)))  # still running after the refusals
    assert obs.shape == (3, 7)


@needs_plugin
def test_both_engines_give_the_same_messages() -> None:
    batch, serial = (make("wpam_mj/WPAMTrack-v0", 2, e) for e in ("batch", "serial"))
    for envs in (batch, serial):
        envs.reset(seed=0)
    for actions in ([[np.nan], [0.0]], [[0.0], [-np.inf]], np.zeros((2, 2)), "0.5",
                    [["a"], [0.1]]):
        assert _refusal(lambda: batch.step(actions)) == _refusal(lambda: serial.step(actions))


def _dead_time_ranges(tmp_path, lo: float, hi: float):
    path = tmp_path / "ranges.toml"
    path.write_text(f"[pneumatics]\ndead_time = [{lo!r}, {hi!r}]\n")
    return path


@needs_plugin
def test_a_randomized_dead_time_runs_on_the_serial_engine_through_autoresets(
        tmp_path) -> None:
    """A dead time drawn per episode sizes the plugin state per episode (its queues):
    'auto' takes the serial engine, which runs through autoresets (the batched one
    failed there with mj_setState's TypeError); 'batch' is refused up front."""
    ranges = _dead_time_ranges(tmp_path, 0.005, 0.04)
    envs = make("wpam_mj/WPAMTrackRandomized-v0", 2, "auto", randomize=ranges,
                time_limit=0.05, max_episode_steps=5)
    assert envs.unwrapped.engine == "serial"
    envs.reset(seed=0)
    sizes = set()
    for _ in range(18):  # three episodes each
        obs, *_ = envs.step(np.zeros((2, 1), np.float32))
        sizes.update(env.physics.model.npluginstate for env in envs.unwrapped.envs)
        assert np.isfinite(obs).all()
    assert len(sizes) > 1
    with pytest.raises(ParameterError, match=re.escape(
            "engine = 'batch' needs one plugin state size for every episode, but randomize "
            "draws pneumatics.dead_time from [0.005, 0.04] s, dead-time queues of 5 to 40 "
            "steps of 0.001 s; use engine='serial' or 'auto'")):
        make("wpam_mj/WPAMTrackRandomized-v0", 2, "batch", randomize=ranges)
    # a range within one step count keeps the batched engine
    same = make("wpam_mj/WPAMTrackRandomized-v0", 2, "auto",
                randomize=_dead_time_ranges(tmp_path, 0.0201, 0.0204))
    assert same.unwrapped.engine == "batch"


def test_make_vec_takes_the_settings_in_gymnasiums_vector_kwargs_spelling() -> None:
    """gymnasium.make_vec refuses vector_kwargs for an environment with its own vector
    entry point; `vector_env.make_vec` takes them in either spelling, once."""
    envs = make_vec("wpam_mj/WPAMTrack-v0", 2, vector_kwargs={
        "autoreset_mode": "SameStep", "engine": "serial"}, params=PARAMS)
    assert envs.autoreset_mode == AutoresetMode.SAME_STEP and envs.engine == "serial"
    assert make_vec("wpam_mj/WPAMTrack-v0", 2, autoreset_mode="SameStep",
                    params=PARAMS).autoreset_mode == AutoresetMode.SAME_STEP
    with pytest.raises(ParameterError, match="vector_kwargs 'copy' unknown; the vector "
                       "env's settings: engine, nthread, autoreset_mode"):
        make_vec("wpam_mj/WPAMTrack-v0", 2, vector_kwargs={"copy": False})
    with pytest.raises(ParameterError, match="engine given twice"):
        make_vec("wpam_mj/WPAMTrack-v0", 2, vector_kwargs={"engine": "serial"},
                 engine="batch")


def test_the_sb3_module_names_the_learn_extra_where_sb3_is_missing() -> None:
    if importlib.util.find_spec("stable_baselines3") is not None:
        pytest.skip("the learn extra is installed: tests/test_sb3.py runs instead")
    with pytest.raises(ImportError, match=re.escape(
            'needs stable-baselines3 (No module named \'stable_baselines3\'): install the '
            'learn extra, pip install ".[learn]"')):
        importlib.import_module("wpam_mj.environments.sb3")
