"""The simulation loop: MuJoCo moves the load, wpam_mj computes the muscle every step.

Per physics step k (state x_k, v_k read straight from qpos/qvel, so nothing is a step old):
  1. controller: Po command from PI/PID (or the open-loop schedule); Pi command given;
  2. `Plant.advance`: regulators (dead time + first-order lag, `wpam_mj.pneumatics`);
     tension T(x_k, Pi_k, Po_k) -> actuator ctrl and friction level -> tendon
     frictionloss (stiction through MuJoCo's no-slip solver); chambers by explicit
     Euler of dp/dt with the flow through the restriction and the volume change S(x_k) v_k;
  3. mj_step: semi-implicit Euler of the load.
No global MuJoCo callback is installed, so nothing leaks into other models.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import mujoco
import numpy as np

from wpam_mj import pneumatics as pn
from wpam_mj.control import PoFeedback, check_control
from wpam_mj.model import MuscleIndex, build_model, check_dt, check_load
from wpam_mj.muscle import MuscleModel
from wpam_mj.params import MPA, Params, ParameterError
from wpam_mj.results import SimResult


# Rows of the recording array filled by both loops, in this order.
REC_FIELDS = ("time", "x", "velocity", "x_ref", "pi", "po", "pi_cmd", "po_cmd", "tension",
              "friction", "pi_reg", "po_reg")
REC_ROWS = len(REC_FIELDS)


class SimulationDiverged(RuntimeError):
    """The state left its physical range (non-finite or negative absolute pressure)."""


@dataclass(frozen=True)
class Drive:
    """Commands for one run, one sample per physics step (SI units).

    pi_cmd: Pi command [Pa], shape (n,).
    po_cmd: Po command [Pa], shape (n,), used in open loop; ignored under feedback.
    x_ref: target contraction [m], shape (n,); NaN where there is none (open loop).
    """

    pi_cmd: np.ndarray
    po_cmd: np.ndarray
    x_ref: np.ndarray
    extra: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        n = len(self.pi_cmd)
        for name in ("pi_cmd", "po_cmd", "x_ref"):
            arr = np.ascontiguousarray(getattr(self, name), dtype=float)
            if arr.shape != (n,):
                raise ParameterError(f"drive.{name} has shape {arr.shape}, expected ({n},)")
            object.__setattr__(self, name, arr)
        for name in ("pi_cmd", "po_cmd"):
            arr = getattr(self, name)
            if not np.all(np.isfinite(arr)):
                raise ParameterError(f"drive.{name} contains NaN or infinite values")


@dataclass(frozen=True)
class RunConstants:
    """Per-run constants of the step kernel, shared by the Python and compiled loops."""

    dt: float
    record_every: int
    feedback: bool
    derivative: bool
    lag_alpha: float  # 1 - exp(-dt / tau) of the regulator lag
    delay_steps: int  # regulator dead time in steps
    atmosphere: float
    p_max: float
    conductance_i: float
    conductance_o: float
    critical_ratio: float
    tube_volume: float
    bag_volume: float
    po_initial: float  # Po [Pa] the feedback outputs at zero error at the start (bumpless)

    @classmethod
    def make(cls, params: Params, dt: float, control: str, record_dt: float) -> "RunConstants":
        check_control(control)
        record_every = round(record_dt / dt)
        if record_every < 1 or abs(record_every * dt - record_dt) > 1e-9 * record_dt:
            raise ParameterError(f"record_dt = {record_dt} s must be a whole multiple of "
                                 f"dt = {dt} s")
        p = params.pneumatics
        tau = p.time_constant
        feedback = control != "open"
        return cls(
            dt=dt, record_every=record_every, feedback=feedback,
            derivative=control == "pid",
            lag_alpha=1.0 if tau == 0.0 else -math.expm1(-dt / tau),
            delay_steps=round(p.dead_time / dt), atmosphere=p.atmosphere, p_max=p.p_max,
            conductance_i=p.inner_conductance, conductance_o=p.outer_conductance,
            critical_ratio=p.critical_ratio,
            tube_volume=p.tube_volume,
            bag_volume=pn.outer_bag_volume(params.braid.outer_bag_length,
                                           params.braid.outer_bag_diameter),
            po_initial=params.controller.po_feedforward if feedback else 0.0)


def simulate(params: Params, load: float, drive: Drive, *, dt: float = 1e-3,
             control: str = "open", record_dt: float = 0.01,
             engine: str = "auto") -> SimResult:
    """Run one experiment and return the recorded time series.

    Args:
      params: muscle and drive parameters.
      load: hanging load [N].
      drive: commands sampled at `dt` (see `Drive`).
      dt: physics time step [s].
      control: "open" (Po from drive.po_cmd), "pi" or "pid" (Po from feedback on x_ref).
      record_dt: sample period of the returned series [s], a multiple of dt.
      engine: "python" (reference loop), "c" (compiled loop, same results), or "auto"
        (compiled when available).
    """
    load, dt = check_load(load), check_dt(dt)
    k = RunConstants.make(params, dt, control, record_dt)
    _check_commands(drive, params, dt, feedback=k.feedback)
    if k.feedback and not np.all(np.isfinite(drive.x_ref)):
        raise ParameterError("feedback control needs a finite target x_ref at every step")
    model = build_model(params, load, dt)
    data = mujoco.MjData(model)
    muscle = MuscleModel.from_params(params)
    n = len(drive.pi_cmd)
    rec = np.zeros((REC_ROWS, (n - 1) // k.record_every + 1))
    run = _select_engine(engine)
    status = run(model, data, muscle, params, k, drive, rec)
    if status is not None:
        step, what = status
        raise SimulationDiverged(f"simulation diverged at t = {step * dt:.4f} s: {what}; "
                                 "reduce dt or check the gains and pneumatic parameters")
    return SimResult(**dict(zip(REC_FIELDS, rec)), load=load, dt=dt, control=control,
                     preset=params.preset)


def _check_commands(drive: Drive, params: Params, dt: float, *, feedback: bool) -> None:
    """Every pressure command lies in [0, p_max]: a command time series may pass below the
    regulator's p_min on its way to 0 (vented); settings such as --po-down are checked
    against [p_min, p_max] where they are given (`wpam_mj.experiments.check_po`)."""
    hi = params.pneumatics.p_max
    for name in ("pi_cmd",) if feedback else ("pi_cmd", "po_cmd"):
        cmd = getattr(drive, name)
        bad = np.flatnonzero((cmd < 0.0) | (cmd > hi))
        if bad.size:
            i = bad[0]
            raise ParameterError(f"drive.{name} = {cmd[i] / MPA:g} MPa at t = {i * dt:g} s is "
                                 f"outside the regulator range [0, {hi / MPA:g}] MPa")


def _select_engine(engine: str):
    if engine == "python":
        return run_python
    from wpam_mj import fastloop  # noqa: PLC0415 (optional compiled path)
    if engine == "c":
        return fastloop.run_compiled
    if engine == "auto":
        return fastloop.run_compiled if fastloop.available() else run_python
    raise ParameterError(f"unknown engine {engine!r}; valid: auto, python, c")


class Plant:
    """Regulators, chambers and muscle force: everything but the load's motion.

    Holds the pneumatic state; `advance` is called once per physics step with the current
    contraction and velocity and returns the tension and friction level to apply.
    Pressures: regulator set points gauge [Pa], chamber pressures absolute [Pa].
    """

    def __init__(self, muscle: MuscleModel, k: RunConstants) -> None:
        self.muscle = muscle
        self.k = k
        self.set_i = self.set_o = 0.0
        self.p_i = self.p_o = k.atmosphere
        self._queue_i = [0.0] * k.delay_steps  # commands in flight (dead time)
        self._queue_o = [0.0] * k.delay_steps
        self._head = 0

    @property
    def pressures(self) -> tuple[float, float]:
        """Chamber gauge pressures (Pi, Po) [Pa]."""
        return self.p_i - self.k.atmosphere, self.p_o - self.k.atmosphere

    def advance(self, x: float, v: float, pi_cmd: float, po_cmd: float) -> tuple[float, float]:
        """One step at contraction x [m], velocity v [m/s]; returns (tension, friction) [N].

        The force uses the pressures at the start of the step; the regulators and
        chambers are then advanced to the end of it. Raises SimulationDiverged.
        """
        k, muscle, geom = self.k, self.muscle, self.muscle.geometry
        # regulators: dead time, then first-order lag
        if k.delay_steps:
            h = self._head
            pi_cmd, self._queue_i[h] = self._queue_i[h], pi_cmd
            po_cmd, self._queue_o[h] = self._queue_o[h], po_cmd
            self._head = (h + 1) % k.delay_steps
        self.set_i += k.lag_alpha * (min(max(pi_cmd, 0.0), k.p_max) - self.set_i)
        self.set_o += k.lag_alpha * (min(max(po_cmd, 0.0), k.p_max) - self.set_o)
        # muscle force from the chamber gauge pressures
        pa = k.atmosphere
        p_i, p_o = self.p_i, self.p_o
        tension = muscle.tension(x, p_i - pa, p_o - pa)
        friction = muscle.friction(x, p_i - pa, p_o - pa)
        # chambers
        area = geom.area(x)
        vol = geom.volume(x)
        m_i = pn.mass_flow(self.set_i + pa, p_i, k.conductance_i, k.critical_ratio)
        m_o = pn.mass_flow(self.set_o + pa, p_o, k.conductance_o, k.critical_ratio)
        v_i = vol + k.tube_volume
        v_o = k.bag_volume + k.tube_volume - vol - muscle.axial_area * x
        self.p_i = p_i + k.dt * (pn.RT0 * m_i - p_i * area * v) / v_i
        self.p_o = p_o + k.dt * (pn.RT0 * m_o + p_o * (area + muscle.axial_area) * v) / v_o
        if not (self.p_i > 0.0 and self.p_o > 0.0):
            raise SimulationDiverged(f"chamber pressure Pi = {self.p_i!r} Pa, "
                                     f"Po = {self.p_o!r} Pa (absolute)")
        return tension, friction

    def actuate(self, model: mujoco.MjModel, data: mujoco.MjData, idx: MuscleIndex,
                x: float, v: float, pi_cmd: float, po_cmd: float) -> tuple[float, float]:
        """`advance`, write the tension (actuator ctrl) and friction level (tendon
        frictionloss) into the model, then `mj_step`; returns (tension, friction) [N]."""
        tension, friction = self.advance(x, v, pi_cmd, po_cmd)
        data.ctrl[idx.actuator] = -tension
        model.tendon_frictionloss[idx.tendon] = friction
        mujoco.mj_step(model, data)
        return tension, friction


def run_python(model, data, muscle: MuscleModel, params: Params, k: RunConstants,
               drive: Drive, rec: np.ndarray):
    """Reference loop in plain Python floats; returns None or (step, reason)."""
    plant = Plant(muscle, k)
    pid = PoFeedback(params, k.dt, derivative=k.derivative, initial_output=k.po_initial)
    idx = MuscleIndex.of(model)
    qpos, qvel = data.qpos, data.qvel
    j = 0
    for step in range(len(drive.pi_cmd)):
        x = float(qpos[idx.qpos])
        v = float(qvel[idx.dof])
        if not -1.0 < x < 1.0:
            return step, f"contraction x = {x!r} m"
        pi_gauge, po_gauge = plant.pressures
        pi_c = float(drive.pi_cmd[step])
        xr = float(drive.x_ref[step])
        po_c = pid.update(x, xr) if k.feedback else float(drive.po_cmd[step])
        try:
            tension, friction = plant.actuate(model, data, idx, x, v, pi_c, po_c)
        except SimulationDiverged as err:
            return step, str(err)
        if step % k.record_every == 0:  # the state at the start of this step
            rec[:, j] = (step * k.dt, x, v, xr, pi_gauge, po_gauge, pi_c, po_c, tension,
                         friction, plant.set_i, plant.set_o)
            j += 1
    return None
