"""Stable-Baselines3's VecEnv over the batched vector environment (the `learn` extra).

    from stable_baselines3 import PPO
    from wpam_mj.environments.sb3 import BatchedVecEnv
    venv = BatchedVecEnv("wpam_mj/WPAMTrackResidual-v0", 16, nthread=2)
    model = PPO("MlpPolicy", venv).learn(100_000)

`BatchedVecEnv` steps `wpam_mj.environments.vector_env.WPAMVectorEnv` (all environments in
one `mujoco.batch` call where the plugin is compiled) and speaks SB3's VecEnv protocol
(SB3 docs, "Vectorized Environments"): an episode that ends at a step is reset in that
step, its last observation in info["terminal_observation"] and its end by the time limit
in info["TimeLimit.truncated"], so it runs the vector env with same-step autoreset. Each
environment's info carries the Gymnasium env's keys (x_m, error_m, is_success, ...; at
an episode's end, its last step's), which SB3 reads for its success rate. `seed` (then
`reset`) seeds environment i with seed + i, as SB3's own VecEnvs do.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from wpam_mj.environments.vector_env import make_vec
from wpam_mj.errors import ParameterError

try:
    from stable_baselines3.common.vec_env import VecEnv
except ImportError as err:  # the optional extra
    raise ImportError(f"wpam_mj.environments.sb3 needs stable-baselines3 ({err}): install "
                      "the learn extra, pip install \".[learn]\" (docs/learning.md)") from None

SB3_AUTORESET = "SameStep"  # what SB3's VecEnv protocol is


def _one(infos: dict, i: int) -> dict:
    """Environment i's info from Gymnasium's batched infos (arrays, "_key" masks)."""
    return {k: v[i] for k, v in infos.items()
            if not k.startswith(("_", "final_")) and infos[f"_{k}"][i]}


class BatchedVecEnv(VecEnv):
    """`num_envs` environments of the registered `env_id` (keyword arguments: those of
    `WPAMEnv` and `WPAMVectorEnv`, in either of `make_vec`'s spellings) as SB3's VecEnv;
    see the module docstring."""

    def __init__(self, env_id: str, num_envs: int, *, vector_kwargs: dict | None = None,
                 **kwargs) -> None:
        mode = {**(vector_kwargs or {}), **kwargs}.get("autoreset_mode", SB3_AUTORESET)
        if str(getattr(mode, "value", mode)) != SB3_AUTORESET:
            raise ParameterError(f"autoreset_mode = {mode!r}: SB3's VecEnv resets an episode "
                                 f"in the step that ends it ({SB3_AUTORESET}); leave it out")
        kwargs.pop("autoreset_mode", None)
        vector_kwargs = {**(vector_kwargs or {}), "autoreset_mode": SB3_AUTORESET}
        self.venv = make_vec(env_id, num_envs, vector_kwargs=vector_kwargs, **kwargs)
        super().__init__(num_envs, self.venv.single_observation_space,
                         self.venv.single_action_space)
        self._actions: np.ndarray | None = None

    def reset(self) -> np.ndarray:
        obs, _ = self.venv.reset(seed=[None if s is None else int(s) for s in self._seeds])
        self._reset_seeds()
        return obs

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = actions

    def step_wait(self):
        obs, rewards, terminated, truncated, infos = self.venv.step(self._actions)
        dones = terminated | truncated
        info_list = [_one(infos, i) for i in range(self.num_envs)]
        for i in np.flatnonzero(dones):  # the ended episode's last info, not the next's first
            info_list[i] = {**_one(infos["final_info"], i),
                            "terminal_observation": infos["final_obs"][i],
                            "TimeLimit.truncated": bool(truncated[i] and not terminated[i])}
        return obs, rewards.astype(np.float32), dones, info_list

    def close(self) -> None:
        self.venv.close()

    def get_attr(self, attr_name: str, indices=None) -> list:
        return [getattr(self.venv.envs[i], attr_name) for i in self._get_indices(indices)]

    def set_attr(self, attr_name: str, value, indices=None) -> None:
        for i in self._get_indices(indices):
            setattr(self.venv.envs[i], attr_name, value)

    def env_method(self, method_name: str, *method_args, indices=None, **method_kwargs):
        return [getattr(self.venv.envs[i], method_name)(*method_args, **method_kwargs)
                for i in self._get_indices(indices)]

    def env_is_wrapped(self, wrapper_class, indices=None) -> Sequence[bool]:
        return [False for _ in self._get_indices(indices)]  # bare WPAMEnv, no wrappers
