"""The paper's studies as library calls: many independent runs in, response objects out.

  * `static_study`     open-loop Pi ramps (paper Figs. 8-9), one loop area per load;
                       `compare_presets` does the same for several muscle types (Fig. 3).
  * `step_study`       staircase runs (Figs. 12-15) with their plateau means (Fig. 16).
  * `table2`           everything Table 2 needs, normalized as in the paper.
  * `sweep`            sinusoidal targets over loads, frequencies and controllers (Figs. 17-19).

Each run is a small picklable task object, run by the execution layer
(`wpam_mj.simulation.execution.execute`) here or on a cluster; tasks reduce their runs to
response objects (`wpam_mj.experiments.responses`) and keep only the time series that a
figure needs. `*_batch` gives a study's tasks to run together with other studies'.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable, Sequence

import numpy as np

from wpam_mj.experiments.analysis import frequency_response, loop_area, steady_state_means
from wpam_mj.control.controllers import check_control
from wpam_mj.experiments.feasibility import load_moved
from wpam_mj.experiments.drives import (STATIC_RAMP_S, SineSpec, check_po, sine_plan, static_plan,
                                        step_plan)
from wpam_mj.simulation.context import StudyContext, check_dt, check_load
from wpam_mj.paper import (FIG18_FREQ_HZ, FIG18_LOAD_N, LOADS_N, PO_DOWN_STATIC_MPA,
                           SINE_AMPLITUDE_MM, STEP_HOLD_S, STEP_LEVELS_MM, SWEEP_CONTROLLERS,
                           SWEEP_FREQS_HZ)
from wpam_mj.physics.params import Params
from wpam_mj.errors import ParameterError, check_range
from wpam_mj.units import MM, MPA
from wpam_mj.simulation.execution import Batch, SimulationTask, execute
from wpam_mj.simulation.results import SimResult
from wpam_mj.experiments.responses import (LOOP_METHOD, StaticLoop, StepRun, SweepKey, SweepPoint,
                                   SweepResult, Table2Result)

RAMP_TIME_RANGE_S = (1.0, 3600.0)  # what `experiments.static_loop` accepts
PLATEAU_SETTLE_S = 5.0  # our choice: average the last half of each 10 s plateau (Fig. 16)


@dataclass(frozen=True)
class StaticTask(SimulationTask):
    params: Params
    load: float
    po_down: float
    dt: float
    ramp_time: float = STATIC_RAMP_S  # s, each direction

    @property
    def cost(self) -> float:
        return 2.0 * self.ramp_time / self.dt

    def runs(self):
        return [static_plan(self.params, self.load, po_down=self.po_down, dt=self.dt,
                            ramp_time=self.ramp_time)]

    def reduce(self, results: list[SimResult]) -> StaticLoop:
        (r,) = results
        return StaticLoop(po_down=self.po_down, area=loop_area(r.pi, r.x, method=LOOP_METHOD),
                          result=r)


def _check_loads(loads: Iterable[float]) -> tuple[float, ...]:
    loads = tuple(check_load(v) for v in loads)
    if not loads:
        raise ParameterError("no loads given")
    return loads


def check_ramp_time(ramp_time: float) -> float:
    """Duration of each static ramp [s] (the paper does not state its own)."""
    return check_range("ramp_time", ramp_time, *RAMP_TIME_RANGE_S, "s")


def static_study(params: Params, loads: Iterable[float] = LOADS_N,
                 po_down: float = 0.0, *, dt: float = 1e-3, jobs: int = 1,
                 progress: bool = False, ramp_time: float = STATIC_RAMP_S) -> list[StaticLoop]:
    """Open-loop static characteristic at each load [N]; Po = `po_down` [Pa] while Pi falls;
    each ramp (up, then down) lasts `ramp_time` [s]."""
    return compare_presets([params], loads, po_down, dt=dt, jobs=jobs, progress=progress,
                           ramp_time=ramp_time)


def compare_presets(params_list: Sequence[Params], loads: Iterable[float] = (100.0,),
                    po_down: float = 0.0, *, dt: float = 1e-3, jobs: int = 1,
                    progress: bool = False,
                    ramp_time: float = STATIC_RAMP_S) -> list[StaticLoop]:
    """`static_study` for several parameter sets (e.g. muscle presets), params-major order."""
    loads, dt, ramp_time = _check_loads(loads), check_dt(dt), check_ramp_time(ramp_time)
    tasks = [StaticTask(p, load, check_po("po_down", po_down, p), dt, ramp_time)
             for p in params_list for load in loads]
    return execute(tasks, jobs, progress=progress, desc="static")


def plateau_segments(levels_mm: Sequence[float] = STEP_LEVELS_MM,
                     hold: float = STEP_HOLD_S) -> np.ndarray:
    """Plateau spans [s], shape (len(levels), 2), of the staircase target."""
    starts = np.arange(len(levels_mm)) * hold
    return np.column_stack([starts, starts + hold])


@dataclass(frozen=True)
class StepTask(SimulationTask):
    params: Params
    load: float
    control: str
    dt: float

    @property
    def cost(self) -> float:
        return len(STEP_LEVELS_MM) * STEP_HOLD_S / self.dt

    def runs(self):
        return [step_plan(self.params, self.load, self.control, dt=self.dt)]

    def reduce(self, results: list[SimResult]) -> StepRun:
        (r,) = results
        seg = plateau_segments()
        means = {name: steady_state_means(r.time, getattr(r, name), seg, PLATEAU_SETTLE_S)
                 for name in ("x", "pi", "po")}
        return StepRun(settle=PLATEAU_SETTLE_S,
                       target=np.asarray(STEP_LEVELS_MM, dtype=float) * MM,
                       x_mean=means["x"], pi_mean=means["pi"], po_mean=means["po"], result=r)


def step_study(params: Params, runs: Iterable[tuple[float, str]], *, dt: float = 1e-3,
               jobs: int = 1, progress: bool = False) -> list[StepRun]:
    """Staircase runs for each (load [N], control) pair, in the order given."""
    dt = check_dt(dt)
    tasks = [StepTask(params, check_load(load), check_control(control), dt)
             for load, control in runs]
    if not tasks:
        raise ParameterError("no step runs requested")
    return execute(tasks, jobs, progress=progress, desc="step")


def table2(params: Params, *, loads: Iterable[float] = LOADS_N,
           po_down: float = PO_DOWN_STATIC_MPA * MPA, dt: float = 1e-3, jobs: int = 1,
           progress: bool = False, ramp_time: float = STATIC_RAMP_S) -> Table2Result:
    """Run the open-loop ramps (Po = 0 and Po = `po_down` [Pa], each direction lasting
    `ramp_time` [s]) and the PI staircase at each load [N], and compute the Table 2 areas."""
    batch = _table2_batch(params, loads=loads, po_down=po_down, dt=dt, ramp_time=ramp_time)
    return execute([batch], jobs, progress=progress, desc="table 2")[0]


def _table2_batch(params: Params, *, loads: Iterable[float] = LOADS_N,
                 po_down: float = PO_DOWN_STATIC_MPA * MPA, dt: float = 1e-3,
                 ramp_time: float = STATIC_RAMP_S) -> Batch:
    """The runs of `table2` as a `Batch` (to run together with other studies)."""
    loads, ramp_time = _check_loads(loads), check_ramp_time(ramp_time)
    context = StudyContext(params, dt)  # dt checked here, once for the study
    dt, po_down = context.dt, check_po("po_down", po_down, params)
    tasks = ([StaticTask(params, load, 0.0, dt, ramp_time) for load in loads]
             + [StaticTask(params, load, po_down, dt, ramp_time) for load in loads]
             + [StepTask(params, load, "pi", dt) for load in loads])

    def assemble(res: list) -> Table2Result:
        n = len(loads)
        open_loops, po_loops, fb = tuple(res[:n]), tuple(res[n:2 * n]), tuple(res[2 * n:])
        for o in open_loops:
            if not o.area > 0.0:
                raise ParameterError(f"the open-loop Po = 0 loop at {o.load:g} N has no "
                                     "area; cannot normalize Table 2 (is there friction?)")
        return Table2Result(loads=loads, po_down=po_down, open_loops=open_loops,
                            po_loops=po_loops, feedback_runs=fb, context=context)
    return Batch(tasks, assemble)


@dataclass(frozen=True)
class SineTask(SimulationTask):
    params: Params
    load: float
    controller: str
    freq: float
    dt: float
    keep: bool  # send the time series back (for a figure)
    amplitude: float = SINE_AMPLITUDE_MM * MM  # m

    @property
    def cost(self) -> float:
        return SineSpec(self.freq).duration / self.dt

    def runs(self):
        spec = SineSpec(self.freq, amplitude=self.amplitude)
        return [sine_plan(self.params, self.load, self.controller, spec, dt=self.dt)]

    def reduce(self, results: list[SimResult]) -> tuple[SweepPoint, SimResult | None]:
        spec = SineSpec(self.freq, amplitude=self.amplitude)
        (r,) = results
        fr = frequency_response(r.time, r.x_ref, r.x, self.freq,
                                settle_cycles=spec.settle_cycles, n_cycles=spec.cycles)
        window = spec.analysed(r.time)
        point = SweepPoint(load=self.load, freq=self.freq, controller=self.controller,
                           gain=fr.gain, phase_lag_deg=fr.phase_lag_deg,
                           po_max=float(r.po_reg[window].max()),
                           po_chamber_max=float(r.po[window].max()),
                           po_cmd_max=float(r.po_cmd[window].max()),
                           load_moved=load_moved(r, window))
        return point, (r if self.keep else None)


def figure_run_key(loads: Sequence[float], freqs: Sequence[float],
                   controllers: Sequence[str]) -> SweepKey:
    """The run shown as a time series (paper Figs. 18-19: 150 N, 0.5 Hz, PI), or the
    nearest one the sweep has: highest load, frequency closest to 0.5 Hz, PI if swept."""
    load = FIG18_LOAD_N if FIG18_LOAD_N in loads else max(loads)
    freq = min(freqs, key=lambda f: (abs(f - FIG18_FREQ_HZ), f))
    ctrl = "pi" if "pi" in controllers else controllers[0]
    return load, freq, ctrl


def sweep(params: Params, loads: Iterable[float] = LOADS_N,
          freqs: Iterable[float] = SWEEP_FREQS_HZ,
          controllers: Iterable[str] = SWEEP_CONTROLLERS, *, keep: Iterable[SweepKey] | None = None,
          dt: float = 1e-3, jobs: int = 1, progress: bool = False,
          amplitude: float = SINE_AMPLITUDE_MM * MM) -> SweepResult:
    """Sinusoidal-target runs (`amplitude` [m], default 25 mm, about 25 mm, `SineSpec`)
    for every combination.

    Args:
      loads: hanging loads [N]; freqs: target frequencies [Hz]; controllers: "pi", "pid"
        (or "open").
      keep: (load, freq, controller) runs whose time series to return; default: the
        `figure_run_key` run.
    """
    batch = sweep_batch(params, loads, freqs, controllers, keep=keep, dt=dt,
                        amplitude=amplitude)
    return execute([batch], jobs, progress=progress, desc="sweep")[0]


def sweep_batch(params: Params, loads: Iterable[float] = LOADS_N,
                freqs: Iterable[float] = SWEEP_FREQS_HZ,
                controllers: Iterable[str] = SWEEP_CONTROLLERS, *,
                keep: Iterable[SweepKey] | None = None, dt: float = 1e-3,
                amplitude: float = SINE_AMPLITUDE_MM * MM) -> Batch:
    """The runs of `sweep` as a `Batch` (to run together with other studies)."""
    loads = _check_loads(loads)
    context = StudyContext(params, dt)  # dt checked here, once for the study
    dt = context.dt
    freqs = tuple(SineSpec(f, amplitude=amplitude).freq for f in freqs)  # validates each
    controllers = tuple(check_control(c) for c in controllers)
    if not freqs or not controllers:
        raise ParameterError("sweep needs at least one frequency and one controller")
    keep = {figure_run_key(loads, freqs, controllers)} if keep is None else set(keep)
    tasks = [SineTask(params, load, c, f, dt, (load, f, c) in keep, amplitude)
             for load in loads for c in controllers for f in freqs]

    def assemble(res: list) -> SweepResult:
        series = {(p.load, p.freq, p.controller): r for p, r in res if r is not None}
        return SweepResult(points=tuple(p for p, _ in res), context=context, series=series,
                           amplitude=amplitude)
    return Batch(tasks, assemble)
