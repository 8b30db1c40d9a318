"""One run of the rig: a `Drive` of commands through the muscle, recorded.

The muscle is the ``wpam_mj.muscle`` actuator of the rig's MJCF
(`wpam_mj.simulation.model.rig_spec`):
each physics step it reads the contraction x and velocity from the tendon, runs its Po
controller, computes the tension and friction level from the chamber pressures, and
after MuJoCo's step advances the regulators and chambers (docs/plugin.md). Two engines
compute it, with bit-identical results (tests/test_plugin.py):
  "plugin": the compiled plugin (`wpam_mj.simulation.plugin`), stepped by `mujoco.batch` in chunks
    of `CHUNK_STEPS`, so that Ctrl-C and SIGTERM act within a fraction of a second;
  "python": the readable definition (`wpam_mj.simulation.engine`), a MuJoCo control callback.
"auto" takes the plugin when it is available, else Python with a one-line notice.
The recorded series are the first fields of the plugin's state (`wpam_mj.simulation.plugin.
STATE_FIELDS`), sampled every `record_dt`.
"""

from __future__ import annotations

import sys
import threading
from dataclasses import dataclass, field

import mujoco
import numpy as np
from mujoco import batch as mjbatch

from wpam_mj.simulation import engine as pyengine
from wpam_mj.simulation import plugin
from wpam_mj.infra import termination
from wpam_mj.control.controllers import make_controller
from wpam_mj.simulation.loop_contract import (REC_FIELDS, REC_ROWS, RunConstants,
                                              SimulationDiverged, state_failure)
from wpam_mj.simulation.context import RunContext
from wpam_mj.simulation.model import INSTANCE, check_chamber_step, rig_spec
from wpam_mj.physics.params import Params
from wpam_mj.errors import ParameterError
from wpam_mj.units import MPA
from wpam_mj.simulation.results import SimResult

CHUNK_STEPS = 2000  # plugin steps per batch call: ~3 ms of wall time between signal checks
ENGINES = ("auto", "plugin", "python")


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


@dataclass(frozen=True)
class Run:
    """One validated run: its context, the rig's spec, one row of input channels per step,
    and what turns its record into a `SimResult` (which carries the context)."""

    context: RunContext
    spec: mujoco.MjSpec
    inputs: np.ndarray  # (n steps, channels)
    record_every: int

    @classmethod
    def make(cls, context: RunContext, drive: Drive) -> "Run":
        """Validate a run of `drive` in `context` (its load and dt were checked where it was
        made; see `simulate` for the rest) and build its model spec."""
        dt, control = context.dt, context.control
        # the drive's feedforward came from the nominal values; the rig is the plant
        params = context.params.plant
        check_chamber_step(params, dt)
        k = RunConstants.make(params, dt, context.record_dt, start_at_rest=drive.start_at_rest)
        controller = make_controller(control, params, dt)
        _check_commands(drive, params, dt, feedback=controller.feedback)
        if controller.feedback and not np.all(np.isfinite(drive.x_ref)):
            raise ParameterError("feedback control needs a finite target x_ref at every step")
        if not params.outer_chamber and (controller.feedback or np.any(drive.po_cmd > 0.0)):
            raise ParameterError(f"the {params.preset} preset has no outer chamber: Po must "
                                 "stay 0 (open loop with --po-down 0)")
        spec = rig_spec(context, start_at_rest=drive.start_at_rest)
        inputs = np.column_stack([getattr(drive, name)
                                  for name in plugin.control_mode(control).channels_for(
                                      params.outer_chamber)])
        return cls(context, spec, inputs, k.record_every)

    def result(self, rec: np.ndarray, failure: tuple[int, str] | None) -> SimResult:
        """The run's `SimResult`; raises SimulationDiverged for a failure (step, reason)."""
        if failure is not None:
            step, what = failure
            raise SimulationDiverged(f"simulation diverged at t = {step * self.context.dt:.4f} "
                                     f"s: {what}; reduce dt or check the gains and pneumatic "
                                     "parameters")
        return SimResult(**dict(zip(REC_FIELDS, rec)), context=self.context)


def simulate(params: Params, load: float, drive: Drive, *, dt: float = 1e-3,
             control: str = "open", record_dt: float = 0.01,
             engine: str = "auto") -> SimResult:
    """Run one experiment and return the recorded time series.

    Args:
      params: muscle and drive parameters.
      load: hanging load [N].
      drive: commands sampled at `dt` (see `Drive`).
      dt: physics time step [s].
      control: a name of `wpam_mj.control.controllers.CONTROLLERS`: "open" (Po from drive.po_cmd),
        "pi" or "pid" (Po from feedback on x_ref), "pi_ff" (PI plus drive.po_cmd).
      record_dt: sample period of the returned series [s], a multiple of dt.
      engine: "plugin", "python" or "auto" (see the module docstring; "c" is taken as
        "plugin").
    """
    _select_engine(engine, control)  # an unknown engine is refused before the run is built
    context = RunContext(params, dt, load, control, record_dt)
    return simulate_run(Run.make(context, drive), engine)


def simulate_run(run: Run, engine: str = "auto") -> SimResult:
    """`simulate` of a run already validated and built (`Run.make`)."""
    run_engine = _select_engine(engine, run.context.control)
    return run.result(*run_engine(run.spec, run.inputs, run.record_every))


def _check_commands(drive: Drive, params: Params, dt: float, *, feedback: bool) -> None:
    """Every pressure command lies in [0, p_max]: a command time series may pass below the
    regulator's p_min on its way to 0 (vented); settings such as --po-down are checked
    against [p_min, p_max] where they are given (`wpam_mj.experiments.drives.check_po`)."""
    hi = params.pneumatics.p_max
    for name in ("pi_cmd",) if feedback else ("pi_cmd", "po_cmd"):
        cmd = getattr(drive, name)
        bad = np.flatnonzero((cmd < 0.0) | (cmd > hi))
        if bad.size:
            i = bad[0]
            raise ParameterError(f"drive.{name} = {cmd[i] / MPA:g} MPa at t = {i * dt:g} s is "
                                 f"outside the regulator range [0, {hi / MPA:g}] MPa")


_noticed: set[str] = set()  # Python fallbacks already announced (once per process)


def _select_engine(engine: str, control: str = "open"):
    """The runner for `engine` and the controller named `control` (see `simulate`)."""
    if engine == "python":
        return _run_python
    if control not in plugin.CONTROL_BY_NAME:  # a controller only Python defines
        if engine != "auto":
            raise ParameterError(f"controller {control!r} runs on the Python engine only")
        if control not in _noticed:
            _noticed.add(control)
            print(f"wpam_mj: controller {control!r} has no compiled form; running the Python"
                  " engine (about 6x slower)", file=sys.stderr)
        return _run_python
    if engine in ("plugin", "c"):
        if not plugin.available():
            raise RuntimeError(f"the compiled plugin is unavailable "
                               f"({plugin.unavailable_reason()}); use engine='python'")
        return _run_plugin
    if engine != "auto":
        raise ParameterError(f"unknown engine {engine!r}; valid: {', '.join(ENGINES)}")
    # without the plugin, loading it has said why, once per command (plugin_build.load)
    return _run_plugin if plugin.available() else _run_python


def _record_shape(n: int, record_every: int) -> tuple[int, int]:
    return REC_ROWS, (n - 1) // record_every + 1


def _run_plugin(spec: mujoco.MjSpec, inputs: np.ndarray, record_every: int):
    """Run the rig `spec` on the compiled plugin with one row of `inputs` (the instance's
    channels) per step. Returns (record, None) or (record so far, (step, reason))."""
    return _run_batch([spec.compile()], [inputs], record_every, nthread=1)[0]


def _run_batch(models: list[mujoco.MjModel], inputs: list[np.ndarray], record_every: int, *,
              nthread: int = 1) -> list[tuple[np.ndarray, tuple[int, str] | None]]:
    """Runs of rig models of one layout (same sizes) and one length on `mujoco.batch`,
    `nthread` threads, in chunks of `CHUNK_STEPS` (results do not depend on nthread).
    Returns (record, failure) per run, as `_run_plugin`."""
    n = len(inputs[0])
    model = models[0]
    adr = plugin.state_address(model, INSTANCE)
    recorded = slice(adr, adr + REC_ROWS - 1)
    status = adr + plugin.FIELD["status"]
    recs = [np.zeros(_record_shape(n, record_every)) for _ in models]
    failures: list[tuple[int, str] | None] = [None] * len(models)
    sim = mjbatch.Batch(model, len(models), nthread=nthread)
    sim.set_models(models)
    sim.reset(stage=mujoco.mjtStage.mjSTAGE_NONE)
    controls = np.stack(inputs)
    dt = model.opt.timestep
    for start in range(0, n, CHUNK_STEPS):
        termination.check()  # a signal held back while this ran in C acts here
        if termination.stopping() and threading.current_thread() is not threading.main_thread():
            raise termination.Interrupted()  # the main thread is stopping: so is this one
        stop = min(n, start + CHUNK_STEPS)
        out = sim.rollout(stop - start, control=controls[:, start:stop],
                          record=("plugin_state",))["plugin_state"]
        first = -start % record_every
        steps = np.arange(start + first, stop, record_every)
        for i, rec in enumerate(recs):
            if failures[i] is not None:
                continue
            rec[0, steps // record_every] = steps * dt
            rec[1:, steps // record_every] = out[i, first::record_every, recorded].T
            bad = np.flatnonzero(out[i, :, status])
            if bad.size:
                failures[i] = (start + int(bad[0]), state_failure(out[i, bad[0], adr:]))
    return list(zip(recs, failures))


def _run_python(spec: mujoco.MjSpec, inputs: np.ndarray, record_every: int):
    """`_run_plugin` on the Python engine (`wpam_mj.simulation.engine`): the reference."""
    model, muscles = pyengine.python_model(spec)
    (muscle,) = muscles
    data = mujoco.MjData(model)
    n = len(inputs)
    rec = np.zeros(_record_shape(n, record_every))
    channels = muscle.channels
    ctrl, dt = data.ctrl, model.opt.timestep
    status, recorded = plugin.FIELD["status"], len(REC_FIELDS) - 1
    j = 0
    for step in range(n):
        for channel, value in zip(channels, inputs[step]):
            ctrl[channel] = value
        pyengine.step(model, data, muscles)
        state = muscle.state(data)
        if state[status]:
            return rec, (step, state_failure(state))
        if step % record_every == 0:
            rec[0, j] = step * dt
            rec[1:, j] = state[:recorded]
            j += 1
    return rec, None
