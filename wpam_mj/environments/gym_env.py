"""The W-PAM as a Gymnasium environment: `gymnasium.make("wpam_mj/WPAM-v0")`.

    import gymnasium, wpam_mj                    # importing wpam_mj registers the ids
    env = gymnasium.make("wpam_mj/WPAM-v0")      # action: Po command [Pa], 10 ms step
    obs, info = env.reset(seed=0)
    obs, reward, terminated, truncated, info = env.step(env.action_space.sample())

A thin layer over the dm_control environment of `wpam_mj.environments.dm_env_task`: `WPAMEnv` owns a
`make_env` environment (its `MusclePhysics` and `TrackingTask`) and translates the calls,
so observations, actions, reward, targets, loads and the physics are the same code, and
for the same seed and actions both give the same trajectory (tests/test_gym_env.py).
The registered ids and what each sets are in `wpam_mj.environments.registry`.

SI spaces (the default, normalize=False):
Observation: Box float64 of shape (6,), SI units, in
`wpam_mj.environments.dm_env_task.OBSERVATIONS` order:
    x_m           contraction x [m]; bounds [-5 mm, x_max + 5 mm] (the slide's stops at
                  0 and x_max are stiff soft constraints: a few um of overshoot)
    velocity_m_s  dx/dt [m/s]; unbounded
    pi_pa, po_pa  chamber gauge pressures [Pa]; bounded below by -atmosphere (absolute
                  pressure > 0, else the run has diverged), unbounded above
    target_m      target x_r [m]; bounds [0, x_max]
    load_n        hanging load [N]; bounds: the load range (or the fixed load)
Action: Box float64 [Pa], clipped to its bounds:
    action="po"   (1,): Po command in [p_min, po_cap]; Pi is the equilibrium feedforward
    action="both" (2,): Pi command in [p_min, p_max], Po command in [p_min, po_cap]
    action="residual" (1,): Po correction in [-po_cap, po_cap] to the paper's PI, which
                  runs in the environment at the control step (`dm_env_task`)
Normalised spaces (normalize=True; the learning variants): float32 everywhere.
    Action: Box [-1, 1], each command as a fraction of its upper bound (Po: a * po_cap),
    clipped to its SI bounds, so a <= p_min / bound (Po: 0.0625) is the regulator minimum.
    Why not [-1, 1] onto [p_min, bound]: a Gaussian policy starts at a = 0, which that
    map makes a mid-range Po (the muscle barely contracts, every reward ~0), and the
    usual best command, the regulator minimum the Pi feedforward assumes, would sit on
    the space's edge, where a clipped Gaussian stops exploring.
    Observation: Box [-1, 1] of shape (7,), each SI value scaled at this edge and clipped:
    x and x_r over [0, x_max], dx/dt over +-`V_SCALE`, Pi over [0, p_max], Po over
    [0, po_cap], the load over its range (0 when fixed), and the tracking error x - x_r
    over +-`ERROR_SCALE` (a policy needs it finer than x and x_r give it).
Reward: `reward="tolerance"` (default): 1 within +-0.5 mm of the target, Gaussian fall-off
to 0.1 at 2 mm outside; `reward="tracking"`: 1 - |x - x_r| / 5 mm, floored at 0 (see
`wpam_mj.environments.dm_env_task`). Episode: `time_limit` [s], then truncated=True. Each
env step is `frame_skip` physics steps of `dt` [s]. The registered ids' TimeLimit cuts at 1000
steps: with a longer time_limit pass max_episode_steps to gymnasium.make too. If the
state diverges (non-physical pressures, MuJoCo's instability warnings) the episode ends
with terminated=True, reward 0, the last valid observation and the reason in
info["diverged"]; stepping again before `reset` raises RuntimeError.
info (SI): time_s, x_m, target_m, error_m (x - x_r), pi_cmd_pa and po_cmd_pa (the
regulator commands applied over the last step: Pi is the feedforward under action="po"),
is_success (|x - x_r| within the 0.5 mm tolerance band at this step).
Seeding: `reset(seed=s)` reseeds the task's RandomState with s, as `make_env(seed=s)`;
targets, loads and sine frequencies are drawn from it. `reset(options={"target": m,
"load": N})` fixes either for that episode only (the draws still happen).
Rendering: render_mode="rgb_array" draws the current state with `wpam_mj.visualisation.render`
(headless: EGL, chosen when the first frame is drawn).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from dm_control.rl import control
from gymnasium import Env, spaces

from wpam_mj.environments.dm_env_task import (LOAD_RANGE, REWARD_BOUND, SINE_FREQ_RANGE,
                                              TARGET_RANGE, TrackingTask, build,
                                              check_actions, check_seed)
from wpam_mj.environments.muscle_physics import RigPhysics
from wpam_mj.physics.geometry import BraidGeometry
from wpam_mj.simulation.context import check_dt
from wpam_mj.physics.params import Params, preset
from wpam_mj.errors import ParameterError
from wpam_mj.units import MM
from wpam_mj.fitting.randomize import ParameterRanges

ENV_ID = "wpam_mj/WPAM-v0"
FRAME_SKIP_RANGE = (1, 100_000)  # physics steps per env step
X_SLACK = 5 * MM  # m: observation bound beyond the stops (soft constraints)
V_SCALE = 0.5  # m/s: normalised velocity +-1 (a 50 mm stroke in 0.1 s)
ERROR_SCALE = 10 * MM  # m: normalised tracking error +-1
RESET_OPTIONS = ("target", "load")


def resolve_params(params: Params | str | None) -> Params:
    """`params` as given, a preset by name ("wpam", "rlam", "mckibben"), or the default."""
    if params is None:
        return preset()
    if isinstance(params, str):
        return preset(params)
    if not isinstance(params, Params):
        raise ParameterError(f"params = {params!r} must be a wpam_mj.Params or a preset name")
    return params


def check_reset_options(options) -> dict[str, float]:
    """`reset(options=...)`: None or a dict of `RESET_OPTIONS` with real numbers."""
    if options is None:
        return {}
    if not isinstance(options, dict):
        raise ParameterError(f"options = {options!r} must be a dict with keys among "
                             f"{', '.join(RESET_OPTIONS)}")
    unknown = sorted(set(options) - set(RESET_OPTIONS), key=str)
    if unknown:
        raise ParameterError(f"reset option(s) {', '.join(map(repr, unknown))} unknown; "
                             f"valid: {', '.join(RESET_OPTIONS)}")
    for key, value in options.items():
        if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float,
                                                                         np.number)):
            raise ParameterError(f"reset option {key} = {value!r} must be a number "
                                 f"({'m' if key == 'target' else 'N'})")
    return {k: float(v) for k, v in options.items()}


def check_episode_steps(steps: int, max_episode_steps: int | None) -> None:
    """An episode of `steps` steps must not be cut short by `max_episode_steps`. (Only
    the vector env can check: gymnasium.make hides the TimeLimit from the env it wraps.)"""
    if max_episode_steps is not None and max_episode_steps < steps:
        raise ParameterError(
            f"time_limit is {steps} steps but gymnasium's TimeLimit ends episodes at "
            f"max_episode_steps = {max_episode_steps}: pass max_episode_steps={steps} to "
            "gymnasium.make too")


class Scaling:
    """SI <-> normalised values at the environment's edge (normalize=True)."""

    def __init__(self, params: Params, action_low: np.ndarray, action_high: np.ndarray,
                 loads: tuple[float, float]) -> None:
        x_max = BraidGeometry.from_params(params.braid).max_contraction
        self._a_lo, self._a_hi = action_low, action_high
        # observation (SI) = centre + half * normalised, per OBSERVATIONS, then the error
        lo = np.array([0.0, -V_SCALE, 0.0, 0.0, 0.0, loads[0], -ERROR_SCALE])
        hi = np.array([x_max, V_SCALE, params.pneumatics.p_max, params.controller.po_cap,
                       x_max, loads[1], ERROR_SCALE])
        self._centre, self._half = (lo + hi) / 2, np.maximum((hi - lo) / 2, 1e-12)

    def action(self, a: np.ndarray) -> np.ndarray:
        """Normalised action in [-1, 1] (checked: `check_actions`) -> SI command [Pa]: a
        times the upper bound, clipped to the bounds (so a <= p_min / upper bound is the
        regulator minimum)."""
        return np.minimum(np.maximum(a * self._a_hi, self._a_lo), self._a_hi)

    def action_of(self, command) -> np.ndarray:
        """SI command [Pa] -> normalised action (float32), e.g. to run a classic
        controller on a normalised environment."""
        c = np.asarray(command, dtype=np.float64).reshape(self._a_lo.shape)
        return (c / self._a_hi).astype(np.float32)

    def normalised(self, full: np.ndarray) -> np.ndarray:
        """SI observations with the tracking error x - x_r appended, (7,) or (N, 7) ->
        normalised float32 in [-1, 1]."""
        return np.clip((full - self._centre) / self._half, -1.0, 1.0).astype(np.float32)


class WPAMEnv(Env):
    """Hold the hung W-PAM's load at a target contraction; see the module docstring.

    Args:
      params: muscle parameters, or a preset name (default: the calibrated ``wpam``).
      action: "po" (Po command), "both" (Pi and Po commands) or "residual" (a Po
        correction to the paper's PI).
      reference: "step" (constant target), "sine" (25 mm about 25 mm at f) or
        "staircase" (a new random level every `dm_env_task.STAIR_HOLD` s, up or down).
      reward: "tolerance" or "tracking" (module docstring).
      normalize: float32 spaces in [-1, 1] (module docstring) instead of SI.
      randomize: domain randomisation, as `wpam_mj.environments.dm_env_task.make_env` (a
        ranges file from `wpam fit --randomize-out`, `ParameterRanges`, or a relative
        spread such as 0.1).
      frame_skip: physics steps per env step (the control step is frame_skip * dt).
      dt: physics step [s].
      time_limit: episode length [s].
      target, load, sine_freq: fix the target [m], load [N], sine frequency [Hz].
      target_range, load_range, sine_freq_range: (low, high) for random draws.
      render_mode: None or "rgb_array".
      render_size: (width, height) [px] of rendered frames.
      controller: the control mode whose feedforward shapes the commands around the
        agent's Po, as `wpam_mj.environments.dm_env_task.make_env`.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 30}

    def __init__(self, params: Params | str | None = None, *, action: str = "po",
                 reference: str = "step", reward: str = "tolerance", normalize: bool = False,
                 randomize: str | Path | float | ParameterRanges | None = None,
                 frame_skip: int = 10, dt: float = 1e-3,
                 time_limit: float = 10.0, target: float | None = None,
                 load: float | None = None, sine_freq: float | None = None,
                 target_range: tuple[float, float] = TARGET_RANGE,
                 load_range: tuple[float, float] = LOAD_RANGE,
                 sine_freq_range: tuple[float, float] = SINE_FREQ_RANGE,
                 render_mode: str | None = None,
                 render_size: tuple[int, int] = (640, 480), controller: str = "pi") -> None:
        params = resolve_params(params)
        dt = check_dt(dt)
        if isinstance(frame_skip, bool) or not isinstance(frame_skip, (int, np.integer)) \
                or not FRAME_SKIP_RANGE[0] <= frame_skip <= FRAME_SKIP_RANGE[1]:
            raise ParameterError(f"frame_skip = {frame_skip!r} must be an integer in "
                                 f"[{FRAME_SKIP_RANGE[0]}, {FRAME_SKIP_RANGE[1]}] "
                                 "physics steps")
        if render_mode not in (None, *self.metadata["render_modes"]):
            raise ParameterError(f"render_mode = {render_mode!r}; valid: None, "
                                 + ", ".join(self.metadata["render_modes"]))
        if not isinstance(normalize, (bool, np.bool_)):
            raise ParameterError(f"normalize = {normalize!r} must be True or False")
        self._physics, self._task, time_limit, self.frame_skip = build(
            RigPhysics, params, action=action, time_limit=time_limit,
            control_timestep=int(frame_skip) * dt, dt=dt, seed=None, target=target, load=load,
            target_range=target_range, load_range=load_range, flat_observation=True,
            reference=reference, sine_freq=sine_freq, sine_freq_range=sine_freq_range,
            randomize=randomize, reward=reward, controller=controller)
        self._params = params
        self.episode_steps = math.ceil(time_limit / self.control_timestep - 1e-9)
        # episodes end after this many steps (dm_control's step limit, rounded up)
        self.step_limit = math.ceil(time_limit / self.control_timestep)
        self._steps = 0
        self.render_mode = render_mode
        self._render_size = render_size
        self._frames = None  # wpam_mj.visualisation.scene.StateFrames, made on the first render
        self.metadata = {**self.metadata, "render_fps": 1.0 / self.control_timestep}

        spec = self._task.action_spec(self._physics)
        lo, hi = (load, load) if load is not None else load_range
        loads = (lo * (1 - 1e-9), hi * (1 + 1e-9))  # observed as mass * g: allow its rounding
        self.scaling = Scaling(params, spec.minimum, spec.maximum, loads) if normalize \
            else None
        self.action_space, self.observation_space = self._spaces(params, spec, loads)
        self._obs: np.ndarray | None = None
        self._info: dict = {}
        # what the action's numbers are, as refusals name them
        self.action_unit = self._task.action_unit if self.scaling is None else (
            f"in [-1, 1] ({spec.name} as fractions of its upper bounds)")
        self._ended: str | None = "no episode has started"

    def _spaces(self, params: Params, spec, loads) -> tuple[spaces.Box, spaces.Box]:
        if self.scaling is not None:
            return (spaces.Box(-1.0, 1.0, spec.shape, dtype=np.float32),
                    spaces.Box(-1.0, 1.0, (7,), dtype=np.float32))
        x_max = BraidGeometry.from_params(params.braid).max_contraction
        atm, inf = params.pneumatics.atmosphere, np.inf
        return (spaces.Box(spec.minimum, spec.maximum, dtype=np.float64),
                spaces.Box(np.array([-X_SLACK, -inf, -atm, -atm, 0.0, loads[0]]),
                           np.array([x_max + X_SLACK, inf, inf, inf, x_max, loads[1]]),
                           dtype=np.float64))

    @property
    def physics(self) -> RigPhysics:
        """The MuJoCo physics and pneumatic state (the dm_control env's, without it)."""
        return self._physics

    @property
    def control_timestep(self) -> float:
        """Time between actions [s] (frame_skip * dt)."""
        return self._physics.timestep() * self.frame_skip

    @property
    def task(self) -> TrackingTask:
        """The tracking task: targets, loads, reward, observations."""
        return self._task

    def reset(self, *, seed: int | None = None,
              options: dict | None = None) -> tuple[np.ndarray, dict]:
        seed = check_seed(seed)
        fixed = check_reset_options(options)
        super().reset(seed=seed)
        if seed is not None:
            self.task.random.seed(seed)
        self.task.fix_next_episode(**fixed)
        # as dm_control's Environment.reset: the physics at rest, the task's episode, then
        # the derived quantities of that state
        self._steps = 0
        self._physics.reset()
        self.task.initialize_episode(self._physics)
        self._physics.after_reset()
        self._ended = None
        if self._frames is not None:
            self._frames.set_load(self.physics.load())
        return self._observe()

    def check_action(self, action) -> np.ndarray:
        """`action` as float64 of the action's shape, or a one-line ParameterError
        (`wpam_mj.environments.dm_env_task.check_actions`, the vector env's check too)."""
        return check_actions(action, self.action_space.shape[0], self.action_unit)

    def step(self, action) -> tuple[np.ndarray, float, bool, bool, dict]:
        if self._ended is not None:
            raise RuntimeError(f"cannot step: {self._ended}; call reset() first")
        return self.step_checked(self.check_action(action))

    def step_checked(self, action: np.ndarray):
        """`step` with an action `check_action` has checked (the vector env's serial
        engine checks all its environments' actions at once)."""
        command = action if self.scaling is None else self.scaling.action(action)
        try:  # as dm_control's Environment.step
            self._task.apply_action(command, self._physics)
            self._physics.step(self.frame_skip)
        except control.PhysicsError as err:
            self._ended = f"the episode ended, the state diverged ({err})"
            return self._obs.copy(), 0.0, True, False, {**self._info, "diverged": str(err)}
        obs, info = self._observe()
        self._steps += 1
        truncated = self._steps >= self.step_limit
        if truncated:
            self._ended = "the episode ended at its time limit"
        return obs, self._task.reward(info["error_m"]), False, truncated, info

    def _observe(self) -> tuple[np.ndarray, dict]:
        """The observation and info of the current state, each read once."""
        physics = self._physics
        values = self._task.readings(physics)
        x, target = values[0], values[4]
        error = x - target
        if self.scaling is None:
            obs = np.array(values)
        else:
            values.append(error)
            obs = self.scaling.normalised(np.array(values))
        self._obs = obs
        self._info = {"time_s": physics.time(), "x_m": x, "target_m": target,
                      "error_m": error, "pi_cmd_pa": physics.pi_cmd,
                      "po_cmd_pa": physics.po_cmd,
                      "is_success": -REWARD_BOUND <= error <= REWARD_BOUND}
        return obs.copy(), self._info

    def render(self) -> np.ndarray | None:
        if self.render_mode != "rgb_array":
            return None
        if self._frames is None:
            from wpam_mj.visualisation.scene import StateFrames  # noqa: PLC0415 (needs OpenGL; only here)
            self._frames = StateFrames(self._params, self.physics.load(),
                                       size=self._render_size)
        pi, po = self.physics.pressures()
        return self._frames.frame(self.physics.time(), self.physics.contraction(),
                                  self.task.target_at(self.physics.time()), pi, po)

    def close(self) -> None:
        if self._frames is not None:
            self._frames.close()
            self._frames = None
