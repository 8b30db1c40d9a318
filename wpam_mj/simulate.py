"""The simulation loop: MuJoCo moves the load, wpam_mj computes the muscle every step.

Per physics step k (state x_k, v_k read straight from qpos/qvel, so nothing is a step old):
  1. controller (`wpam_mj.control.PoController`): the Po command; Pi command given;
  2. `wpam_mj.plant.Plant.advance`: regulators (dead time + first-order lag) and chambers
     (explicit Euler of dp/dt with the flow through the restriction and the volume
     change), both from `wpam_mj.pneumatics`; tension T(x_k, Pi_k, Po_k) -> actuator ctrl
     and friction level -> tendon frictionloss (stiction through MuJoCo's no-slip solver);
  3. mj_step: semi-implicit Euler of the load.
The record layout and per-run constants are `wpam_mj.loop_contract`, shared with the
compiled twin of `run_python` (`wpam_mj.fastloop`). No global MuJoCo callback is
installed, so nothing leaks into other models.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, field

import mujoco
import numpy as np

from wpam_mj import fastloop
from wpam_mj.control import PoController, make_controller
from wpam_mj.loop_contract import (REC_FIELDS, REC_ROWS, RunConstants, SimulationDiverged,
                                   contraction_diverged)
from wpam_mj.model import MuscleIndex, build_model, check_dt, check_load
from wpam_mj.muscle import MuscleModel
from wpam_mj.params import MPA, Params, ParameterError
from wpam_mj.plant import Plant
from wpam_mj.results import SimResult


@dataclass(frozen=True)
class Drive:
    """Commands for one run, one sample per physics step (SI units).

    pi_cmd: Pi command [Pa], shape (n,).
    po_cmd: Po command [Pa], shape (n,), used in open loop; ignored under feedback.
    x_ref: target contraction [m], shape (n,); NaN where there is none (open loop).
    start_at_rest: True when the rig has been holding the first commands before the run
      (regulators settled, chambers at their pressures); False: chambers vented at t = 0.
    """

    pi_cmd: np.ndarray
    po_cmd: np.ndarray
    x_ref: np.ndarray
    extra: dict = field(default_factory=dict)
    start_at_rest: bool = False

    def __post_init__(self) -> None:
        n = len(self.pi_cmd)
        if n < 2:  # a run needs a start and at least one step
            raise ParameterError(f"drive has {n} sample(s); a run needs at least 2 "
                                 "(a positive duration)")
        for name in ("pi_cmd", "po_cmd", "x_ref"):
            arr = np.ascontiguousarray(getattr(self, name), dtype=float)
            if arr.shape != (n,):
                raise ParameterError(f"drive.{name} has shape {arr.shape}, expected ({n},)")
            object.__setattr__(self, name, arr)
        for name in ("pi_cmd", "po_cmd"):
            arr = getattr(self, name)
            if not np.all(np.isfinite(arr)):
                raise ParameterError(f"drive.{name} contains NaN or infinite values")


def simulate(params: Params, load: float, drive: Drive, *, dt: float = 1e-3,
             control: str = "open", record_dt: float = 0.01,
             engine: str = "auto") -> SimResult:
    """Run one experiment and return the recorded time series.

    Args:
      params: muscle and drive parameters.
      load: hanging load [N].
      drive: commands sampled at `dt` (see `Drive`).
      dt: physics time step [s].
      control: a name of `wpam_mj.control.CONTROLLERS`: "open" (Po from drive.po_cmd),
        "pi" or "pid" (Po from feedback on x_ref).
      record_dt: sample period of the returned series [s], a multiple of dt.
      engine: "python" (reference loop), "c" (compiled loop, same results), or "auto"
        (compiled when available and it implements `control`; otherwise Python, with a
        one-line notice on stderr when only the controller is missing).
    """
    load, dt = check_load(load), check_dt(dt)
    k = RunConstants.make(params, dt, record_dt, start_at_rest=drive.start_at_rest)
    controller = make_controller(control, params, dt)
    _check_commands(drive, params, dt, feedback=controller.feedback)
    if controller.feedback and not np.all(np.isfinite(drive.x_ref)):
        raise ParameterError("feedback control needs a finite target x_ref at every step")
    if not params.outer_chamber and (controller.feedback or np.any(drive.po_cmd > 0.0)):
        raise ParameterError(f"the {params.preset} preset has no outer chamber: Po must stay "
                             "0 (open loop with --po-down 0)")
    model = build_model(params, load, dt)
    data = mujoco.MjData(model)
    muscle = MuscleModel.from_params(params)
    n = len(drive.pi_cmd)
    rec = np.zeros((REC_ROWS, (n - 1) // k.record_every + 1))
    run = _select_engine(engine, control)
    status = run(model, data, muscle, controller, k, drive, rec)
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


_noticed: set[str] = set()  # Python fallbacks already announced (once per process)


def _python_fallback(key: str, why: str):
    """The Python loop, saying once per process why it runs instead of the compiled one."""
    if key not in _noticed:
        _noticed.add(key)
        print(f"wpam_mj: {why}; running the Python loop (about 6x slower, same physics)",
              file=sys.stderr)
    return run_python


def _select_engine(engine: str, control: str):
    """The loop for `engine` and the controller named `control`."""
    if engine == "python":
        return run_python
    if engine == "c":
        return fastloop.run_compiled
    if engine != "auto":
        raise ParameterError(f"unknown engine {engine!r}; valid: auto, python, c")
    if not fastloop.available():
        if fastloop.disabled():  # the user asked for it (WPAM_MJ_NO_COMPILE=1)
            return run_python
        return _python_fallback("", f"the compiled loop is unavailable "
                                    f"({fastloop.unavailable_reason()})")
    if control not in fastloop.compiled_controllers():
        return _python_fallback(control, f"controller {control!r} has no compiled loop")
    return fastloop.run_compiled


def run_python(model, data, muscle: MuscleModel, controller: PoController, k: RunConstants,
               drive: Drive, rec: np.ndarray):
    """Reference loop in plain Python floats; returns None or (step, reason)."""
    plant = Plant(muscle, k)
    idx = MuscleIndex.of(model)
    qpos, qvel = data.qpos, data.qvel
    j = 0
    for step in range(len(drive.pi_cmd)):
        x = float(qpos[idx.qpos])
        v = float(qvel[idx.dof])
        if not -1.0 < x < 1.0:
            return step, contraction_diverged(x)
        pi_gauge, po_gauge = plant.pressures
        pi_c = float(drive.pi_cmd[step])
        xr = float(drive.x_ref[step])
        po_c = controller.update(x, xr, float(drive.po_cmd[step]))
        if step == 0 and k.start_at_rest:  # the first commands were held before the run
            plant.rest(pi_c, po_c)
            pi_gauge, po_gauge = plant.pressures
        try:
            tension, friction = plant.actuate(model, data, idx, x, v, pi_c, po_c)
        except SimulationDiverged as err:
            return step, str(err)
        if step % k.record_every == 0:  # the state at the start of this step
            rec[:, j] = (step * k.dt, x, v, xr, pi_gauge, po_gauge, pi_c, po_c, tension,
                         friction, *plant.set_points)
            j += 1
    return None
