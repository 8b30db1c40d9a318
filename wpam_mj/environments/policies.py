"""Reference policies for the Gymnasium environments, and their scores.

A learned policy is worth something only against these: holding Po still at the
regulator minimum (the Pi feedforward then does all the work), random actions, and the
paper's PI on Po (`wpam_mj.control.controllers.PIControl`, the paper's gains). Each works on the SI
and the normalised spaces (`WPAMEnv.scaling`) with action="po".

    scores = {name: mean_return("wpam_mj/WPAMTrack-v0", name, seeds=range(10))
              for name in POLICIES}
"""

from __future__ import annotations

from collections.abc import Callable, Iterable

import gymnasium
import numpy as np

from wpam_mj.control.controllers import PIControl
from wpam_mj.errors import ParameterError

Policy = Callable[[np.ndarray, dict], np.ndarray]
POLICIES = ("constant", "random", "pi")
CONSTANT_PO = 5e3  # Pa: the constant policy's Po, the regulator minimum (paper §4)


def _command(env: gymnasium.Env, po: float) -> np.ndarray:
    """The action commanding Po = `po` [Pa] on `env`'s SI or normalised action space."""
    scaling = env.unwrapped.scaling
    return np.array([po]) if scaling is None else scaling.action_of([po])


def make_policy(name: str, env: gymnasium.Env, seed: int) -> Policy:
    """A fresh policy `name` of `POLICIES` for one episode of `env` (action="po")."""
    if env.action_space.shape != (1,):
        raise ParameterError("the reference policies command Po only: use action=\"po\"")
    if name == "constant":
        action = _command(env, CONSTANT_PO)
        return lambda obs, info: action
    if name == "random":
        space = env.action_space
        rng = np.random.default_rng(seed)
        return lambda obs, info: rng.uniform(space.low, space.high).astype(space.dtype)
    if name == "pi":
        base = env.unwrapped
        pi = PIControl.for_run(base.physics.params, base.control_timestep)
        return lambda obs, info: _command(env, pi.update(info["x_m"], info["target_m"]))
    raise ParameterError(f"policy = {name!r}; valid policies: {', '.join(POLICIES)}")


def episode_return(env: gymnasium.Env, policy: str | Policy, seed: int) -> float:
    """Sum of rewards of one episode from `reset(seed=seed)`."""
    obs, info = env.reset(seed=seed)
    act = make_policy(policy, env, seed) if isinstance(policy, str) else policy
    total, done = 0.0, False
    while not done:
        obs, reward, terminated, truncated, info = env.step(act(obs, info))
        total += reward
        done = terminated or truncated
    return total


def mean_return(env_id: str, policy: str | Policy, seeds: Iterable[int] = range(10),
                **kwargs) -> float:
    """Mean episode return of `policy` over `seeds` on `gymnasium.make(env_id, **kwargs)`."""
    env = gymnasium.make(env_id, **kwargs)
    try:
        return float(np.mean([episode_return(env, policy, s) for s in seeds]))
    finally:
        env.close()
