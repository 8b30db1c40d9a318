"""The paper's experiments as protocols: commands in, `SimResult` out (no plotting here).

  * `static_loop`   slow Pi ramp up then down, open loop; Po = 0 or a constant Po while
                    Pi falls (paper §2.3, Figs. 8-9).
  * `step_run`      target 0 -> 50 mm in 10-mm steps of 10 s, then back to 0, open loop or
                    Po feedback (§4.1, Figs. 12-15).
  * `sine_run`      sinusoidal target, 25 mm amplitude about a 25 mm mean (§4.2, Figs. 17-19).
  * `simulate_for_render`  one of them cut to a video's length (`wpam render`).

Targets and pressures are SI; the defaults carry the paper's values in its units
(`wpam_mj.paper`).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from wpam_mj.infra.budget import MAX_RUN_S, check_duration, check_run
from wpam_mj.control.controllers import CONTROLLERS, check_control
from wpam_mj.display import fmt
from wpam_mj.experiments.feasibility import check_liftable
from wpam_mj.physics.geometry import BraidGeometry
from wpam_mj.simulation.context import RunContext
from wpam_mj.physics.muscle import MuscleModel
from wpam_mj.paper import SINE_AMPLITUDE_MM, STEP_HOLD_S, STEP_LEVELS_MM
from wpam_mj.physics.params import Params
from wpam_mj.errors import ParameterError, check_range, shown
from wpam_mj.units import MM, MPA
from wpam_mj.simulation.results import SimResult
from wpam_mj.simulation.simulate import Drive, Run, simulate_run

EXPERIMENTS = ("step", "sweep", "static")  # what `simulate_for_render` can run
SINE_MEAN_MM = 25.0  # our choice: the target spans 0-50 mm, the range of the step runs
STATIC_TOP_MM = float(max(STEP_LEVELS_MM))  # ramp until the contracting branch reaches the
# step runs' top target (our choice)
STATIC_RAMP_S = 60.0  # our choice: "slow" (near quasi-static), each direction


def check_po(name: str, po: float, params: Params) -> float:
    """A Po setting [Pa]: 0 (vented) or within the regulator range."""
    if po == 0.0:
        return 0.0
    pn = params.pneumatics
    return check_range(name, po / MPA, pn.p_min / MPA, pn.p_max / MPA, "MPa") * MPA


def _steps(what: str, duration: float, dt: float, record_dt: float) -> tuple[int, np.ndarray]:
    """The physics steps of a run of `duration` [s], within the budget of one run."""
    check_run(what, duration, dt, record_dt)
    n = int(round(duration / dt)) + 1
    return n, np.arange(n) * dt


def static_top_pressure(params: Params, load: float, x_top: float = STATIC_TOP_MM * MM) -> float:
    """Pi [Pa] at which the contracting branch (paper eq. 5) reaches `x_top` [m]."""
    pi_top = MuscleModel.from_params(params).equilibrium_pressure(x_top, load, 0.0, +1)
    return min(pi_top, params.pneumatics.p_max)


def static_loop(params: Params, load: float, *, po_down: float = 0.0,
                pi_top: float | None = None, ramp_time: float = STATIC_RAMP_S,
                dt: float = 1e-3, record_dt: float = 0.01, engine: str = "auto") -> SimResult:
    """Open-loop Pi ramp p_min -> pi_top -> p_min with Po = 0 rising, `po_down` falling
    (`static_plan`, simulated on `engine`)."""
    return simulate_run(static_plan(params, load, po_down=po_down, pi_top=pi_top,
                                    ramp_time=ramp_time, dt=dt, record_dt=record_dt), engine)


def static_plan(params: Params, load: float, *, po_down: float = 0.0,
                pi_top: float | None = None, ramp_time: float = STATIC_RAMP_S,
                dt: float = 1e-3, record_dt: float = 0.01) -> Run:
    """The run of `static_loop`, validated and built, not yet simulated.

    Args:
      load: hanging load [N].
      po_down: constant Po while Pi decreases [Pa] (0 = vented, paper Fig. 8).
      pi_top: top of the ramp [Pa]; default: the Pi whose contracting-branch equilibrium
        is 50 mm for this load, so every load sweeps the working range of the step runs.
      ramp_time: duration of each ramp [s]. A 1 s dwell at each end lets the state settle.
    """
    context = RunContext(params, dt, load, "open", record_dt)  # load and dt checked here
    load, dt = context.load, context.dt
    po_down = check_po("po_down", po_down, params)
    p_min = params.pneumatics.p_min
    pi_top = static_top_pressure(params, load) if pi_top is None else \
        check_po("pi_top", pi_top, params)
    check_range("ramp_time", ramp_time, 1.0, 3600.0, "s")
    dwell = 1.0
    n, t = _steps(f"a static loop of {ramp_time:g} s ramps", 2 * dwell + 2 * ramp_time, dt,
                  record_dt)
    knots_t = [0.0, dwell, dwell + ramp_time, dwell + 2 * ramp_time, 2 * dwell + 2 * ramp_time]
    pi_cmd = np.interp(t, knots_t, [p_min, p_min, pi_top, p_min, p_min])
    po_cmd = np.where(t > dwell + ramp_time, po_down, 0.0)
    drive = Drive(pi_cmd=pi_cmd, po_cmd=po_cmd, x_ref=np.full(n, np.nan))
    return Run.make(context, drive)


def check_targets(params: Params, load: float, lo: float, hi: float, what: str) -> None:
    """Targets spanning [lo, hi] [m] must lie within the braid's stroke, and the muscle
    must lift `load` [N] to the highest of them (else the run reports numbers of a load
    that sits where it hangs: `wpam_mj.experiments.feasibility`)."""
    stroke = BraidGeometry.from_params(params.braid).max_contraction
    if not 0.0 <= lo <= hi <= stroke:
        raise ParameterError(f"{what} spans [{fmt(lo / MM, 'g')}, {fmt(hi / MM, 'g')}] mm; "
                             f"targets must lie in the stroke [0, {stroke / MM:.1f}] mm")
    check_liftable(params, (load,), "load", x=hi)


def step_targets(t: np.ndarray, levels_mm=STEP_LEVELS_MM, hold: float = STEP_HOLD_S) -> np.ndarray:
    """Staircase target x_r(t) [m] for times t [s]."""
    idx = np.minimum((t / hold).astype(int), len(levels_mm) - 1)
    return np.asarray(levels_mm, dtype=float)[idx] * MM


def drive_for_targets(params: Params, load: float, x_ref: np.ndarray, control: str,
                      dt: float) -> Drive:
    """The controller's feedforward for the target x_ref [m] sampled every dt [s]
    (`PoController.feedforward`): for the paper's controllers, Pi from the mechanical
    equilibrium model, Po fed back (or 0 in open loop).

    Feedback runs assume Po = po_feedforward (with less Po the muscle over-contracts,
    paper §4.1) and start with the feedback holding that Po (`wpam_mj.control.controllers`); the
    open-loop run assumes Po = 0, the only Po it has (paper Fig. 12). The rig starts at
    rest at the first target: regulators and chambers already at the first commands, as
    the feedback's bumpless start assumes. From vented chambers the small inner bag fills
    faster than the outer bag's litre, and the muscle would start over-contracted by up to
    2 mm at its stop, a start-up transient the plateau errors would then carry.
    """
    pi_cmd, po_cmd = CONTROLLERS[check_control(control)].feedforward(params, load, x_ref, dt)
    return Drive(pi_cmd=pi_cmd, po_cmd=po_cmd, x_ref=x_ref, start_at_rest=True)


def step_run(params: Params, load: float, control: str, *, levels_mm=STEP_LEVELS_MM,
             hold: float = STEP_HOLD_S, dt: float = 1e-3, record_dt: float = 0.01,
             engine: str = "auto") -> SimResult:
    """Staircase target (paper §4.1): open loop or PI/PID on Po (`step_plan`, simulated
    on `engine`)."""
    return simulate_run(step_plan(params, load, control, levels_mm=levels_mm, hold=hold,
                                  dt=dt, record_dt=record_dt), engine)


def step_plan(params: Params, load: float, control: str, *, levels_mm=STEP_LEVELS_MM,
              hold: float = STEP_HOLD_S, dt: float = 1e-3, record_dt: float = 0.01) -> Run:
    """The run of `step_run`, validated and built, not yet simulated."""
    context = RunContext(params, dt, load, control, record_dt)  # load and dt checked here
    load, dt, control = context.load, context.dt, check_control(control)
    hold = check_range("hold", hold, 0.0, 3600.0, "s", lo_open=True)
    if len(levels_mm) < 1:
        raise ParameterError("levels_mm is empty: a step run needs at least one target")
    levels = np.asarray(levels_mm, dtype=float) * MM
    check_targets(params, load, float(levels.min()), float(levels.max()), "levels_mm")
    n, t = _steps(f"a staircase of {len(levels_mm)} levels of {hold:g} s",
                  len(levels_mm) * hold - dt, dt, record_dt)
    x_ref = step_targets(t, levels_mm, hold)
    return Run.make(context, drive_for_targets(params, load, x_ref, control, dt))


@dataclass(frozen=True)
class SineSpec:
    """Sinusoidal target x_r = mean - amplitude cos(2 pi f t) (starts at rest at 0 mm)."""

    freq: float  # Hz
    amplitude: float = SINE_AMPLITUDE_MM * MM  # m
    mean: float = SINE_MEAN_MM * MM  # m
    settle_cycles: int = 4
    cycles: int = 3  # analysed cycles after settling

    def __post_init__(self) -> None:
        check_range("freq", self.freq, 0.0, 20.0, "Hz", lo_open=True)
        check_range("amplitude", self.amplitude / MM, 0.0, 100.0, "mm", lo_open=True)
        check_range("mean", self.mean / MM, 0.0, 100.0, "mm")
        for name, lo in (("settle_cycles", 0), ("cycles", 1)):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < lo:
                raise ParameterError(f"{name} = {shown(value)} must be an integer >= {lo}")
        cycles = self.settle_cycles + self.cycles
        check_duration(f"a sine at {self.freq:g} Hz ({cycles} cycles)", self.duration,
                       f"the lowest frequency allowed is {cycles / MAX_RUN_S:g} Hz")

    @property
    def duration(self) -> float:
        return (self.settle_cycles + self.cycles) / self.freq

    def analysed(self, time: np.ndarray) -> np.ndarray:
        """Mask of the samples at `time` [s] (starting at 0) in the analysed cycles."""
        t0 = time[0] + self.settle_cycles / self.freq
        t1 = t0 + self.cycles / self.freq
        eps = 1e-9 * t1  # sample times are k dt: keep the window's ends exact
        return (time >= t0 - eps) & (time < t1 - eps)

    def target(self, t: np.ndarray) -> np.ndarray:
        return self.mean - self.amplitude * np.cos(2.0 * math.pi * self.freq * t)


def sine_run(params: Params, load: float, control: str, spec: SineSpec, *,
             dt: float = 1e-3, record_dt: float = 0.01, engine: str = "auto") -> SimResult:
    """Sinusoidal target (paper §4.2) under PI/PID on Po (or open loop) (`sine_plan`,
    simulated on `engine`)."""
    return simulate_run(sine_plan(params, load, control, spec, dt=dt, record_dt=record_dt),
                        engine)


def sine_plan(params: Params, load: float, control: str, spec: SineSpec, *,
              dt: float = 1e-3, record_dt: float = 0.01) -> Run:
    """The run of `sine_run`, validated and built, not yet simulated."""
    context = RunContext(params, dt, load, control, record_dt)  # load and dt checked here
    load, dt, control = context.load, context.dt, check_control(control)
    check_targets(params, load, spec.mean - spec.amplitude, spec.mean + spec.amplitude,
                  "the sine's target")
    n, t = _steps(f"a sine at {spec.freq:g} Hz", spec.duration, dt, record_dt)
    x_ref = spec.target(t)
    return Run.make(context, drive_for_targets(params, load, x_ref, control, dt))


def simulate_for_render(params: Params, load: float, experiment: str, control: str,
                        spec: SineSpec, duration: float | None, dt: float) -> SimResult:
    """Run `experiment` for at least `duration` [s] (when it can be shortened) and
    truncate the result to `duration` (None: the whole run)."""
    if experiment == "step":
        levels = STEP_LEVELS_MM if duration is None else \
            STEP_LEVELS_MM[:max(1, math.ceil(duration / STEP_HOLD_S))]
        result = step_run(params, load, control, levels_mm=levels, dt=dt)
    elif experiment == "sweep":
        if duration is not None:  # as many cycles as the video shows, from rest
            spec = dataclasses.replace(spec, settle_cycles=0,
                                       cycles=max(1, math.ceil(duration * spec.freq)))
        result = sine_run(params, load, control, spec, dt=dt)
    elif experiment == "static":
        result = static_loop(params, load, dt=dt)
    else:
        raise ParameterError(f"unknown experiment {experiment!r}; valid: "
                             + ", ".join(EXPERIMENTS))
    if duration is not None:
        keep = result.time <= duration + 1e-9
        result = dataclasses.replace(result, **{k: v[keep]
                                                for k, v in result.arrays().items()})
    return result
