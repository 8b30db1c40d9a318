"""The W-PAM as a control / reinforcement-learning environment (dm_env interface).

    env = make_env(seed=0)                      # action: Po command [Pa]
    timestep = env.reset()
    while not timestep.last():
        timestep = env.step(policy(timestep.observation))

Built on dm_control's `rl.control.Environment` with a `Task` (reward, observations,
random targets and loads) and a `dm_control.mujoco.Physics` subclass, `MusclePhysics`
(`wpam_mj.environments.muscle_physics`),
whose `step` is the project's physics step: the muscle is the rig's `wpam_mj.muscle`
actuator plugin (docs/plugin.md), whose input channels are the two regulator commands, and
`MusclePhysics.step(n)` runs n full `mj_step`s (dm_control's default legacy step would run
`mj_step2` on constraints `mj_step1` already built), so an episode reproduces
`wpam_mj.simulation.simulate.simulate(..., control="open")` driven by the same commands exactly
(tests/test_env.py checks this), and no force code is duplicated.

Observations (each a float64 array of shape (1,), SI units, named with their unit):
    x_m           contraction x [m] (positive = shorter muscle)
    velocity_m_s  contraction velocity dx/dt [m/s]
    pi_pa         inner-chamber gauge pressure Pi [Pa]
    po_pa         outer-chamber gauge pressure Po [Pa]
    target_m      target contraction x_r [m] at the current time
    load_n        hanging load F [N] (constant over an episode)
Actions (`BoundedArray`, float64, [Pa]; out-of-range values are clipped, anything but
finite real numbers of the right count is refused, `check_actions`):
    action="po"   shape (1,): Po command in [p_min, po_cap]; Pi is the feedforward of the
                  `controller` (default "pi": the equilibrium model for (target,
                  load) at the nominal Po, as in the paper's §4 controller; "open": at
                  Po = 0). The agent takes the place of the controller's Po feedback; a
                  controller that adds a Po feedforward to its feedback ("pi_ff") adds it
                  to the agent's Po, and one that needs the target ahead of time ("pi_ff")
                  is fed the episode's whole target path at its start.
    action="both" shape (2,): (Pi command in [p_min, p_max], Po command in [p_min, po_cap]);
                  Po keeps the bag's 0.08 MPa durability cap (paper §4.2).
    action="residual" shape (1,): a Po correction in [-po_cap, po_cap] added to the paper's
                  PI on Po, which runs inside the environment once per control step
                  (`PIControl` at the control step, started bumpless as `simulate` starts
                  it; the same law as the reference policy "pi" of
                  `wpam_mj.environments.policies`); the sum is clipped to [p_min, po_cap].
                  A zero action is that PI (docs/learning.md: why a residual).
Targets (`reference`):
    "step"  x_r constant over the episode, reached from rest at x = 0 (paper §4.1);
    "sine"  x_r(t) = 25 mm - 25 mm cos(2 pi f t) (paper §4.2, `experiments.SineSpec`),
            f drawn from `sine_freq_range` [Hz] (or fixed with `sine_freq=`);
    "staircase"  a new level every `STAIR_HOLD` s, each drawn from `target_range`, so
            targets also fall (what the Po feedback is for, paper §4: the friction holds
            a falling muscle over-contracted); under action="po" the Pi feedforward
            follows x_r at the start of each control step (sine and staircase).
Reward (`reward=`): "tolerance" (default), `dm_control.utils.rewards.tolerance(x - x_r)`:
1 within +-0.5 mm of the target, Gaussian fall-off to 0.1 at 2 mm outside that band;
"tracking", max(0, 1 - |x - x_r| / `TRACKING_SCALE`), 1 mm (docs/learning.md: why).
Discount 1; episodes end at `time_limit` [s]. A load the muscle cannot lift to the
highest target at the regulator maximum is refused, naming the largest it can
(`feasibility.check_liftable`). At each reset the muscle hangs at rest at x = 0 with
vented chambers, and target and load are drawn uniformly from `target_range` [m] and
`load_range` [N] with the task's seeded `numpy.random.RandomState` (or fixed with
`target=` / `load=`), then any `randomize` parameters, then for "sine" the frequency or
for "staircase" its levels; the load mass is load / g.
A divergence (negative absolute chamber pressure, non-finite state, MuJoCo warning) raises
`dm_control.rl.control.PhysicsError`; from then on `step` refuses, with the same cause,
until `reset()`: the state it would continue from has no meaning.
"""

from __future__ import annotations

import collections
import math
from pathlib import Path

import mujoco
import numpy as np
from dm_env import specs

from wpam_mj.control.controllers import CONTROLLERS, PIControl, check_control
from wpam_mj.environments.muscle_physics import MusclePhysics, RigPhysics
from wpam_mj.experiments.drives import SineSpec
from wpam_mj.experiments.feasibility import check_liftable
from wpam_mj.fitting.randomize import ParameterRanges, ranges_of
from wpam_mj.physics.geometry import BraidGeometry
from wpam_mj.physics.muscle import MuscleModel
from wpam_mj.physics.params import Params, preset
from wpam_mj.errors import ParameterError, check_range, check_whole_steps
from wpam_mj.units import MM
from wpam_mj.simulation.context import check_dt, check_load
from wpam_mj.visualisation import gl

with gl.quiet_display_probe():  # dm_control probes GLFW on import
    from dm_control.rl import control

ACTIONS = ("po", "both", "residual")
REFERENCES = ("step", "sine", "staircase")
REWARDS = ("tolerance", "tracking")
STAIR_HOLD = 2.5  # s per staircase level: our choice, long enough for a PI to act
SINE_FREQ_RANGE = (0.1, 1.0)  # Hz: the paper's frequency sweep (§4.2, Fig. 17)
TARGET_RANGE = (0.0, 50 * MM)  # m: the paper's step experiment spans 0-50 mm (§4.1)
LOAD_RANGE = (50.0, 150.0)  # N: the paper's loads (§4)
REWARD_BOUND = 0.5 * MM  # m: reward 1 inside +-bound
REWARD_MARGIN = 2 * MM  # m: reward 0.1 this far outside the bound
TRACKING_SCALE = 1 * MM  # m: the "tracking" reward falls linearly to 0 at this error
# dm_control's Gaussian sigmoid reaches 0.1 at the margin: exp(-(d s)^2 / 2) with
# s = sqrt(-2 ln 0.1) (dm_control.utils.rewards._sigmoids), d the distance in margins
_GAUSSIAN_SCALE = float(np.sqrt(-2 * np.log(0.1)))
TIME_LIMIT_RANGE = (1e-3, 3600.0)  # s
CONTROL_TIMESTEP_RANGE = (1e-5, 1.0)  # s

OBSERVATIONS = ("x_m", "velocity_m_s", "pi_pa", "po_pa", "target_m", "load_n")


class TrackingTask(control.Task):
    """Hold the load at a target contraction; see the module docstring for the specs."""

    def __init__(self, params: Params, *, action: str = "po", target: float | None = None,
                 load: float | None = None, target_range: tuple[float, float] = TARGET_RANGE,
                 load_range: tuple[float, float] = LOAD_RANGE,
                 random: int | np.random.RandomState | None = None,
                 flat_observation: bool = False, reference: str = "step",
                 sine_freq: float | None = None,
                 sine_freq_range: tuple[float, float] = SINE_FREQ_RANGE,
                 randomize: ParameterRanges | None = None, reward: str = "tolerance",
                 time_limit: float = 10.0, controller: str = "pi", dt: float = 1e-3,
                 control_timestep: float = 0.01) -> None:
        if action not in ACTIONS:
            raise ParameterError(f"action = {action!r}; valid actions: {', '.join(ACTIONS)}")
        if reference not in REFERENCES:
            raise ParameterError(f"reference = {reference!r}; valid references: "
                                 f"{', '.join(REFERENCES)}")
        if reward not in REWARDS:
            raise ParameterError(f"reward = {reward!r}; valid rewards: {', '.join(REWARDS)}")
        self._controller = CONTROLLERS[check_control(controller)]
        if action == "both" and controller != "pi":
            raise ParameterError(f"controller = {controller!r} shapes the commands around the "
                                 "agent's Po: use it with action=\"po\" (action=\"both\" "
                                 "commands Pi and Po itself)")
        self._reference, self._reward = reference, reward
        self._dt, self._time_limit = dt, time_limit
        self._drive: tuple[np.ndarray, np.ndarray] | None = None  # the episode's, if ahead
        self._levels = np.zeros(1)  # staircase targets [m], one per STAIR_HOLD
        self._n_levels = math.ceil(time_limit / STAIR_HOLD) + 1
        self._freq_range = _check_interval("sine_freq_range", sine_freq_range, 1e-3, 20.0, "Hz")
        self._fixed_freq = None if sine_freq is None else SineSpec(sine_freq).freq
        self._sine: SineSpec | None = None
        x_max = BraidGeometry.from_params(params.braid).max_contraction
        if reference == "sine":  # its peak must be a reachable contraction
            spec = SineSpec(self._freq_range[0])
            check_range("sine target peak", (spec.mean + spec.amplitude) / MM, 0.0,
                        x_max / MM, "mm")
        self._target_range = _check_interval("target_range", target_range, 0.0, x_max, "m")
        self._load_range = tuple(check_load(v) for v in _check_interval(
            "load_range", load_range, -np.inf, np.inf, "N"))
        self._fixed_target = None if target is None else check_range("target", target, 0.0,
                                                                      x_max, "m")
        self._fixed_load = None if load is None else check_load(load)
        heaviest = self._load_range[1] if load is None else self._fixed_load
        check_liftable(params, [heaviest], "load" if load is not None else "load_range high",
                       x=self._highest_target(x_max))
        self._params, self._action = params, action
        self._base, self._randomize = params, randomize
        self._flat = flat_observation
        self._muscle = MuscleModel.from_params(params)
        if not isinstance(random, np.random.RandomState):
            random = np.random.RandomState(check_seed(random))
        self._random = random
        self.target = self._fixed_target if target is not None else 0.0
        self._pi_ff = 0.0
        self._next: tuple[float | None, float | None] = (None, None)
        pn, c = params.pneumatics, params.controller
        # the paper's PI on Po at the control step, under action="residual"
        self._control_timestep = control_timestep
        self._pi: PIControl | None = None  # made for each episode's parameters
        self._po_lo, self._po_hi = pn.p_min, c.po_cap  # the Po command's range [Pa]
        if action == "po":
            self._lo, self._hi = np.array([pn.p_min]), np.array([c.po_cap])
            self._name = "po_cmd_pa"
        elif action == "residual":
            self._lo, self._hi = np.array([-c.po_cap]), np.array([c.po_cap])
            self._name = "po_residual_pa"
        else:
            self._lo, self._hi = np.array([pn.p_min, pn.p_min]), np.array([pn.p_max, c.po_cap])
            self._name = "pi_cmd_pa,po_cmd_pa"
        self._lo_f, self._hi_f = self._lo.tolist(), self._hi.tolist()  # the step path's

    def _highest_target(self, x_max: float) -> float:
        """The highest contraction [m] an episode may ask for."""
        if self._reference == "sine":
            spec = SineSpec(self._freq_range[0])
            return min(spec.mean + spec.amplitude, x_max)
        if self._fixed_target is not None and self._reference == "step":
            return self._fixed_target
        return self._target_range[1]

    def fix_next_episode(self, target: float | None = None, load: float | None = None) -> None:
        """Use `target` [m] and `load` [N] for the next episode only (gym reset options);
        the random draws still happen, so the sequence of later episodes is unchanged."""
        x_max = BraidGeometry.from_params(self._base.braid).max_contraction
        self._next = (None if target is None else check_range("target", target, 0.0, x_max,
                                                               "m"),
                      None if load is None else check_load(load))
        if self._next[1] is not None:
            check_liftable(self._base, [self._next[1]], x=self._highest_target(x_max))

    @property
    def random(self) -> np.random.RandomState:
        """The task's random state (targets and loads)."""
        return self._random

    def initialize_episode(self, physics: MusclePhysics) -> None:
        # draw both every episode so fixing one does not shift the other's sequence
        target = self._random.uniform(*self._target_range)
        load = self._random.uniform(*self._load_range)
        next_target, next_load = self._next
        self._next = (None, None)
        target = next_target if next_target is not None else (
            target if self._fixed_target is None else self._fixed_target)
        load = next_load if next_load is not None else (
            load if self._fixed_load is None else self._fixed_load)
        self.target = target
        if self._randomize is not None:  # drawn after target and load: same sequence
            self._params = self._randomize.sample(self._base, self._random)
            self._muscle = MuscleModel.from_params(self._params)
            physics.set_params(self._params)
        physics.set_load(load)
        if self._reference == "sine":
            freq = self._random.uniform(*self._freq_range)
            self._sine = SineSpec(freq if self._fixed_freq is None else self._fixed_freq)
        if self._reference == "staircase":
            self._levels = self._random.uniform(*self._target_range, size=self._n_levels)
        if self._controller.needs_target_ahead:
            t = np.arange(round(self._time_limit / self._dt) + 1) * self._dt
            x_ref = self.targets_at(t)
            self._drive = self._controller.feedforward(self._params, physics.load(), x_ref,
                                                       self._dt)
        else:
            self._pi_ff = self._feedforward(self.target_at(0.0), physics.load())
        if self._action == "residual":
            self._pi = PIControl.for_run(self._params, self._control_timestep)

    def _feedforward(self, target: float, load: float) -> float:
        """The controller's Pi [Pa] holding `target` [m] under `load` [N]."""
        return float(self._controller.feedforward(self._params, load, np.array([target]),
                                                  self._dt)[0][0])

    def target_at(self, t: float) -> float:
        """Target contraction x_r [m] at episode time `t` [s] (the same floats as
        `targets_at`, without its arrays: this runs every control step)."""
        if self._reference == "staircase":
            return float(self._levels[min(int(t / STAIR_HOLD + 1e-9), self._n_levels - 1)])
        if self._sine is None:
            return self.target
        return float(self._sine.target(np.array([t]))[0])

    def targets_at(self, t: np.ndarray) -> np.ndarray:
        """Target contractions x_r [m] at episode times `t` [s] (an array)."""
        if self._reference == "staircase":
            # t sums physics steps: 2.4999999 s is 2.5 s
            k = (t / STAIR_HOLD + 1e-9).astype(np.int64)
            return self._levels[np.minimum(k, self._n_levels - 1)]
        if self._sine is None:
            return np.full(len(t), self.target)
        return self._sine.target(t)

    def action_spec(self, physics: MusclePhysics) -> specs.BoundedArray:
        return specs.BoundedArray(shape=self._lo.shape, dtype=np.float64, minimum=self._lo,
                                  maximum=self._hi, name=self._name)

    @property
    def action_unit(self) -> str:
        """What the action's numbers are, as refusals name it."""
        return f"[Pa] ({self._name})"

    def before_step(self, action, physics: MusclePhysics) -> None:
        self.apply_action(check_actions(action, self._lo.size, self.action_unit), physics)

    def apply_action(self, action: np.ndarray, physics: MusclePhysics) -> None:
        """Set the regulator commands for the checked `action` (`check_actions`; [Pa]),
        clipped to the action's bounds, with the controller's feedforward and, under
        action="residual", the paper's PI around it."""
        values = action.tolist()
        if self._action == "both":
            pi_cmd = min(max(values[0], self._lo_f[0]), self._hi_f[0])
            physics.set_commands(pi_cmd, min(max(values[1], self._lo_f[1]), self._hi_f[1]))
            return
        t = physics.time()
        pi_cmd, po_drive = self._feedforward_now(t, physics.load())
        po = min(max(values[0], self._lo_f[0]), self._hi_f[0])
        if self._pi is not None:  # action="residual": the PI's Po plus the agent's
            po = self._pi.update(physics.contraction(), self.target_at(t)) + po
        physics.set_commands(pi_cmd, min(max(po + po_drive, self._po_lo), self._po_hi))

    def _feedforward_now(self, t: float, load: float) -> tuple[float, float]:
        """`feedforward_at` at one time `t` [s], the same floats without its arrays where
        the feedforward is a table (a drive, a step target)."""
        if self._drive is not None:
            k = min(round(t / self._dt), len(self._drive[0]) - 1)  # half-even, as np.rint
            po = float(self._drive[1][k]) if self._controller.adds_drive_po else 0.0
            return float(self._drive[0][k]), po
        if self._reference == "step":
            return self._pi_ff, 0.0
        pi_cmd, po = self.feedforward_at(np.array([t]), load)
        return float(pi_cmd[0]), float(po[0])

    def feedforward_at(self, t: np.ndarray, load: float) -> tuple[np.ndarray, np.ndarray]:
        """(Pi command, Po added to the agent's) [Pa] at the start of control steps at
        episode times `t` [s] under action "po" or "residual": what `before_step` commands
        around the agent; `wpam_mj.environments.vector_env` takes a whole episode's at once."""
        if self._drive is not None:  # the episode's drive, at these physics steps
            k = np.minimum(np.rint(t / self._dt).astype(np.int64), len(self._drive[0]) - 1)
            po = self._drive[1][k] if self._controller.adds_drive_po else np.zeros(len(t))
            return self._drive[0][k], po
        if self._reference == "step":
            return np.full(len(t), self._pi_ff), np.zeros(len(t))
        return (self._controller.feedforward(self._params, load, self.targets_at(t),
                                             self._dt)[0],
                np.zeros(len(t)))

    @property
    def pi_controller(self) -> PIControl | None:
        """The PI that the agent's action corrects (action="residual"), else None."""
        return self._pi

    def observation_spec(self, physics: MusclePhysics) -> collections.OrderedDict:
        if self._flat:  # as control.flatten_observation: the values in OBSERVATIONS order
            key = control.FLAT_OBSERVATION_KEY
            return collections.OrderedDict(
                [(key, specs.Array(shape=(len(OBSERVATIONS),), dtype=np.float64, name=key))])
        return collections.OrderedDict(
            (name, specs.Array(shape=(1,), dtype=np.float64, name=name))
            for name in OBSERVATIONS)

    def readings(self, physics: MusclePhysics) -> list[float]:
        """The observed values in `OBSERVATIONS` order [SI]."""
        pi, po = physics.pressures()
        return [physics.contraction(), physics.velocity(), pi, po,
                self.target_at(physics.time()), physics.load()]

    def get_observation(self, physics: MusclePhysics) -> collections.OrderedDict:
        values = self.readings(physics)
        if self._flat:  # what control.flatten_observation would make of the values
            return collections.OrderedDict([(control.FLAT_OBSERVATION_KEY,
                                             np.array(values))])
        return collections.OrderedDict(
            (name, np.array([v], dtype=np.float64)) for name, v in zip(OBSERVATIONS, values))

    def get_reward(self, physics: MusclePhysics) -> float:
        return self.reward(physics.contraction() - self.target_at(physics.time()))

    def reward(self, error: float) -> float:
        """The reward of one tracking error x - x_r [m]: `rewards` on one value, the same
        float without arrays (this runs every control step)."""
        if self._reward == "tracking":
            return max(0.0, 1.0 - abs(error) / TRACKING_SCALE)
        if -REWARD_BOUND <= error <= REWARD_BOUND:
            return 1.0
        d = ((-REWARD_BOUND - error) if error < -REWARD_BOUND else (error - REWARD_BOUND)) \
            / REWARD_MARGIN
        d *= _GAUSSIAN_SCALE
        return float(np.exp(-0.5 * (d * d)))

    def rewards(self, error: np.ndarray) -> np.ndarray:
        """Rewards of tracking errors x - x_r [m] (an array; the module docstring):
        "tolerance" is `dm_control.utils.rewards.tolerance` with a Gaussian tail, its
        operations in its order."""
        if self._reward == "tracking":
            return np.maximum(0.0, 1.0 - np.abs(error) / TRACKING_SCALE)
        d = np.where(error < -REWARD_BOUND, -REWARD_BOUND - error, error - REWARD_BOUND) \
            / REWARD_MARGIN
        d *= _GAUSSIAN_SCALE
        inside = np.logical_and(-REWARD_BOUND <= error, error <= REWARD_BOUND)
        return np.where(inside, 1.0, np.exp(-0.5 * (d * d)))

    @property
    def randomize(self) -> ParameterRanges | None:
        """The parameter ranges each episode draws from, or None."""
        return self._randomize

    @property
    def action(self) -> str:
        """The action kind, one of `ACTIONS`."""
        return self._action

    @property
    def action_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """(low, high) of the action [Pa], which `before_step` clips to."""
        return self._lo, self._hi

    @property
    def po_range(self) -> tuple[float, float]:
        """(low, high) [Pa] of the Po command under action "po" or "residual"."""
        return self._po_lo, self._po_hi

    def get_termination(self, physics: MusclePhysics) -> None:
        return None  # episodes end at the time limit only


def make_env(params: Params | None = None, *, action: str = "po", time_limit: float = 10.0,
             control_timestep: float = 0.01, dt: float = 1e-3, seed: int | None = None,
             target: float | None = None, load: float | None = None,
             target_range: tuple[float, float] = TARGET_RANGE,
             load_range: tuple[float, float] = LOAD_RANGE,
             flat_observation: bool = False, reference: str = "step",
             sine_freq: float | None = None,
             sine_freq_range: tuple[float, float] = SINE_FREQ_RANGE,
             randomize: str | Path | float | ParameterRanges | None = None,
             reward: str = "tolerance", controller: str = "pi") -> control.Environment:
    """The hung W-PAM as a `dm_control.rl.control.Environment`.

    Args:
      params: muscle parameters (default: the calibrated ``wpam`` preset).
      action: "po" (Po command), "both" (Pi and Po commands) or "residual" (a correction
        to the paper's PI on Po), see the module docstring.
      time_limit: episode length [s].
      control_timestep: time between actions [s], a whole multiple of `dt`.
      dt: physics step [s].
      seed: seed of the task's RandomState (targets, loads): None or an integer in
        [0, 2**32 - 1].
      target: fix the target contraction [m] instead of drawing it.
      load: fix the load [N] instead of drawing it.
      target_range: (low, high) [m] for random targets.
      load_range: (low, high) [N] for random loads.
      flat_observation: concatenate the observations, in `OBSERVATIONS` order, into one
        array of shape (6,) under the key "observations".
      reference: "step" (constant target) or "sine" (sinusoidal target), see above.
      sine_freq: fix the sine target's frequency [Hz] instead of drawing it.
      sine_freq_range: (low, high) [Hz] for random sine frequencies.
      randomize: domain randomisation: a ranges file (`wpam fit --randomize-out`),
        `ParameterRanges`, or a relative spread (0.1: each fitted plant parameter of
        `randomize.PLANT_PARAMETERS` within +-10 %); each episode draws the listed
        parameters from their ranges (with the task's RandomState, after target and load).
      reward: "tolerance" (1 within +-0.5 mm, Gaussian tail) or "tracking" (1 - |x - x_r|
        / 5 mm, floored at 0); see the module docstring.
      controller: a control mode (`wpam_mj.control.controllers.CONTROLS`) whose feedforward
        shapes the commands around the agent's Po (action="po"; see the module docstring).
    """
    check_dm_control()
    dt = check_dt(dt)
    physics, task, time_limit, n_sub = build(
        MusclePhysics, params, action=action, time_limit=time_limit,
        control_timestep=control_timestep, dt=dt, seed=seed, target=target, load=load,
        target_range=target_range, load_range=load_range, flat_observation=flat_observation,
        reference=reference, sine_freq=sine_freq, sine_freq_range=sine_freq_range,
        randomize=randomize, reward=reward, controller=controller)
    # the task makes the flat observation itself (`get_observation`)
    return control.Environment(physics, task, time_limit=time_limit, n_sub_steps=n_sub)


def build(physics_class: type[MusclePhysics] | type[RigPhysics], params: Params | None,
          *, time_limit: float, control_timestep: float, dt: float, seed: int | None,
          randomize, **task_kwargs) -> tuple:
    """`make_env`'s arguments validated, but for dt [s], which the environment checked as
    its first use: (physics of `physics_class`, its `TrackingTask`, time limit [s],
    physics steps per control step)."""
    params = preset() if params is None else params
    randomize = ranges_of(randomize, params)
    time_limit = check_range("time_limit", time_limit, *TIME_LIMIT_RANGE, "s")
    control_timestep = check_range("control_timestep", control_timestep,
                                   *CONTROL_TIMESTEP_RANGE, "s")
    n_sub = check_whole_steps("control_timestep", control_timestep, dt)
    physics = physics_class.create(params, dt)
    task = TrackingTask(params, random=seed, randomize=randomize, time_limit=time_limit,
                        dt=dt, control_timestep=control_timestep, **task_kwargs)
    return physics, task, time_limit, n_sub


# The mujoco versions dm-control runs on: 1.0.50, its newest, fails on mujoco 4 (every
# Physics construction: MjModel has no attribute 'flex_vertedge').
DM_CONTROL_MUJOCO = ">= 3.17, < 4"


def dm_control_runs() -> bool:
    """Whether dm_control runs on the installed mujoco (`DM_CONTROL_MUJOCO`)."""
    return int(mujoco.__version__.split(".")[0]) < 4


def check_dm_control() -> None:
    """Refuse, in one line, a mujoco that dm_control does not run on."""
    if not dm_control_runs():
        raise RuntimeError(f"the dm_control environment needs mujoco {DM_CONTROL_MUJOCO} "
                           f"(dm-control fails on mujoco {mujoco.__version__}); the default "
                           "install has it, and the Gymnasium ids run on both")


def _brief(value) -> str:
    """`value` on one short line, for a refusal."""
    text = " ".join(repr(value).split())
    return text if len(text) <= 60 else text[:57] + "..."


def check_actions(actions, size: int, unit: str, num_envs: int | None = None) -> np.ndarray:
    """The one check of what an agent sends: for one environment (`num_envs` None), `size`
    real numbers in any shape ((size,) the usual), returned as float64 (size,); for
    `num_envs` environments, one row of them per environment, (num_envs, size) (or
    (num_envs,) when size is 1), returned as float64 (num_envs, size). Numbers out of
    the action's bounds are the caller's to clip; anything else (strings, booleans,
    NaN or an infinity, the wrong count) is refused in one line naming it and `unit`."""
    label = "action" if num_envs is None else "actions"
    numbers = f"{size} finite number{'s' if size > 1 else ''} {unit}"
    want = numbers if num_envs is None else (f"({num_envs}, {size}) finite numbers, one "
                                              f"row of {numbers} per environment")
    try:
        a = actions if type(actions) is np.ndarray else np.asarray(actions)
    except (TypeError, ValueError):  # ragged nesting
        raise ParameterError(f"{label} = {_brief(actions)} must be {want}") from None
    if a.dtype.kind not in "fiu":
        raise ParameterError(f"{label} = {_brief(actions)} must be {want}; got dtype {a.dtype}")
    if a.size != size * (num_envs or 1) or (num_envs is not None and (
            a.ndim == 0 or a.shape[0] != num_envs)):
        raise ParameterError(f"{label} must be {want}; got shape {a.shape}")
    a = a.astype(np.float64, copy=False).reshape(size if num_envs is None else (num_envs, size))
    if not (np.isfinite(a).all() if a.size > 4 else all(map(math.isfinite, a.ravel().tolist()))):
        where = tuple(int(i) for i in np.argwhere(~np.isfinite(a))[0])
        raise ParameterError(f"{label}[{', '.join(map(str, where))}] = {float(a[where])} "
                             f"must be finite: {label} must be {want}")
    return a


SEED_RANGE = (0, 2**32 - 1)  # numpy.random.RandomState's seed range


def check_seed(seed: int | None) -> int | None:
    """A RandomState seed: None (fresh entropy) or an integer in `SEED_RANGE`."""
    if seed is None:
        return None
    lo, hi = SEED_RANGE
    if isinstance(seed, (bool, np.bool_)) or not isinstance(seed, (int, np.integer)) \
            or not lo <= seed <= hi:
        raise ParameterError(f"seed = {seed!r} must be None or an integer in [{lo}, {hi}]")
    return int(seed)


def _check_interval(name: str, interval, lo: float, hi: float,
                    unit: str) -> tuple[float, float]:
    try:
        a, b = (float(v) for v in interval)
    except (TypeError, ValueError):
        raise ParameterError(f"{name} = {interval!r} must be a pair (low, high) {unit}") \
            from None
    if not (lo <= a <= b <= hi):
        raise ParameterError(f"{name} = ({a:g}, {b:g}) {unit} must satisfy "
                             f"{lo:g} <= low <= high <= {hi:g} {unit}")
    return a, b
