"""The one way to run many simulations: `execute`, for every many-run job (reproduce, the
paper's studies, sweeps, linear studies, design studies, fits, calibration, the search).

A job is a list of tasks, `Batch`es and `Run`s:
  * a `SimulationTask` gives its `runs()` (validated `Run`s, not yet simulated) and its
    `reduce(results)` (their `SimResult`s to the task's result: metrics, a response);
  * any other picklable object with `.run()` (and `.cost`, a relative run time) runs as it
    is: a figure, a file, a static fit;
  * a `Batch` is a study's tasks and what turns their results into its response;
  * a `Run` is one simulation; its result is its `SimResult`.

Where they run is chosen once, by `wpam_mj.infra.pool.open_workers` (its `Workers`, or
what it takes: a number of cores, a `Cluster`, an executor):
  * here (`--jobs N`): the runs of every `SimulationTask` simulated together on N
    `mujoco.batch` threads in this process (runs of one model layout and length share a
    batch; batches smaller than the threads run side by side, one thread each); the
    other tasks on the local process pool, if there is one;
  * a Dask cluster (`--scheduler`): each task (a `Batch`: its tasks together) shipped,
    longest first, to a worker, which runs it through the same path on one batch thread.
    A cluster whose scheduler or every worker is gone for `pool.LOST_AFTER_S` ends the
    job with `pool.WorkersLost`, one line; what the job journaled is kept.
`backend="warp"` (the gpu extra, docs/warp.md) simulates the runs here on MuJoCo Warp
instead, on `device` ("cuda" or Warp's "cpu"): the runs of every `SimulationTask` of a
window share batches (`warp_backend.run_warp`), in float32, so their results follow the
plugin's within docs/warp.md's tolerance rather than bit for bit.

Results come back in job order and, on the default backend, are bit-identical whatever
the target: a run's record
does not depend on its batch or the thread count, and the reduction is the same code as
the task's own serial `run()`. A task that fails with SimulationDiverged, ParameterError
or ArithmeticError (`FAILURES`: the run diverged, its inputs were refused, its metrics
are undefined) is a `Failed` outcome; any other error is raised.
"""

from __future__ import annotations

import concurrent.futures
import dataclasses
import struct
import sys
import time
from concurrent.futures import FIRST_COMPLETED, CancelledError, Future, ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any, Callable, Sequence

import numpy as np
from tqdm import tqdm

from wpam_mj.infra import termination
from wpam_mj.infra.pool import LOST_AFTER_S, Workers, WorkersLost, open_workers
from wpam_mj.errors import ParameterError
from wpam_mj.simulation.loop_contract import SimulationDiverged
from wpam_mj.simulation.results import SimResult
from wpam_mj.simulation.simulate import Run, _run_batch, _select_engine, _run_plugin, simulate_run

FAILURES = (SimulationDiverged, ParameterError, ArithmeticError)
BACKENDS = ("mujoco", "warp")
LOCAL_SLICE = 256  # our choice: tasks simulated at once here (bounds the records in memory)
TASKS_PER_THREAD = 8  # ... and at least this many per batch thread, where there are
LOST_POLL_S = 1.0  # how often a waiting job asks whether its cluster is still there


class SimulationTask:
    """A task that is runs and a reduction (module docstring). `run()` is the serial
    path: its runs one after another, then `reduce`."""

    def runs(self) -> Sequence[Run]:
        raise NotImplementedError

    def reduce(self, results: list[SimResult]) -> Any:
        raise NotImplementedError

    def run(self) -> Any:
        return self.reduce([simulate_run(r) for r in self.runs()])


@dataclass(frozen=True)
class _RunTask(SimulationTask):
    """A bare `Run` as a task: its `SimResult`."""

    job: Run

    @property
    def cost(self) -> float:
        return float(len(self.job.inputs))

    def runs(self) -> Sequence[Run]:
        return [self.job]

    def reduce(self, results: list[SimResult]) -> SimResult:
        return results[0]


@dataclass(frozen=True)
class Batch:
    """A study's tasks and what turns their results (in task order) into its response."""

    tasks: Sequence
    assemble: Callable[[list], Any]

    @property
    def cost(self) -> float:
        return sum(getattr(t, "cost", 0.0) for t in self.tasks)


@dataclass(frozen=True)
class Failed:
    """The outcome of a task that failed with one of `FAILURES`."""

    error: Exception


_RAISE = object()


def execute(jobs: Sequence, workers: Any = None, *, backend: str = "mujoco",
            device: str = "cpu", failed: Any = _RAISE, progress: bool = False,
            desc: str = "runs", each: Callable[[int, Any], None] | None = None) -> list:
    """Every job's result (a task's, a `Batch`'s response, a `Run`'s `SimResult`), in
    job order, wherever `workers` runs them (module docstring).

    workers: the `Workers` of `infra.pool.open_workers`, or what it takes (a number of
      local cores, a `Cluster`, a concurrent.futures.Executor; None: this process).
    backend, device: "mujoco" (`mujoco.batch` on the CPU, device "cpu") or "warp"
      (MuJoCo Warp on device "cuda", "cuda:N" or "cpu"; the gpu extra; not on a cluster).
    failed: what stands for a task that failed with one of `FAILURES`: a value, or a
      callable of the error (`Failed` keeps it); by default the first such failure (in
      job order) is raised.
    progress, desc: a progress bar on stderr, and its label.
    each: called with (job index, result) as each job is done, so that a long job can
      keep what is finished (a study's part files); with it, jobs start in the order
      given, else longest first.
    """
    if not isinstance(workers, Workers):
        with open_workers(workers) as opened:
            return execute(jobs, opened, backend=backend, device=device, failed=failed,
                           progress=progress, desc=desc, each=each)
    warp_device = _warp_device(backend, device, workers)
    jobs = [_RunTask(j) if isinstance(j, Run) else j for j in jobs]
    units = [list(j.tasks) if isinstance(j, Batch) else [j] for j in jobs]
    order = list(range(len(jobs))) if each is not None else \
        sorted(range(len(jobs)), key=lambda k: -getattr(jobs[k], "cost", 0.0))
    results: list = [None] * len(jobs)
    with tqdm(total=sum(map(len, units)), desc=desc, unit="run", file=sys.stderr,
              disable=not progress, leave=False) as bar:

        def finish(k: int, outcomes: list) -> None:
            bar.update(len(outcomes))
            if each is None:
                results[k] = outcomes  # judged below, in job order
                return
            results[k] = _result(jobs[k], outcomes, failed)
            each(k, results[k])

        work = [(k, units[k]) for k in order]
        if workers.remote:
            _run_remote(work, workers, finish, each is not None)
        else:
            _run_local(work, workers, finish, each is not None, warp_device)
    if each is None:
        results = [_result(job, outcomes, failed) for job, outcomes in zip(jobs, results)]
    return results


def _warp_device(backend: str, device: str, workers: Workers) -> str | None:
    """The MuJoCo Warp device the runs go to, or None (`mujoco.batch`); a backend, a
    device or workers that cannot go together refused in one line."""
    if backend not in BACKENDS:
        raise ParameterError(f"backend = {backend!r}; valid: {', '.join(BACKENDS)}")
    if backend == "mujoco":
        if device != "cpu":
            raise ParameterError(f"device = {device!r} needs backend='warp' (mujoco.batch "
                                 "runs on the CPU)")
        return None
    if workers.remote:
        raise ParameterError(f"backend = 'warp' simulates on this machine's device, not on "
                             f"{workers.where}: run it without a scheduler")
    from wpam_mj.simulation.warp_backend import check_device  # noqa: PLC0415 (the gpu extra)

    return check_device(device)


def _result(job, outcomes: list, failed: Any) -> Any:
    """A job's result from its tasks' outcomes, each `Failed` one judged by `failed`."""
    values = []
    for o in outcomes:
        if isinstance(o, Failed):
            if failed is _RAISE:
                raise o.error
            o = failed(o.error) if callable(failed) else failed
        values.append(o)
    return job.assemble(values) if isinstance(job, Batch) else values[0]


def _run_local(units: list[tuple[int, list]], workers: Workers,
               finish: Callable[[int, list], None], in_order: bool,
               warp_device: str | None = None) -> None:
    """Units here: their simulations on `workers.slots` batch threads (or on MuJoCo Warp's
    `warp_device`), consecutive units together (up to LOCAL_SLICE tasks; in order on
    threads, each unit is finished as soon as every thread has had TASKS_PER_THREAD
    tasks), the other tasks on the local process pool."""
    pool = workers.executor
    pooled: dict[tuple[int, int], Future] = {}
    # (a Warp device wants its worlds together: full windows even in order)
    window_size = TASKS_PER_THREAD * workers.slots if in_order and warp_device is None \
        else LOCAL_SLICE
    try:
        if pool is not None:  # tasks that are not simulations: longest first
            mine = [(k, i, t) for k, tasks in units for i, t in enumerate(tasks)
                    if not isinstance(t, SimulationTask)]
            with termination.deferred():  # every future recorded, so that all are cancelled
                for k, i, t in sorted(mine, key=lambda m: -getattr(m[2], "cost", 0.0)):
                    pooled[k, i] = pool.submit(_ship, [t])
        window: list[tuple[int, list]] = []
        here: list = []  # the window's simulations
        for n, (k, tasks) in enumerate(units):
            window.append((k, tasks))
            here += [t for i, t in enumerate(tasks) if (k, i) not in pooled]
            if n + 1 < len(units) and len(here) < window_size:
                continue
            outcomes = iter(_run_here(here, workers.slots, warp_device))
            for j, ts in window:
                mine = [pooled.get((j, i)) for i in range(len(ts))]
                if any(f is not None and not f.done() for f in mine):
                    _wait_pooled(pooled.values())
                finish(j, [next(outcomes) if f is None else f.result()[0] for f in mine])
            window, here = [], []
    finally:
        for fut in pooled.values():
            fut.cancel()


def _wait_pooled(futures) -> None:
    """Until every pooled task is done; the first fault is raised as soon as it happens."""
    done, _ = termination.wait(futures, concurrent.futures.FIRST_EXCEPTION)
    for f in done:
        if not f.cancelled() and f.exception() is not None:
            raise f.exception()


def _run_remote(units: list[tuple[int, list]], workers: Workers,
                finish: Callable[[int, list], None], in_order: bool) -> None:
    """Each unit shipped to the cluster as one task, finished as it comes back; a
    cluster that can no longer run it raises `WorkersLost`."""
    pending: dict[Future, int] = {}
    try:
        with termination.deferred():  # every future recorded, so that all are cancelled
            for k, tasks in units:
                pending[workers.executor.submit(_ship, tasks)] = k
        probed = time.monotonic()
        while pending:
            done, _ = concurrent.futures.wait(pending, termination.SIGNAL_POLL_S,
                                              FIRST_COMPLETED)
            for fut in sorted(done, key=pending.__getitem__):
                finish(pending.pop(fut), _shipped(fut, workers))
            if not done and time.monotonic() - probed >= LOST_POLL_S:
                probed = time.monotonic()
                _check_alive(workers)
    finally:
        for fut in pending:
            fut.cancel()


def _shipped(fut: Future, workers: Workers) -> list:
    """A shipped unit's outcomes; what the cluster made of losing it, as `WorkersLost`."""
    try:
        return fut.result()
    except CancelledError:  # the client cancels what it can no longer track
        _check_alive(workers, at_once=True)
        raise
    except Exception as err:
        if type(err).__name__ in ("KilledWorker", "CommClosedError", "FutureCancelledError"):
            raise WorkersLost(f"{workers.where}: {_lost_text(err)}; {_RESUME}") from None
        raise


_RESUME = "what finished is kept: run the command again (with --resume where it has one)"


def _lost_text(err: Exception) -> str:
    if type(err).__name__ == "KilledWorker":
        return "workers died running one task (KilledWorker)"
    return f"lost the cluster ({' '.join(str(err).split()) or type(err).__name__})"


def _check_alive(workers: Workers, *, at_once: bool = False) -> None:
    """Raise `WorkersLost` if the cluster is gone; `at_once`: a task was cancelled, so
    wait (at most LOST_AFTER_S) for the client to say whether it was the cluster."""
    why = workers.lost()
    deadline = time.monotonic() + (LOST_AFTER_S + 2 * LOST_POLL_S if at_once else 0.0)
    while why is None and time.monotonic() < deadline:
        time.sleep(termination.SIGNAL_POLL_S)
        why = workers.lost()
    if why is not None:
        raise WorkersLost(f"{workers.where}: {why}; {_RESUME}")


def _ship(tasks: Sequence) -> list:
    """Worker entry point (module level, so that every executor can pickle it)."""
    return _run_here(tasks, 1)


def _attempt(call: Callable[[], Any]) -> Any:
    try:
        return call()
    except FAILURES as err:
        return Failed(err)


def _run_here(tasks: Sequence, nthread: int = 1, warp_device: str | None = None) -> list:
    """Outcomes of `tasks` in this process (the result, or `Failed`), in task order: the
    runs of every `SimulationTask` simulated together on `nthread` batch threads, or on
    MuJoCo Warp's `warp_device`."""
    out: list = [None] * len(tasks)
    planned: list[tuple[int, int, int]] = []  # (task, first run, number of runs)
    runs: list[Run] = []
    for k, task in enumerate(tasks):
        if not isinstance(task, SimulationTask):
            out[k] = _attempt(task.run)
            continue
        mine = _attempt(lambda: list(task.runs()))
        if isinstance(mine, Failed):
            out[k] = mine
            continue
        planned.append((k, len(runs), len(mine)))
        runs += mine
    if warp_device is None:
        results = _simulate_runs(runs, nthread)
    else:
        from wpam_mj.simulation.warp_backend import run_warp  # noqa: PLC0415 (the gpu extra)

        results = run_warp(runs, device=warp_device)
    for k, first, n in planned:
        got = results[first:first + n]
        failed = next((r for r in got if isinstance(r, SimulationDiverged)), None)
        out[k] = Failed(failed) if failed is not None else \
            _attempt(lambda: tasks[k].reduce(got))
    return out


def _simulate_runs(runs: list[Run], nthread: int) -> list[SimResult | SimulationDiverged]:
    """Each run's `SimResult`, or the SimulationDiverged it raises, bit-identical to
    `simulate_run(run)`: the runs the plugin takes share `mujoco.batch` batches (one per
    model layout and length) on `nthread` threads (batches of fewer runs than threads run
    side by side, one thread each); the others (no plugin, a controller only Python
    defines) run one after another on the Python engine, as `simulate` runs them."""
    done: dict[int, tuple] = {}
    batched = [i for i, run in enumerate(runs)
               if _select_engine("auto", run.context.control) is _run_plugin]
    models = {i: runs[i].spec.compile() for i in batched}
    groups: dict[tuple, list[int]] = {}
    for i in batched:
        run, model = runs[i], models[i]
        key = (len(run.inputs), run.record_every, model.nu, model.npluginstate, model.nq)
        groups.setdefault(key, []).append(i)

    def batch(ids: list[int], threads: int) -> None:
        done.update(zip(ids, _run_batch([models[i] for i in ids],
                                        [runs[i].inputs for i in ids],
                                        runs[ids[0]].record_every, nthread=threads)))

    small = []  # batches too small for the threads: several at once, one thread each
    for ids in groups.values():
        if len(ids) >= nthread:
            batch(ids, nthread)
        else:
            small.append(ids)
    if small:
        small.sort(key=lambda ids: -len(runs[ids[0]].inputs) * len(ids))  # longest first
        with ThreadPoolExecutor(nthread) as threads:
            futures = [threads.submit(batch, ids, 1) for ids in small]
            termination.wait(futures, concurrent.futures.FIRST_EXCEPTION)
            for fut in futures:
                fut.result()
    out: list[SimResult | SimulationDiverged] = []
    for i, run in enumerate(runs):
        try:
            out.append(run.result(*done[i]) if i in done else simulate_run(run))
        except SimulationDiverged as err:
            out.append(err)
    return out


def result_bytes(obj) -> bytes:
    """Every number of `obj` (results: dataclasses of arrays, in containers) as bytes, in
    order: equal bytes are bit-identical results, whatever the target ran them (pickle's
    own bytes depend on which equal strings happen to be one object)."""
    if dataclasses.is_dataclass(obj):
        return type(obj).__name__.encode() + b"".join(
            result_bytes(getattr(obj, f.name)) for f in dataclasses.fields(obj))
    if isinstance(obj, np.ndarray):
        return str(obj.dtype).encode() + obj.tobytes()
    if isinstance(obj, (list, tuple)):
        return b"[" + b",".join(result_bytes(v) for v in obj) + b"]"
    if isinstance(obj, dict):
        return b"{" + b",".join(result_bytes(k) + b":" + result_bytes(v)
                                for k, v in obj.items()) + b"}"
    if isinstance(obj, float):
        return struct.pack("<d", obj)
    return repr(obj).encode()
