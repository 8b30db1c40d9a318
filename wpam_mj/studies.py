"""The paper's studies as library calls: many independent runs in, response objects out.

  * `static_study`     open-loop Pi ramps (paper Figs. 8-9), one loop area per load;
                       `compare_presets` does the same for several muscle types (Fig. 3).
  * `step_study`       staircase runs (Figs. 12-15) with their plateau means (Fig. 16).
  * `table2`           everything Table 2 needs, normalized as in the paper.
  * `sweep`            sinusoidal targets over loads, frequencies and controllers (Figs. 17-19).

Independent runs are small picklable task objects; a `TaskPool` (or `run_tasks`) runs
them serially (jobs = 1) or in a `ProcessPoolExecutor`, with results in task order. Every
run is deterministic, so the results do not depend on `jobs`. Workers send back reduced
results and only the time series that a figure needs.

SI inside (m, Pa, N, s; frequency in Hz as in `SineSpec`); loop areas are in Pa m (the
normalized Table 2 values are unit-free). No plotting here: the `.plot()` methods of
the response objects call `wpam_mj.plots`.
"""

from __future__ import annotations

import math
import os
import sys
from concurrent.futures import FIRST_EXCEPTION, Executor, Future, ProcessPoolExecutor, wait
from dataclasses import dataclass, field
from typing import Callable, Iterable, Mapping, Sequence

import numpy as np
from tqdm import tqdm

from wpam_mj.analysis import frequency_response, loop_area, steady_state_means
from wpam_mj.experiments import (PO_DOWN_STATIC_MPA, STATIC_RAMP_S, STEP_HOLD_S,
                                 STEP_LEVELS_MM, SineSpec, check_po,
                                 sine_run, static_loop, step_run)
from wpam_mj.control import check_control
from wpam_mj.model import check_dt, check_load
from wpam_mj.params import MM, MPA, Params, ParameterError
from wpam_mj.results import SimResult

PAPER_LOADS_N = (50.0, 100.0, 150.0)  # paper §2.3, §4
PAPER_FREQS_HZ = (0.1, 0.2, 0.25, 0.5, 1.0)  # paper §4.2
PAPER_CONTROLLERS = ("pi", "pid")  # paper §4.2
FIG18_LOAD_N = 150.0  # paper Figs. 18-19
FIG18_FREQ_HZ = 0.5  # paper Figs. 18-19
PLATEAU_SETTLE_S = 5.0  # our choice: average the last half of each 10 s plateau (Fig. 16)
LOOP_METHOD = "branches"  # one loop-area method for every Table 2 cell

# Paper Table 2: hysteresis-loop areas normalized by the open-loop, Po = 0 area per load.
PAPER_TABLE2 = {
    "open": {50.0: 1.0, 100.0: 1.0, 150.0: 1.0},
    "open_po": {50.0: 0.7042, 100.0: 0.1899, 150.0: 0.0638},
    "feedback": {50.0: 0.0008, 100.0: 0.0019, 150.0: 0.0170},
}
PAPER_TABLE2_SOURCE = "Saito, Satoh & Saga, Actuators 2024, 13, 282, Table 2"


def load_key(load: float) -> str:
    """JSON/CSV key of a load [N]: "50", "100", "112.5"."""
    return f"{load:g}"


def check_jobs(jobs: int) -> int:
    """Process-pool size: an integer >= 1."""
    if isinstance(jobs, bool) or not isinstance(jobs, (int, np.integer)) or jobs < 1:
        raise ParameterError(f"jobs = {jobs!r} must be an integer >= 1")
    return int(jobs)


def default_jobs() -> int:
    return os.cpu_count() or 1


# ------------------------------------------------------------------ running tasks


def _execute(task):
    """Worker entry point (module level, so the pool can pickle it)."""
    return task.run()


class TaskPool:
    """Runs task objects (`.run()`, `.cost`) in this process or in one process pool.

    jobs = 1 runs each task as it is submitted; jobs > 1 starts a pool (default start
    method) and queues each submitted group longest first. Tasks submitted after others
    queue behind them, so follow-up work (figures of finished runs) keeps the cores busy
    without a second pool. The first failure cancels every task not yet started and is
    re-raised (by `submit` when jobs = 1, else by `results`). Use as a context manager.
    `executor`: any concurrent.futures.Executor (e.g. Dask's, `wpam_mj.executors`) to
    run on instead of a pool of its own, whatever `jobs` is; the caller shuts it down.
    """

    def __init__(self, jobs: int = 1, *, progress: bool = False, desc: str = "runs",
                 executor: Executor | None = None) -> None:
        self.jobs = check_jobs(jobs)
        self._executor = executor
        self._pool: ProcessPoolExecutor | None = None
        self._submitted: list[Future] = []
        self._bar = tqdm(total=0, desc=desc, unit="run", file=sys.stderr,
                         disable=not progress, leave=False)

    def __enter__(self) -> TaskPool:
        return self

    def __exit__(self, *exc) -> None:
        for fut in self._submitted:
            fut.cancel()
        if self._pool is not None:
            self._pool.shutdown(wait=True)
        self._bar.close()

    def submit(self, tasks: Sequence) -> list[Future]:
        """Futures of `task.run()` for each task, in task order."""
        tasks = list(tasks)
        self._bar.total += len(tasks)
        self._bar.refresh()
        futures: list[Future | None] = [None] * len(tasks)
        if self.jobs == 1 and self._executor is None:  # a failure propagates at once
            for i, task in enumerate(tasks):
                futures[i] = Future()
                futures[i].set_result(task.run())
                self._bar.update()
            return futures
        if self._pool is None and self._executor is None:
            self._pool = ProcessPoolExecutor(max_workers=self.jobs)
        pool = self._pool if self._executor is None else self._executor
        for i in sorted(range(len(tasks)), key=lambda i: -tasks[i].cost):
            futures[i] = fut = pool.submit(_execute, tasks[i])
            fut.add_done_callback(lambda _: self._bar.update())
        self._submitted += futures
        return futures

    def results(self, futures: Sequence[Future]) -> list:
        """The results of `futures` (from `submit`), in order; raises the first failure."""
        done, _ = wait(futures, return_when=FIRST_EXCEPTION)
        for fut in done:
            if fut.exception() is not None:
                for other in self._submitted:
                    other.cancel()
                raise fut.exception()
        return [fut.result() for fut in futures]

    def run(self, tasks: Sequence) -> list:
        """`submit` then `results`."""
        return self.results(self.submit(tasks))


def run_tasks(tasks: Sequence, *, jobs: int = 1, progress: bool = False,
              desc: str = "runs", executor: Executor | None = None) -> list:
    """Run `task.run()` for every task (see `TaskPool`); results in task order."""
    with TaskPool(jobs, progress=progress, desc=desc, executor=executor) as pool:
        return pool.run(tasks)


@dataclass(frozen=True)
class Batch:
    """Tasks of one study and the function that turns their results into its response."""

    tasks: Sequence
    assemble: Callable[[list], object]


def submit_batches(pool: TaskPool, batches: Sequence[Batch]) -> list[Callable[[], object]]:
    """Submit the tasks of several studies at once (longest first across all of them, so
    they balance each other on few cores); returns one callable per study that waits for
    its runs and returns its assembled response."""
    futures = pool.submit([t for b in batches for t in b.tasks])
    out, start = [], 0
    for b in batches:
        mine = futures[start:start + len(b.tasks)]
        out.append(lambda b=b, mine=mine: b.assemble(pool.results(mine)))
        start += len(b.tasks)
    return out


def run_batches(batches: Sequence[Batch], *, jobs: int = 1, progress: bool = False,
                desc: str = "runs", executor: Executor | None = None) -> list:
    """Run the tasks of several studies in one pool and return each study's assembled
    response, in the order given."""
    with TaskPool(jobs, progress=progress, desc=desc, executor=executor) as pool:
        return [response() for response in submit_batches(pool, batches)]


# ------------------------------------------------------------------ static loops


@dataclass(frozen=True)
class StaticLoop:
    """One open-loop Pi ramp up then down (paper Figs. 3, 8, 9).

    load [N]; po_down: Po while Pi falls [Pa]; preset: muscle type;
    area: loop area of the measured (Pi, x) trace [Pa m]; result: the run.
    """

    load: float
    po_down: float
    preset: str
    area: float
    result: SimResult

    @property
    def area_mpa_mm(self) -> float:
        return self.area / (MPA * MM)

    def plot(self):
        """x against Pi with direction arrows (`wpam_mj.plots.static_figure`)."""
        from wpam_mj import plots  # noqa: PLC0415 (matplotlib only when plotting)
        return plots.static_figure([self])


@dataclass(frozen=True)
class StaticTask:
    params: Params
    load: float
    po_down: float
    dt: float

    @property
    def cost(self) -> float:
        return 2.0 * STATIC_RAMP_S / self.dt

    def run(self) -> StaticLoop:
        r = static_loop(self.params, self.load, po_down=self.po_down, dt=self.dt)
        return StaticLoop(load=self.load, po_down=self.po_down, preset=self.params.preset,
                          area=loop_area(r.pi, r.x, method=LOOP_METHOD), result=r)


def _check_loads(loads: Iterable[float]) -> tuple[float, ...]:
    loads = tuple(check_load(v) for v in loads)
    if not loads:
        raise ParameterError("no loads given")
    return loads


def static_study(params: Params, loads: Iterable[float] = PAPER_LOADS_N,
                 po_down: float = 0.0, *, dt: float = 1e-3, jobs: int = 1,
                 progress: bool = False) -> list[StaticLoop]:
    """Open-loop static characteristic at each load [N]; Po = `po_down` [Pa] while Pi falls."""
    return compare_presets([params], loads, po_down, dt=dt, jobs=jobs, progress=progress)


def compare_presets(params_list: Sequence[Params], loads: Iterable[float] = (100.0,),
                    po_down: float = 0.0, *, dt: float = 1e-3, jobs: int = 1,
                    progress: bool = False) -> list[StaticLoop]:
    """`static_study` for several parameter sets (e.g. muscle presets), params-major order."""
    loads, dt = _check_loads(loads), check_dt(dt)
    tasks = [StaticTask(p, load, check_po("po_down", po_down, p), dt)
             for p in params_list for load in loads]
    return run_tasks(tasks, jobs=jobs, progress=progress, desc="static")


# ------------------------------------------------------------------ step runs


def plateau_segments(levels_mm: Sequence[float] = STEP_LEVELS_MM,
                     hold: float = STEP_HOLD_S) -> np.ndarray:
    """Plateau spans [s], shape (len(levels), 2), of the staircase target."""
    starts = np.arange(len(levels_mm)) * hold
    return np.column_stack([starts, starts + hold])


@dataclass(frozen=True)
class StepRun:
    """A staircase run (paper Figs. 12-15) and its settled plateau means (Fig. 16).

    Plateau arrays have shape (n_plateaus,), averaged over the last `settle` seconds of
    each plateau: target [m], x [m], measured chamber Pi and Po [Pa].
    """

    load: float
    control: str
    preset: str
    settle: float
    target: np.ndarray
    x_mean: np.ndarray
    pi_mean: np.ndarray
    po_mean: np.ndarray
    result: SimResult

    @property
    def area(self) -> float:
        """Loop area of the plateau means (Pi, x), up branch then down branch [Pa m]."""
        return loop_area(self.pi_mean, self.x_mean, method=LOOP_METHOD)

    @property
    def error(self) -> np.ndarray:
        """Settled error x - target per plateau [m]."""
        return self.x_mean - self.target

    def worst_error(self, settle: float = 3.0) -> float:
        """Largest |x - x_r| over the last `settle` s of every plateau [m]."""
        r = self.result
        settled = (r.time % STEP_HOLD_S) >= STEP_HOLD_S - settle
        return float(np.max(np.abs(r.x - r.x_ref)[settled]))

    def plot(self):
        """Figure of x, target, Pi and Po against time (`wpam_mj.plots.step_figure`)."""
        from wpam_mj import plots  # noqa: PLC0415 (matplotlib only when plotting)
        return plots.step_figure([self.result])


@dataclass(frozen=True)
class StepTask:
    params: Params
    load: float
    control: str
    dt: float

    @property
    def cost(self) -> float:
        return len(STEP_LEVELS_MM) * STEP_HOLD_S / self.dt

    def run(self) -> StepRun:
        r = step_run(self.params, self.load, self.control, dt=self.dt)
        seg = plateau_segments()
        means = {name: steady_state_means(r.time, getattr(r, name), seg, PLATEAU_SETTLE_S)
                 for name in ("x", "pi", "po")}
        return StepRun(load=self.load, control=self.control, preset=self.params.preset,
                       settle=PLATEAU_SETTLE_S,
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
    return run_tasks(tasks, jobs=jobs, progress=progress, desc="step")


# ------------------------------------------------------------------ Table 2


@dataclass(frozen=True)
class Table2Result:
    """Hysteresis-loop areas behind the paper's Table 2, per load.

    open_loops: open loop, Po = 0 (Fig. 8); po_loops: open loop, Po = `po_down` while Pi
    falls (Fig. 9); feedback_runs: PI staircase runs (Figs. 14-16). Normalized values
    divide each area by the open-loop, Po = 0 area of the same load.
    """

    loads: tuple[float, ...]
    po_down: float
    open_loops: tuple[StaticLoop, ...]
    po_loops: tuple[StaticLoop, ...]
    feedback_runs: tuple[StepRun, ...]

    @property
    def open_po(self) -> dict[float, float]:
        return {o.load: p.area / o.area for o, p in zip(self.open_loops, self.po_loops)}

    @property
    def feedback(self) -> dict[float, float]:
        return {o.load: f.area / o.area for o, f in zip(self.open_loops, self.feedback_runs)}

    def paper(self) -> dict[str, dict[float, float]]:
        """The paper's rows for the loads of this study that the paper has."""
        return {row: {load: v[load] for load in self.loads if load in v}
                for row, v in PAPER_TABLE2.items()}

    def as_json(self) -> dict:
        """{"open_po": {"50": a, ...}, "feedback": {...}, "paper": {...}}."""
        paper: dict = {row: {load_key(k): v for k, v in vals.items()}
                       for row, vals in self.paper().items()}
        paper["po_down_mpa"] = PO_DOWN_STATIC_MPA
        paper["source"] = PAPER_TABLE2_SOURCE
        return {"open_po": {load_key(k): v for k, v in self.open_po.items()},
                "feedback": {load_key(k): v for k, v in self.feedback.items()},
                "paper": paper}

    def plot(self):
        """Bar chart of the normalized areas beside the paper's (`plots.table2_figure`)."""
        from wpam_mj import plots  # noqa: PLC0415 (matplotlib only when plotting)
        return plots.table2_figure(self)

    def rows(self) -> list[dict]:
        """One dict per load: raw areas [MPa mm] and normalized values, ours and paper's."""
        paper = self.paper()
        out = []
        for o, p, f in zip(self.open_loops, self.po_loops, self.feedback_runs):
            out.append({
                "load_n": o.load,
                "open_area_mpa_mm": o.area_mpa_mm,
                "open_po_area_mpa_mm": p.area_mpa_mm,
                "feedback_area_mpa_mm": f.area / (MPA * MM),
                "open_po": p.area / o.area,
                "feedback": f.area / o.area,
                "paper_open_po": paper["open_po"].get(o.load, math.nan),
                "paper_feedback": paper["feedback"].get(o.load, math.nan),
            })
        return out


def table2(params: Params, *, loads: Iterable[float] = PAPER_LOADS_N,
           po_down: float = PO_DOWN_STATIC_MPA * MPA, dt: float = 1e-3, jobs: int = 1,
           progress: bool = False) -> Table2Result:
    """Run the open-loop ramps (Po = 0 and Po = `po_down` [Pa]) and the PI staircase at
    each load [N], and compute the Table 2 areas."""
    batch = table2_batch(params, loads=loads, po_down=po_down, dt=dt)
    return run_batches([batch], jobs=jobs, progress=progress, desc="table 2")[0]


def table2_batch(params: Params, *, loads: Iterable[float] = PAPER_LOADS_N,
                 po_down: float = PO_DOWN_STATIC_MPA * MPA, dt: float = 1e-3) -> Batch:
    """The runs of `table2` as a `Batch` (to share a pool with other studies)."""
    loads, dt = _check_loads(loads), check_dt(dt)
    po_down = check_po("po_down", po_down, params)
    tasks = ([StaticTask(params, load, 0.0, dt) for load in loads]
             + [StaticTask(params, load, po_down, dt) for load in loads]
             + [StepTask(params, load, "pi", dt) for load in loads])

    def assemble(res: list) -> Table2Result:
        n = len(loads)
        open_loops, po_loops, fb = tuple(res[:n]), tuple(res[n:2 * n]), tuple(res[2 * n:])
        for o in open_loops:
            if not o.area > 0.0:
                raise ParameterError(f"the open-loop Po = 0 loop at {o.load:g} N has no "
                                     "area; cannot normalize Table 2 (is there friction?)")
        return Table2Result(loads=loads, po_down=po_down, open_loops=open_loops,
                            po_loops=po_loops, feedback_runs=fb)
    return Batch(tasks, assemble)


# ------------------------------------------------------------------ frequency sweep


@dataclass(frozen=True)
class SweepPoint:
    """Response to a sinusoidal target at one (load, frequency, controller).

    load [N]; freq [Hz]; gain [1]; phase_lag_deg [deg], positive = lag; po_max: highest
    Po read by the regulator's own gauge over the analysed cycles [Pa] (what the paper
    plots, §2.3); po_chamber_max: highest Po inside the outer chamber, behind the line
    restriction [Pa]; po_cmd_max: highest Po command (capped at po_cap) [Pa].
    """

    load: float
    freq: float
    controller: str
    gain: float
    phase_lag_deg: float
    po_max: float
    po_chamber_max: float = float("nan")
    po_cmd_max: float = float("nan")

    def as_json(self) -> dict:
        return {"load_n": self.load, "freq_hz": self.freq, "controller": self.controller,
                "gain": self.gain, "phase_lag_deg": self.phase_lag_deg,
                "po_max_mpa": self.po_max / MPA}


@dataclass(frozen=True)
class SineTask:
    params: Params
    load: float
    controller: str
    freq: float
    dt: float
    keep: bool  # send the time series back (for a figure)

    @property
    def cost(self) -> float:
        return SineSpec(self.freq).duration / self.dt

    def run(self) -> tuple[SweepPoint, SimResult | None]:
        spec = SineSpec(self.freq)
        r = sine_run(self.params, self.load, self.controller, spec, dt=self.dt)
        fr = frequency_response(r.time, r.x_ref, r.x, self.freq,
                                settle_cycles=spec.settle_cycles, n_cycles=spec.cycles)
        t0 = r.time[0] + spec.settle_cycles / self.freq
        t1 = t0 + spec.cycles / self.freq
        eps = 1e-9 * t1
        window = (r.time >= t0 - eps) & (r.time < t1 - eps)
        point = SweepPoint(load=self.load, freq=self.freq, controller=self.controller,
                           gain=fr.gain, phase_lag_deg=fr.phase_lag_deg,
                           po_max=float(r.po_reg[window].max()),
                           po_chamber_max=float(r.po[window].max()),
                           po_cmd_max=float(r.po_cmd[window].max()))
        return point, (r if self.keep else None)


SweepKey = tuple[float, float, str]  # (load [N], freq [Hz], controller)


@dataclass(frozen=True)
class SweepResult:
    """Points in (load, freq, controller) loop order; `series` holds the kept runs."""

    points: tuple[SweepPoint, ...]
    series: Mapping[SweepKey, SimResult] = field(default_factory=dict)

    def as_json(self) -> list[dict]:
        return [p.as_json() for p in self.points]

    def point(self, load: float, freq: float, controller: str) -> SweepPoint | None:
        for p in self.points:
            if p.load == load and p.freq == freq and p.controller == controller:
                return p
        return None

    def curve(self, load: float, controller: str) -> list[SweepPoint]:
        """The points of one (load, controller), by increasing frequency."""
        return sorted((p for p in self.points if p.load == load and
                       p.controller == controller), key=lambda p: p.freq)

    def plot(self):
        """Gain and phase lag against frequency (`wpam_mj.plots.sweep_figure`)."""
        from wpam_mj import plots  # noqa: PLC0415 (matplotlib only when plotting)
        return plots.sweep_figure(self)

    @property
    def loads(self) -> list[float]:
        return sorted({p.load for p in self.points})

    @property
    def freqs(self) -> list[float]:
        return sorted({p.freq for p in self.points})

    @property
    def controllers(self) -> list[str]:
        return list(dict.fromkeys(p.controller for p in self.points))


def figure_run_key(loads: Sequence[float], freqs: Sequence[float],
                   controllers: Sequence[str]) -> SweepKey:
    """The run shown as a time series (paper Figs. 18-19: 150 N, 0.5 Hz, PI), or the
    nearest one the sweep has: highest load, frequency closest to 0.5 Hz, PI if swept."""
    load = FIG18_LOAD_N if FIG18_LOAD_N in loads else max(loads)
    freq = min(freqs, key=lambda f: (abs(f - FIG18_FREQ_HZ), f))
    ctrl = "pi" if "pi" in controllers else controllers[0]
    return load, freq, ctrl


def sweep(params: Params, loads: Iterable[float] = PAPER_LOADS_N,
          freqs: Iterable[float] = PAPER_FREQS_HZ,
          controllers: Iterable[str] = PAPER_CONTROLLERS, *, keep: Iterable[SweepKey] | None = None,
          dt: float = 1e-3, jobs: int = 1, progress: bool = False) -> SweepResult:
    """Sinusoidal-target runs (25 mm about 25 mm, `SineSpec`) for every combination.

    Args:
      loads: hanging loads [N]; freqs: target frequencies [Hz]; controllers: "pi", "pid"
        (or "open").
      keep: (load, freq, controller) runs whose time series to return; default: the
        `figure_run_key` run.
    """
    batch = sweep_batch(params, loads, freqs, controllers, keep=keep, dt=dt)
    return run_batches([batch], jobs=jobs, progress=progress, desc="sweep")[0]


def sweep_batch(params: Params, loads: Iterable[float] = PAPER_LOADS_N,
                freqs: Iterable[float] = PAPER_FREQS_HZ,
                controllers: Iterable[str] = PAPER_CONTROLLERS, *,
                keep: Iterable[SweepKey] | None = None, dt: float = 1e-3) -> Batch:
    """The runs of `sweep` as a `Batch` (to share a pool with other studies)."""
    loads, dt = _check_loads(loads), check_dt(dt)
    freqs = tuple(SineSpec(f).freq for f in freqs)  # validates each
    controllers = tuple(check_control(c) for c in controllers)
    if not freqs or not controllers:
        raise ParameterError("sweep needs at least one frequency and one controller")
    keep = {figure_run_key(loads, freqs, controllers)} if keep is None else set(keep)
    tasks = [SineTask(params, load, c, f, dt, (load, f, c) in keep)
             for load in loads for c in controllers for f in freqs]

    def assemble(res: list) -> SweepResult:
        series = {(p.load, p.freq, p.controller): r for p, r in res if r is not None}
        return SweepResult(points=tuple(p for p, _ in res), series=series)
    return Batch(tasks, assemble)

