"""One execution layer for every many-run job: studies, fits, calibration, the search.

A job is a list of tasks. A task that is a plain simulation is a `SimulationTask`: its
`runs()` (validated `Run`s, not yet simulated) and its `reduce(results)` (their
`SimResult`s to the task's result: metrics, a response object). The layer simulates the
runs of many such tasks together through `simulate.simulate_each` (`simulate_many`'s
`mujoco.batch` batches: runs of one model layout and length share one) and reduces each
task. Any other picklable object with `.run()` (and `.cost`) is run as it is.

Where it runs (`execute`'s `where`, the `Workers` of `infra.pool.open_workers`, their
executor, or None):

  * here: None or one local slot runs everything in this process, one batch thread;
    local processes (`--jobs N`, a `WorkerPool`) mean N cores here: the simulations run
    in this process on N batch threads, and only tasks that are not simulations go to the
    pool's processes;
  * any other executor (a Dask cluster's, `--scheduler`): each task is shipped, longest
    first, to a worker, which runs it through the same path on one batch thread.

Results come back in task order and are bit-identical whatever the target: a run's
record does not depend on its batch or the thread count (`simulate_many`), and the
reduction is the same code as the task's own `run()`. A task that fails with
SimulationDiverged, ParameterError or ArithmeticError (`FAILURES`: the run diverged, its
inputs were refused, its metrics are undefined) is a `Failed` outcome; any other error
is raised.
"""

from __future__ import annotations

import dataclasses
import struct
from concurrent.futures import FIRST_COMPLETED, Executor, Future, ProcessPoolExecutor
from dataclasses import dataclass
from typing import Any, Callable, Sequence

import numpy as np

from wpam_mj.infra import termination
from wpam_mj.infra.pool import Workers
from wpam_mj.physics.params import ParameterError
from wpam_mj.simulation.loop_contract import SimulationDiverged
from wpam_mj.simulation.results import SimResult
from wpam_mj.simulation.simulate import Run, simulate_each, simulate_run

FAILURES = (SimulationDiverged, ParameterError, ArithmeticError)
LOCAL_SLICE = 256  # our choice: tasks simulated at once here (bounds the records in memory)
TASKS_PER_THREAD = 8  # ... and at least this many per batch thread, where there are


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
class Failed:
    """The outcome of a task that failed with one of `FAILURES`."""

    error: Exception


def _attempt(call: Callable[[], Any]) -> Any:
    try:
        return call()
    except FAILURES as err:
        return Failed(err)


def run_here(tasks: Sequence, nthread: int = 1) -> list:
    """Outcomes of `tasks` in this process (the result, or `Failed`), in task order: the
    runs of every `SimulationTask` simulated together on `nthread` batch threads."""
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
    results = simulate_each(runs, nthread=nthread)
    for k, first, n in planned:
        got = results[first:first + n]
        failed = next((r for r in got if isinstance(r, SimulationDiverged)), None)
        out[k] = Failed(failed) if failed is not None else \
            _attempt(lambda: tasks[k].reduce(got))
    return out


def _ship(tasks: Sequence) -> list:
    """Worker entry point (module level, so that every executor can pickle it)."""
    return run_here(tasks, 1)


@dataclass(frozen=True)
class _Target:
    threads: int  # batch threads in this process
    executor: Executor | None  # local: the pool for other tasks; remote: everything
    remote: bool


def _target(where: Workers | Executor | None) -> _Target:
    executor = where.executor if isinstance(where, Workers) else where
    if executor is not None and not isinstance(executor, Executor):
        raise ParameterError(f"where = {where!r}: expected the Workers of "
                             "wpam_mj.infra.pool.open_workers, a concurrent.futures.Executor "
                             "or None (this process)")
    if executor is None:
        return _Target(1, None, False)
    if isinstance(executor, ProcessPoolExecutor):  # local processes: this machine's cores
        return _Target(executor._max_workers, executor, False)
    return _Target(1, executor, True)


def run_chunks(chunks: Sequence[Sequence], where: Workers | Executor | None,
               finish: Callable[[int, list], None]) -> None:
    """Run each chunk of tasks as one unit and hand `finish(i, outcomes)` chunk i's
    outcomes (`run_here`) as it is done: here in order, consecutive chunks simulated
    together until every batch thread has TASKS_PER_THREAD tasks; on a remote executor
    as they arrive (submitted in the order given). On any failure or interruption, what
    has not started is cancelled."""
    target = _target(where)
    if not target.remote:  # several chunks at once, so that every thread has runs
        window: list[int] = []
        for i, chunk in enumerate(chunks):
            window.append(i)
            if i + 1 < len(chunks) and \
                    sum(len(chunks[j]) for j in window) < TASKS_PER_THREAD * target.threads:
                continue
            outcomes = run_here([t for j in window for t in chunks[j]], target.threads)
            for j in window:
                finish(j, outcomes[:len(chunks[j])])
                outcomes = outcomes[len(chunks[j]):]
            window = []
        return
    pending: dict[Future, int] = {}
    try:
        with termination.deferred():  # every future recorded, so that all are cancelled
            for i, chunk in enumerate(chunks):
                pending[target.executor.submit(_ship, list(chunk))] = i
        while pending:
            done, _ = termination.wait(pending, FIRST_COMPLETED)
            for fut in sorted(done, key=pending.__getitem__):
                finish(pending.pop(fut), fut.result())
    finally:
        for fut in pending:
            fut.cancel()


_RAISE = object()


def execute(tasks: Sequence, where: Workers | Executor | None = None, *,
            failed: Any = _RAISE) -> list:
    """Every task's result, in task order, whatever `where` is (module docstring).

    failed: what stands for a task that failed with one of `FAILURES`: a value, or a
    callable of the error; by default the first such failure (in task order) is raised.
    """
    tasks = list(tasks)
    target = _target(where)
    order = sorted(range(len(tasks)), key=lambda k: -getattr(tasks[k], "cost", 0.0))
    outcome: list = [None] * len(tasks)
    pooled: dict[int, Future] = {}
    try:
        if target.remote:
            chunks = [[k] for k in order]
        else:
            if target.executor is not None:  # tasks that are not simulations: the pool
                with termination.deferred():
                    pooled = {k: target.executor.submit(_ship, [tasks[k]]) for k in order
                              if not isinstance(tasks[k], SimulationTask)}
            mine = [k for k in order if k not in pooled]
            chunks = [mine[s:s + LOCAL_SLICE] for s in range(0, len(mine), LOCAL_SLICE)]

        def finish(i: int, outcomes: list) -> None:
            for k, o in zip(chunks[i], outcomes):
                outcome[k] = o

        run_chunks([[tasks[k] for k in c] for c in chunks], where, finish)
        termination.wait(pooled.values())
        for k, fut in pooled.items():
            (outcome[k],) = fut.result()
    finally:
        for fut in pooled.values():
            fut.cancel()
    out = []
    for o in outcome:
        if isinstance(o, Failed):
            if failed is _RAISE:
                raise o.error
            o = failed(o.error) if callable(failed) else failed
        out.append(o)
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
