"""Many W-PAM environments stepped in one call: the ids' `vector_entry_point`.

    envs = gymnasium.make_vec("wpam_mj/WPAMTrack-v0", num_envs=8)
    obs, infos = envs.reset(seed=0)          # env i seeded with 0 + i, as SyncVectorEnv
    obs, rewards, terminated, truncated, infos = envs.step(envs.action_space.sample())

Same results as `gymnasium.vector.SyncVectorEnv` over N `WPAMEnv` (next-step autoreset,
the registered `max_episode_steps`, infos batched the same way; tests/test_gym_env.py).
The physics of the N environments is advanced by a `Stepper`, the one seam between the
batch and the engine: `SerialStepper` steps each environment in turn today; a stepper
that advances all N MuJoCo states at once (`mujoco.batch`, once the muscle is a MuJoCo
actuator plugin) replaces it without touching the rest of this module.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol

import numpy as np
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from wpam_mj.environments.gym_env import WPAMEnv, check_episode_steps
from wpam_mj.physics.params import ParameterError

Transition = tuple[np.ndarray, float, bool, bool, dict]


class Stepper(Protocol):
    """Advances the environments at `indices` by one step each, with their actions."""

    def step(self, envs: Sequence[WPAMEnv], indices: Sequence[int],
             actions: Sequence[np.ndarray]) -> list[Transition]: ...


class SerialStepper:
    """One environment after the other (the per-env engine of today)."""

    def step(self, envs: Sequence[WPAMEnv], indices: Sequence[int],
             actions: Sequence[np.ndarray]) -> list[Transition]:
        return [envs[i].step(a) for i, a in zip(indices, actions)]


class WPAMVectorEnv(VectorEnv):
    """`num_envs` `WPAMEnv(**kwargs)`; each env ends its episodes at its time_limit, which
    `max_episode_steps` (gymnasium.make_vec passes the registered one) may not cut short."""

    metadata = {"autoreset_mode": AutoresetMode.NEXT_STEP, "render_modes": []}

    def __init__(self, num_envs: int = 1, *, max_episode_steps: int | None = None,
                 stepper: Stepper | None = None, **kwargs) -> None:
        if isinstance(num_envs, bool) or not isinstance(num_envs, (int, np.integer)) \
                or num_envs < 1:
            raise ParameterError(f"num_envs = {num_envs!r} must be an integer >= 1")
        self.envs = [WPAMEnv(**kwargs) for _ in range(num_envs)]
        self.num_envs = int(num_envs)
        self.single_action_space = self.envs[0].action_space
        self.single_observation_space = self.envs[0].observation_space
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self._stepper = stepper or SerialStepper()
        check_episode_steps(self.envs[0].episode_steps, max_episode_steps)
        self._autoreset = np.zeros(self.num_envs, dtype=bool)

    def reset(self, *, seed: int | Sequence[int | None] | None = None,
              options: dict | None = None) -> tuple[np.ndarray, dict]:
        if seed is None or isinstance(seed, (int, np.integer)):
            seeds = [None if seed is None else int(seed) + i for i in range(self.num_envs)]
        else:
            seeds = list(seed)
            if len(seeds) != self.num_envs:
                raise ParameterError(f"{len(seeds)} seeds for {self.num_envs} environments")
        obs, infos = [], {}
        for i, (env, s) in enumerate(zip(self.envs, seeds)):
            o, info = env.reset(seed=s, options=options)
            obs.append(o)
            infos = self._add_info(infos, info, i)
        self._autoreset[:] = False
        return np.stack(obs), infos

    def step(self, actions) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict]:
        actions = np.asarray(actions)
        n = self.num_envs
        obs = [None] * n
        rewards = np.zeros(n)
        terminated, truncated = np.zeros(n, dtype=bool), np.zeros(n, dtype=bool)
        infos_each: list[dict] = [{}] * n
        for i in np.flatnonzero(self._autoreset):  # next-step autoreset
            obs[i], infos_each[i] = self.envs[i].reset()
        stepping = np.flatnonzero(~self._autoreset)
        results = self._stepper.step(self.envs, stepping, [actions[i] for i in stepping])
        for i, (o, r, term, trunc, info) in zip(stepping, results):
            obs[i], rewards[i], terminated[i], truncated[i], infos_each[i] = o, r, term, trunc, info
        infos: dict = {}
        for i, info in enumerate(infos_each):
            infos = self._add_info(infos, info, i)
        self._autoreset = terminated | truncated
        return np.stack(obs), rewards, terminated, truncated, infos

    def close_extras(self, **kwargs) -> None:
        for env in self.envs:
            env.close()
