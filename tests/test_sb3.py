"""wpam_mj.environments.sb3: the batched vector env as Stable-Baselines3's VecEnv (the
`learn` extra): SB3's protocol at episode ends, seeding, and a PPO update through it."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("stable_baselines3", reason="the `learn` extra is not installed")
from stable_baselines3 import PPO  # noqa: E402
from stable_baselines3.common.vec_env import VecMonitor  # noqa: E402

import wpam_mj  # noqa: E402
from wpam_mj.environments.sb3 import BatchedVecEnv  # noqa: E402
from wpam_mj.errors import ParameterError  # noqa: E402

PARAMS = wpam_mj.preset("wpam", calibration=None)
SHORT = {"params": PARAMS, "time_limit": 0.05, "max_episode_steps": 5}


def test_an_episode_end_resets_in_the_same_step_with_the_terminal_observation() -> None:
    venv = BatchedVecEnv("wpam_mj/WPAMTrack-v0", 3, **SHORT)
    venv.seed(4)
    first = venv.reset()
    zero = np.zeros((3, 1), np.float32)
    for step in range(5):
        venv.step_async(zero)
        obs, rewards, dones, infos = venv.step_wait()
        assert dones.all() == (step == 4) and rewards.dtype == np.float32
        assert all(0.0 < info["time_s"] < 0.05 + 1e-9 for info in infos)
    for info in infos:  # the ended episode's last step, at 50 ms
        assert info["TimeLimit.truncated"] and info["time_s"] == pytest.approx(0.05)
        assert info["terminal_observation"].shape == (7,) and "is_success" in info
    assert not np.array_equal(obs, np.stack([i["terminal_observation"] for i in infos]))
    venv.seed(4)  # the same seeds give the same first observations
    np.testing.assert_array_equal(venv.reset(), first)
    assert venv.get_attr("frame_skip") == [10, 10, 10]
    assert venv.env_is_wrapped(VecMonitor) == [False, False, False]
    venv.close()


def test_ppo_trains_through_it_and_it_takes_gymnasiums_vector_kwargs() -> None:
    venv = VecMonitor(BatchedVecEnv("wpam_mj/WPAMTrackResidual-v0", 2,
                                    vector_kwargs={"nthread": 1}, **SHORT))
    model = PPO("MlpPolicy", venv, n_steps=16, batch_size=32, n_epochs=1, seed=0,
                device="cpu")
    model.learn(total_timesteps=32)
    assert model.num_timesteps == 32


def test_another_autoreset_mode_is_refused_in_one_line() -> None:
    with pytest.raises(ParameterError, match="autoreset_mode = 'NextStep': SB3's VecEnv"):
        BatchedVecEnv("wpam_mj/WPAMTrack-v0", 2, autoreset_mode="NextStep", **SHORT)
