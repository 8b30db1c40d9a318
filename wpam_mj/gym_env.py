"""The W-PAM as a Gymnasium environment: `gymnasium.make("wpam_mj/WPAM-v0")`.

    import gymnasium, wpam_mj                    # importing wpam_mj registers the id
    env = gymnasium.make("wpam_mj/WPAM-v0")      # action: Po command [Pa], 10 ms step
    obs, info = env.reset(seed=0)
    obs, reward, terminated, truncated, info = env.step(env.action_space.sample())

A thin layer over the dm_control environment of `wpam_mj.env`: `WPAMEnv` owns a
`make_env` environment (its `MusclePhysics` and `TrackingTask`) and translates the calls,
so observations, actions, reward, targets, loads and the physics are the same code, and
for the same seed and actions both give the same trajectory (tests/test_gym_env.py).

Observation: Box float64 of shape (6,), SI units, in `wpam_mj.env.OBSERVATIONS` order:
    x_m           contraction x [m]; bounds [-5 mm, x_max + 5 mm] (the slide's stops at
                  0 and x_max are stiff soft constraints: a few um of overshoot)
    velocity_m_s  dx/dt [m/s]; unbounded
    pi_pa, po_pa  chamber gauge pressures [Pa]; bounded below by -atmosphere (absolute
                  pressure > 0, else the run has diverged), unbounded above
    target_m      target x_r [m]; bounds [0, x_max]
    load_n        hanging load [N]; bounds: the load range (or the fixed load)
Action: Box float64 [Pa], clipped to its bounds (`gymnasium.wrappers.RescaleAction` maps it
to [-1, 1] for learners that want that):
    action="po"   (1,): Po command in [p_min, po_cap]; Pi is the equilibrium feedforward
    action="both" (2,): Pi command in [p_min, p_max], Po command in [p_min, po_cap]
Reward: 1 within +-0.5 mm of the target, Gaussian fall-off to 0.1 at 2 mm outside.
Episode: `time_limit` [s], then truncated=True. Each env step is `frame_skip` physics steps
of `dt` [s]. If the state diverges (non-physical pressures, MuJoCo's instability
warnings) the episode ends with terminated=True, reward 0, the last valid observation and
the reason in info["diverged"]; stepping again before `reset` raises RuntimeError.
Seeding: `reset(seed=s)` reseeds the task's RandomState with s, as `make_env(seed=s)`;
targets, loads and sine frequencies are drawn from it. info["time_s"]: episode time [s].
Rendering: render_mode="rgb_array" draws the current state with `wpam_mj.render`
(headless: EGL).
"""

from __future__ import annotations

import numpy as np
from dm_control.rl import control
from gymnasium import Env, spaces

from wpam_mj.env import (LOAD_RANGE, SINE_FREQ_RANGE, TARGET_RANGE, MusclePhysics,
                         TrackingTask, make_env)
from wpam_mj.geometry import BraidGeometry
from wpam_mj.model import check_dt
from wpam_mj.params import MM, ParameterError, Params, preset

ENV_ID = "wpam_mj/WPAM-v0"
FRAME_SKIP_RANGE = (1, 100_000)  # physics steps per env step
X_SLACK = 5 * MM  # m: observation bound beyond the stops (soft constraints)


class WPAMEnv(Env):
    """Hold the hung W-PAM's load at a target contraction; see the module docstring.

    Args:
      params: muscle parameters (default: the calibrated ``wpam`` preset).
      action: "po" (Po command) or "both" (Pi and Po commands).
      reference: "step" (constant target) or "sine" (25 mm about 25 mm at f).
      frame_skip: physics steps per env step (the control step is frame_skip * dt).
      dt: physics step [s].
      time_limit: episode length [s].
      target, load, sine_freq: fix the target [m], load [N], sine frequency [Hz].
      target_range, load_range, sine_freq_range: (low, high) for random draws.
      render_mode: None or "rgb_array".
      render_size: (width, height) [px] of rendered frames.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 30}

    def __init__(self, params: Params | None = None, *, action: str = "po",
                 reference: str = "step", frame_skip: int = 10, dt: float = 1e-3,
                 time_limit: float = 10.0, target: float | None = None,
                 load: float | None = None, sine_freq: float | None = None,
                 target_range: tuple[float, float] = TARGET_RANGE,
                 load_range: tuple[float, float] = LOAD_RANGE,
                 sine_freq_range: tuple[float, float] = SINE_FREQ_RANGE,
                 render_mode: str | None = None,
                 render_size: tuple[int, int] = (640, 480)) -> None:
        params = preset() if params is None else params
        dt = check_dt(dt)
        if isinstance(frame_skip, bool) or not isinstance(frame_skip, (int, np.integer)) \
                or not FRAME_SKIP_RANGE[0] <= frame_skip <= FRAME_SKIP_RANGE[1]:
            raise ParameterError(f"frame_skip = {frame_skip!r} must be an integer in "
                                 f"[{FRAME_SKIP_RANGE[0]}, {FRAME_SKIP_RANGE[1]}] "
                                 "physics steps")
        if render_mode not in (None, *self.metadata["render_modes"]):
            raise ParameterError(f"render_mode = {render_mode!r}; valid: None, "
                                 + ", ".join(self.metadata["render_modes"]))
        self._env = make_env(params, action=action, time_limit=time_limit,
                             control_timestep=int(frame_skip) * dt, dt=dt, target=target,
                             load=load, target_range=target_range, load_range=load_range,
                             flat_observation=True, reference=reference,
                             sine_freq=sine_freq, sine_freq_range=sine_freq_range)
        self._params = params
        self.render_mode = render_mode
        self._render_size = render_size
        self._frames = None  # wpam_mj.render.StateFrames, made on the first render
        self.metadata = {**self.metadata, "render_fps": 1.0 / self._env.control_timestep()}

        spec = self._env.action_spec()
        self.action_space = spaces.Box(spec.minimum, spec.maximum, dtype=np.float64)
        x_max = BraidGeometry.from_params(params.braid).max_contraction
        lo, hi = (load, load) if load is not None else load_range
        loads = (lo * (1 - 1e-9), hi * (1 + 1e-9))  # observed as mass * g: allow its rounding
        atm = params.pneumatics.atmosphere
        inf = np.inf
        self.observation_space = spaces.Box(
            np.array([-X_SLACK, -inf, -atm, -atm, 0.0, loads[0]]),
            np.array([x_max + X_SLACK, inf, inf, inf, x_max, loads[1]]), dtype=np.float64)
        self._obs: np.ndarray | None = None
        self._ended: str | None = "no episode has started"

    @property
    def physics(self) -> MusclePhysics:
        """The MuJoCo physics and pneumatic state (shared with the dm_control env)."""
        return self._env.physics

    @property
    def task(self) -> TrackingTask:
        """The tracking task: targets, loads, reward, observations."""
        return self._env.task

    def reset(self, *, seed: int | None = None,
              options: dict | None = None) -> tuple[np.ndarray, dict]:
        super().reset(seed=seed)
        if seed is not None:
            self.task.random.seed(seed)
        timestep = self._env.reset()
        self._obs = self._observation(timestep)
        self._ended = None
        if self._frames is not None:
            self._frames.set_load(self.physics.load())
        return self._obs.copy(), self._info()

    def step(self, action) -> tuple[np.ndarray, float, bool, bool, dict]:
        if self._ended is not None:
            raise RuntimeError(f"cannot step: {self._ended}; call reset() first")
        try:
            timestep = self._env.step(action)
        except control.PhysicsError as err:
            self._ended = f"the episode ended, the state diverged ({err})"
            return self._obs.copy(), 0.0, True, False, {**self._info(), "diverged": str(err)}
        self._obs = self._observation(timestep)
        truncated = timestep.last()
        if truncated:
            self._ended = "the episode ended at its time limit"
        return self._obs.copy(), float(timestep.reward), False, truncated, self._info()

    def render(self) -> np.ndarray | None:
        if self.render_mode != "rgb_array":
            return None
        if self._frames is None:
            from wpam_mj.render import StateFrames  # noqa: PLC0415 (needs OpenGL; only here)
            self._frames = StateFrames(self._params, self.physics.load(),
                                       size=self._render_size)
        pi, po = self.physics.pressures()
        return self._frames.frame(self.physics.time(), self.physics.contraction(),
                                  self.task.target_at(self.physics.time()), pi, po)

    def close(self) -> None:
        if self._frames is not None:
            self._frames.close()
            self._frames = None

    @staticmethod
    def _observation(timestep) -> np.ndarray:
        return np.asarray(timestep.observation[control.FLAT_OBSERVATION_KEY], dtype=np.float64)

    def _info(self) -> dict:
        return {"time_s": self.physics.time()}
