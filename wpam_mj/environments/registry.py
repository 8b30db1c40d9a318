"""The Gymnasium ids `import wpam_mj` registers (with the optional `rl` extra).

Light on purpose: `wpam_mj/__init__.py` imports it, so nothing heavy is imported here;
`gymnasium.make` imports `wpam_mj.environments.gym_env` when an environment is made.

    wpam_mj/WPAM-v0             SI spaces, Po action, one step target from rest,
                                "tolerance" reward (the documented default)
    wpam_mj/WPAMTrack-v0        normalised spaces, Po action, staircase targets, "tracking"
                                reward: the learning task (docs/learning.md)
    wpam_mj/WPAMTrackBoth-v0    as WPAMTrack-v0 with Pi and Po actions
    wpam_mj/WPAMTrackSine-v0    as WPAMTrack-v0 with the paper's sine targets (0.1-1 Hz)
    wpam_mj/WPAMTrackRandomized-v0  as WPAMTrack-v0 with the fitted plant parameters
                                drawn within +-10 % each episode (`randomize=0.1`)
    wpam_mj/WPAMTrackResidual-v0  as WPAMTrack-v0, the action a Po correction to the
                                paper's PI (action="residual"): the task PPO and SAC learn

Every id takes the keyword arguments of `wpam_mj.environments.gym_env.WPAMEnv` (e.g. randomize=FILE
from `wpam fit --randomize-out`), has `max_episode_steps` = 1000 (10 s of 10 ms steps;
pass max_episode_steps with a longer time_limit) and a `vector_entry_point`
(`gymnasium.make_vec`, `wpam_mj.environments.vector_env`).
"""

from __future__ import annotations

EPISODE_STEPS = 1000  # the default 10 s episode at the default 10 ms control step
_TRACK = {"normalize": True, "reference": "staircase", "reward": "tracking"}
VARIANTS: dict[str, dict] = {
    "wpam_mj/WPAM-v0": {},
    "wpam_mj/WPAMTrack-v0": _TRACK,
    "wpam_mj/WPAMTrackBoth-v0": {**_TRACK, "action": "both"},
    "wpam_mj/WPAMTrackSine-v0": {**_TRACK, "reference": "sine"},
    "wpam_mj/WPAMTrackRandomized-v0": {**_TRACK, "randomize": 0.1},
    "wpam_mj/WPAMTrackResidual-v0": {**_TRACK, "action": "residual"},
}


def register_all() -> None:
    """Register every id of `VARIANTS` with Gymnasium."""
    from gymnasium.envs.registration import register  # noqa: PLC0415 (optional extra)

    for env_id, kwargs in VARIANTS.items():
        register(id=env_id, entry_point="wpam_mj.environments.gym_env:WPAMEnv",
                 vector_entry_point="wpam_mj.environments.vector_env:WPAMVectorEnv",
                 max_episode_steps=EPISODE_STEPS, kwargs=dict(kwargs))
