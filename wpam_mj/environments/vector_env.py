"""Many W-PAM environments stepped in one call: the ids' `vector_entry_point`.

    envs = gymnasium.make_vec("wpam_mj/WPAMTrack-v0", num_envs=16)   # engine="batch"
    obs, infos = envs.reset(seed=0)          # env i seeded with 0 + i, as SyncVectorEnv
    obs, rewards, terminated, truncated, infos = envs.step(envs.action_space.sample())

Same results, bit for bit, as `gymnasium.vector.SyncVectorEnv` over N `WPAMEnv`
(next-step autoreset, the registered `max_episode_steps`, infos batched the same way;
tests/test_vector_env.py). Two engines step the physics:

  "batch"  all N MuJoCo states in one `mujoco.batch` call on `nthread` threads, the
           muscle being the compiled plugin (docs/plugin.md). The step path is array
           code only: the commands come from tables each environment's task fills at
           its reset (Pi feedforward, target, drive) and, under action="residual", a
           PI on arrays (`PIArrays`, `PoFeedback`'s arithmetic in the same order); the
           observations, rewards, truncations and infos are computed on (N,) arrays
           from the batch's tendon lengths and plugin states. Resets (explicit or
           automatic) run each environment's own `WPAMEnv.reset` (its task draws
           targets and loads with its seeded RandomState, as one environment does),
           then copy that state into the batch: so a reset, and everything after it,
           is the serial environment's.
  "serial" each environment's `WPAMEnv.step` in turn (the reference, and the engine
           where the compiled plugin is unavailable).
"auto" takes "batch" when the plugin is available and every episode's plugin state has
one size (a randomized dead time may not: `varying_state_size`). Both engines check the
actions once, as one `WPAMEnv` does (`dm_env_task.check_actions`). During a batched
episode the environments' own MuJoCo data is not advanced: `envs.envs[i]` keeps its reset
state.
"""

from __future__ import annotations

import os
from collections.abc import Sequence

import gymnasium
import mujoco
import numpy as np
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space
from mujoco import batch as mjbatch

from wpam_mj.environments.dm_env_task import REWARD_BOUND, check_actions, check_seed
from wpam_mj.environments.gym_env import WPAMEnv, check_episode_steps
from wpam_mj.physics.kernel_codegen import array_kernel
from wpam_mj.errors import ParameterError
from wpam_mj.simulation import plugin
from wpam_mj.simulation.loop_contract import RunConstants, state_failure

ENGINES = ("auto", "batch", "serial")
INFO_KEYS = ("time_s", "x_m", "target_m", "error_m", "pi_cmd_pa", "po_cmd_pa", "is_success")
_STATE = mujoco.mjtState.mjSTATE_INTEGRATION
_WARNING_NUMBER = 1  # mjWarningStat: (lastinfo, number)
DEAD_TIME = "pneumatics.dead_time"  # the one parameter that sizes the plugin state


def default_threads(num_envs: int) -> int:
    """Batch threads by default: one per CPU this process may run on, at most num_envs."""
    cpus = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") \
        else os.cpu_count() or 1
    return max(1, min(num_envs, cpus))


VECTOR_SETTINGS = ("engine", "nthread", "autoreset_mode")  # WPAMVectorEnv's own keywords


def make_vec(env_id: str, num_envs: int = 1, *, vector_kwargs: dict | None = None,
             **kwargs) -> VectorEnv:
    """`gymnasium.make_vec(env_id, num_envs, **kwargs)` that also takes the vector env's
    settings (`VECTOR_SETTINGS`) in Gymnasium's spelling, `vector_kwargs={...}`, which
    gymnasium.make_vec itself refuses for every environment with its own vector entry
    point (Gymnasium >= 1.0: such settings go in as keywords)."""
    vector_kwargs = dict(vector_kwargs or {})
    unknown = sorted(set(vector_kwargs) - set(VECTOR_SETTINGS), key=str)
    if unknown:
        raise ParameterError(f"vector_kwargs {', '.join(map(repr, unknown))} unknown; the "
                             f"vector env's settings: {', '.join(VECTOR_SETTINGS)}")
    twice = sorted(set(vector_kwargs) & set(kwargs))
    if twice:
        raise ParameterError(f"{', '.join(twice)} given twice, in vector_kwargs and as a "
                             "keyword: give it once")
    return gymnasium.make_vec(env_id, num_envs, **kwargs, **vector_kwargs)


def varying_state_size(env: WPAMEnv) -> str:
    """Why the episodes of a new `env` may not share one plugin state size, or "". The
    regulators' dead-time queues hold `RunConstants.delay_steps` = round(dead_time / dt)
    commands each, so a randomized dead time whose range rounds to several step counts
    changes the state's size from episode to episode; one `mujoco.batch` holds states of
    one size only."""
    ranges = env.task.randomize
    if ranges is None or DEAD_TIME not in ranges.ranges:
        return ""
    physics = env.physics  # before any reset: the base parameters
    dt = physics.timestep()
    lo, hi = ranges.ranges[DEAD_TIME]
    steps = [RunConstants.make(physics.params.with_values({DEAD_TIME: v}), dt, dt).delay_steps
             for v in (lo, hi)]
    if steps[0] == steps[1]:
        return ""
    return (f"randomize draws {DEAD_TIME} from [{lo:g}, {hi:g}] s, dead-time queues of "
            f"{steps[0]} to {steps[1]} steps of {dt:g} s")


class PIArrays:
    """The paper's PI on Po (`wpam_mj.control.controllers.PoFeedback.evaluate` and
    `commit`: the kernel's `po_feedback`, in its array form) for N environments at once."""

    def __init__(self, n: int) -> None:
        self.kp, self.ki, self.kd, self.tf, self.dt, self.pa_per_unit, self.lo, self.hi = (
            np.zeros(n) for _ in range(8))
        self.integral, self.derivative, self.e_prev = np.zeros(n), np.zeros(n), np.zeros(n)
        self.has_prev = np.zeros(n, dtype=bool)

    def load(self, i: int, pi) -> None:
        """Environment i takes the constants and state of the PoFeedback `pi`."""
        for name in ("kp", "ki", "kd", "tf", "dt", "pa_per_unit", "lo", "hi", "integral",
                     "derivative"):
            getattr(self, name)[i] = getattr(pi, name)
        self.has_prev[i] = pi.e_prev is not None
        self.e_prev[i] = 0.0 if pi.e_prev is None else pi.e_prev

    def update(self, x: np.ndarray, x_ref: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """Po commands [Pa] of environments `rows` at contractions x and targets x_ref [m]
        (arrays over `rows`), advancing their state."""
        u, self.integral[rows], self.derivative[rows], self.e_prev[rows] = \
            array_kernel().po_feedback(
                x, x_ref, 0.0, self.integral[rows], self.derivative[rows], self.e_prev[rows],
                self.has_prev[rows], self.kp[rows], self.ki[rows], self.kd[rows],
                self.tf[rows], self.pa_per_unit[rows], self.lo[rows], self.hi[rows],
                self.dt[rows])
        self.has_prev[rows] = True
        return u


class WPAMVectorEnv(VectorEnv):
    """`num_envs` `WPAMEnv(**kwargs)` stepped by `engine` ("auto", "batch" or "serial";
    the module docstring) on `nthread` batch threads (default: `default_threads`). Each
    environment ends its episodes at its time_limit, which `max_episode_steps`
    (gymnasium.make_vec passes the registered one) may not cut short."""

    metadata = {"autoreset_mode": AutoresetMode.NEXT_STEP, "render_modes": []}

    def __init__(self, num_envs: int = 1, *, engine: str = "auto", nthread: int | None = None,
                 autoreset_mode: AutoresetMode | str = AutoresetMode.NEXT_STEP,
                 max_episode_steps: int | None = None, backend: str = "mujoco",
                 device: str = "cpu", **kwargs) -> None:
        if backend != "mujoco":  # MuJoCo Warp (the gpu extra): wpam_mj.environments.warp_vector_env
            from wpam_mj.environments import warp_vector_env  # noqa: PLC0415 (optional)
            warp_vector_env.check_backend(backend)
        if isinstance(num_envs, bool) or not isinstance(num_envs, (int, np.integer)) \
                or num_envs < 1:
            raise ParameterError(f"num_envs = {num_envs!r} must be an integer >= 1")
        if engine not in ENGINES:
            raise ParameterError(f"engine = {engine!r}; valid engines: {', '.join(ENGINES)}")
        if nthread is not None and (isinstance(nthread, bool) or not isinstance(
                nthread, (int, np.integer)) or nthread < 1):
            raise ParameterError(f"nthread = {nthread!r} must be an integer >= 1")
        modes = (AutoresetMode.NEXT_STEP, AutoresetMode.SAME_STEP)
        if autoreset_mode not in modes + tuple(m.value for m in modes):
            raise ParameterError(f"autoreset_mode = {autoreset_mode!r}; valid: "
                                 + ", ".join(m.value for m in modes))
        self.autoreset_mode = AutoresetMode(autoreset_mode)
        self.metadata = {**self.metadata, "autoreset_mode": self.autoreset_mode}
        if engine == "batch" and not plugin.available():
            raise ParameterError(f"engine = 'batch' needs the compiled plugin, which is "
                                 f"unavailable ({plugin.unavailable_reason()}); use "
                                 "engine='serial'")
        self.envs = [WPAMEnv(**kwargs) for _ in range(num_envs)]
        self.num_envs = int(num_envs)
        self.single_action_space = self.envs[0].action_space
        self.single_observation_space = self.envs[0].observation_space
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        check_episode_steps(self.envs[0].episode_steps, max_episode_steps)
        self._autoreset = np.zeros(self.num_envs, dtype=bool)
        self._started = False
        varying = varying_state_size(self.envs[0])
        if engine == "batch" and varying:
            raise ParameterError(f"engine = 'batch' needs one plugin state size for every "
                                 f"episode, but {varying}; use engine='serial' or 'auto'")
        self.engine = "batch" if engine == "batch" or (
            engine == "auto" and plugin.available() and not varying) else "serial"
        self._batch = _BatchedEpisodes(self.envs, nthread or default_threads(num_envs)) \
            if self.engine == "batch" and backend == "mujoco" else None
        if backend == "warp":
            self.engine = "warp"
            self._batch = warp_vector_env.WarpEpisodes(self.envs, device)

    def reset(self, *, seed: int | Sequence[int | None] | None = None,
              options: dict | None = None) -> tuple[np.ndarray, dict]:
        seeds = self._seeds(seed)
        obs, infos = [], {}
        for i, (env, s) in enumerate(zip(self.envs, seeds)):
            o, info = env.reset(seed=s, options=options)
            obs.append(o)
            infos = self._add_info(infos, info, i)
        obs = np.stack(obs)
        if self._batch is not None:
            self._batch.restart(np.arange(self.num_envs))
            self._batch.obs[:] = obs
        self._autoreset[:] = False
        self._started = True
        return obs, infos

    def _seeds(self, seed) -> list[int | None]:
        """Each environment's seed: None, seed + i for an integer seed (as SyncVectorEnv),
        or one each (None or an integer in `dm_env_task.SEED_RANGE`)."""
        if seed is None:
            return [None] * self.num_envs
        if isinstance(seed, (int, np.integer)) and not isinstance(seed, (bool, np.bool_)):
            check_seed(seed)
            check_seed(int(seed) + self.num_envs - 1)  # the last environment's
            return [int(seed) + i for i in range(self.num_envs)]
        if not isinstance(seed, (Sequence, np.ndarray)) or isinstance(seed, str):
            raise ParameterError(f"seed = {seed!r} must be None, an integer, or a sequence "
                                 f"of {self.num_envs} (None or integers), one per environment")
        if len(seed) != self.num_envs:
            raise ParameterError(f"{len(seed)} seeds for {self.num_envs} environments: give "
                                 "one per environment")
        return [check_seed(s) for s in seed]

    def step(self, actions) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict]:
        if not self._started:
            raise RuntimeError("cannot step: no episode has started; call reset() first")
        env = self.envs[0]
        actions = check_actions(actions, env.action_space.shape[0], env.action_unit,
                                self.num_envs)
        if self._batch is None:
            obs, rewards, terminated, truncated, infos = self._step_serial(actions)
        else:
            obs, rewards, terminated, truncated, infos = self._batch.step(actions,
                                                                          self._autoreset)
        ended = terminated | truncated
        if self.autoreset_mode == AutoresetMode.SAME_STEP and ended.any():
            obs, infos = self._reset_ended(np.flatnonzero(ended), obs, infos)
            ended[:] = False
        self._autoreset = ended
        return obs, rewards, terminated, truncated, infos

    def _reset_ended(self, ids: np.ndarray, obs: np.ndarray, infos: dict):
        """Same-step autoreset (as SyncVectorEnv's): the episodes `ids` ended at this step
        start again now; their last observation and info go to infos["final_obs"] and
        infos["final_info"]."""
        final: dict = {}
        for i in ids:
            info_i = {key: infos[key][i] for key in infos
                      if not key.startswith("_") and infos[f"_{key}"][i]}
            final = self._add_info(final, {"final_obs": obs[i].copy(), "final_info": info_i},
                                   int(i))
        obs = obs.copy()
        for i in ids:
            obs[i], reset_info = self.envs[i].reset()
            for key in [k for k in infos if not k.startswith("_")]:
                if key not in reset_info:
                    infos[f"_{key}"] = infos[f"_{key}"].copy()
                    infos[f"_{key}"][i] = False
            for key, value in reset_info.items():
                infos[key][i] = value
        if self._batch is not None:
            self._batch.restart(ids)
            self._batch.obs[ids] = obs[ids]
        return obs, {**infos, **final}

    def _step_serial(self, actions: np.ndarray):
        n = self.num_envs
        obs = [None] * n
        rewards = np.zeros(n)
        terminated, truncated = np.zeros(n, dtype=bool), np.zeros(n, dtype=bool)
        infos_each: list[dict] = [{}] * n
        for i in range(n):
            if self._autoreset[i]:  # next-step autoreset
                obs[i], infos_each[i] = self.envs[i].reset()
            else:
                obs[i], rewards[i], terminated[i], truncated[i], infos_each[i] = \
                    self.envs[i].step_checked(actions[i])
        infos: dict = {}
        for i, info in enumerate(infos_each):
            infos = self._add_info(infos, info, i)
        self._autoreset = terminated | truncated
        return np.stack(obs), rewards, terminated, truncated, infos

    def close_extras(self, **kwargs) -> None:
        for env in self.envs:
            env.close()


class _BatchedEpisodes:
    """The N environments' episodes on one `mujoco.batch`: per-environment tables made at
    reset, array code on the step path (see the module docstring)."""

    def __init__(self, envs: list[WPAMEnv], nthread: int) -> None:
        self.envs = envs
        n = len(envs)
        env = envs[0]
        self.rig = env.physics.rig
        self.rows = np.arange(n)
        self.action = env.task.action
        self.scaling = env.scaling
        self.n_sub = env.frame_skip
        self.steps = env.step_limit
        self.reward = env.task.rewards
        # episode time at the start of each control step: MuJoCo adds dt per physics step
        t = np.cumsum(np.full(self.steps * self.n_sub, env.physics.timestep()))
        self.times = np.concatenate([[0.0], t[self.n_sub - 1::self.n_sub]])
        lo, hi = env.task.action_bounds
        self.a_lo, self.a_hi = lo, hi
        self.po_lo, self.po_hi = env.task.po_range
        self.k = np.zeros(n, dtype=np.int64)  # control steps into the episode
        self.targets = np.zeros((n, self.steps + 1))
        self.pi_ff = np.zeros((n, self.steps))
        self.po_ff = np.zeros((n, self.steps))
        self.length0, self.atmosphere, self.load = np.zeros(n), np.zeros(n), np.zeros(n)
        self.x = np.zeros(n)  # contraction [m] at the start of the next step
        self.obs = np.zeros((n, *env.observation_space.shape), env.observation_space.dtype)
        self.pid = PIArrays(n) if self.action == "residual" else None
        self._open(env.physics.model, n, nthread)
        adr = max(self.rig.state, 0)
        self.p_i, self.p_o = adr + plugin.FIELD["p_i"], adr + plugin.FIELD["p_o"]
        self.status = adr + plugin.FIELD["status"]

    def _open(self, model: mujoco.MjModel, n: int, nthread: int) -> None:
        """The n simulations, on `mujoco.batch` (MuJoCo Warp: `warp_vector_env`)."""
        self.sim = mjbatch.Batch(model, n, nthread=nthread)
        self.ten_length = self.sim.bind("ten_length")
        self.ten_velocity = self.sim.bind("ten_velocity")
        self.plugin_state = self.sim.bind("plugin_state")
        self.ctrl = self.sim.bind("ctrl")

    def _load_states(self, ids: np.ndarray) -> None:
        """Simulations `ids` take their environments' state and model (just reset)."""
        for i in ids:
            physics = self.envs[i].physics
            mujoco.mj_getState(physics.model, physics.data, self.sim.state[i], _STATE)
            self.sim.warning[i] = 0  # warnings are no part of the state: as a reset data
        # set again: a reset edits the load's mass
        self.sim.set_models([env.physics.model for env in self.envs])

    def restart(self, ids: np.ndarray) -> None:
        """Environments `ids` have just been reset: their state, model and tables in."""
        for i in ids:
            env = self.envs[i]
            physics, task = env.physics, env.task
            self.k[i] = 0
            self.length0[i] = physics.rig.length0
            self.atmosphere[i] = physics.rig.atmosphere
            self.load[i] = physics.load()
            self.x[i] = physics.contraction()
            self.targets[i] = task.targets_at(self.times)
            if self.action != "both":
                self.pi_ff[i], self.po_ff[i] = task.feedforward_at(self.times[:-1],
                                                                   self.load[i])
            if self.pid is not None:
                self.pid.load(i, task.pi_controller)
        self._load_states(ids)

    def step(self, a: np.ndarray, autoreset: np.ndarray):
        """One step of every environment with the checked actions `a` ((n, size) float64,
        `check_actions`), those in `autoreset` resetting instead."""
        n = len(self.envs)
        command = a * self.a_hi if self.scaling is not None else a
        command = np.minimum(np.maximum(command, self.a_lo), self.a_hi)
        resetting = np.flatnonzero(autoreset) if autoreset.any() else ()
        reset_info = [self.envs[i].reset() for i in resetting]
        # the stepped environments: all (a slice: views, no copies) or those not resetting
        rows, at = slice(None), self.rows
        if len(resetting):
            self.restart(resetting)
            rows = at = np.flatnonzero(~autoreset)
        k = self.k[rows]
        if self.action == "both":
            pi_cmd, po = command[rows, 0], command[rows, 1]
        else:
            pi_cmd, po = self.pi_ff[at, k], command[rows, 0]
            if self.pid is not None:
                po = self.pid.update(self.x[rows], self.targets[at, k], rows) + po
            po = np.minimum(np.maximum(po + self.po_ff[at, k], self.po_lo), self.po_hi)
        channels = self.rig.channels
        self.ctrl[rows, channels[0]] = pi_cmd
        self.ctrl[rows, channels[1]] = po
        diverged = self._advance(rows, at)
        k += 1
        self.k[rows] = k
        tendon = self.rig.tendon
        x = self.length0[rows] - self.ten_length[rows, tendon]
        state = self.plugin_state[rows]
        target = self.targets[at, k]
        error = x - target
        # the SI observation (OBSERVATIONS order) and the tracking error
        full = np.empty((len(x), 7))
        full[:, 0], full[:, 4], full[:, 5], full[:, 6] = x, target, self.load[rows], error
        np.negative(self.ten_velocity[rows, tendon], out=full[:, 1])
        atmosphere = self.atmosphere[rows]
        np.subtract(state[:, self.p_i], atmosphere, out=full[:, 2])
        np.subtract(state[:, self.p_o], atmosphere, out=full[:, 3])
        obs = full[:, :6] if self.scaling is None else self.scaling.normalised(full)
        self.x[rows] = x
        rewards, terminated = np.zeros(n), np.zeros(n, dtype=bool)
        truncated = np.zeros(n, dtype=bool)
        rewards[rows] = self.reward(error)
        truncated[rows] = k >= self.steps
        info = {"time_s": self.sim.time[rows], "x_m": x, "target_m": target,
                "error_m": error, "pi_cmd_pa": pi_cmd, "po_cmd_pa": po,
                "is_success": np.abs(error) <= REWARD_BOUND}
        every = np.ones(n, dtype=bool)
        every.flags.writeable = False  # one mask for every key: each environment has each
        infos = {}
        for key in INFO_KEYS:
            values = info[key]  # each a new array but time_s, a view of the state
            if len(resetting) or key == "time_s":
                values = np.empty(n, dtype=values.dtype)
                values[rows] = info[key]
            infos[key], infos[f"_{key}"] = values, every
        if diverged:  # rare: terminated, reward 0, the last valid observation kept
            j = np.array(list(diverged))
            ended = at[j]
            obs[j] = self.obs[ended]
            rewards[ended], terminated[ended], truncated[ended] = 0.0, True, False
            infos["diverged"] = np.full(n, None, dtype=object)
            infos["_diverged"] = np.zeros(n, dtype=bool)
            infos["diverged"][ended] = list(diverged.values())
            infos["_diverged"][ended] = True
        self.obs[rows] = obs
        for i, (o, info_i) in zip(resetting, reset_info):
            self.obs[i] = o
            for key in INFO_KEYS:
                infos[key][i] = info_i[key]
        return self.obs.copy(), rewards, terminated, truncated, infos

    def _advance(self, rows, at: np.ndarray) -> dict[int, str]:
        """One control step of the simulations `rows` (a slice or the indices `at`);
        {position in rows: why} for those that diverged (the plugin's status, a MuJoCo
        warning or error; `restart` zeroes a simulation's warning counters)."""
        diverged: dict[int, str] = {}
        try:
            self.sim.step(None if isinstance(rows, slice) else rows, nstep=self.n_sub,
                          stage=mujoco.mjtStage.mjSTAGE_VEL)
        except mjbatch.SimulationError as err:
            for i in err.ids:
                diverged[int(np.flatnonzero(at == i)[0])] = self.sim.error(int(i))
        failed = self.plugin_state[rows, self.status] != 0
        warnings = self.sim.warning[rows, :, _WARNING_NUMBER]
        if failed.any() or warnings.any():
            for j in np.flatnonzero(failed | warnings.any(axis=1)):
                state = self.plugin_state[at[j], self.rig.state:]
                diverged.setdefault(int(j), state_failure(state) if failed[j]
                                    else "MuJoCo warned of an invalid physics state")
        return dict(sorted(diverged.items()))
