"""Running many independent, deterministic tasks: in this process or in one process pool.

A task is any picklable object with `.run()` (its result) and `.cost` (a relative run
time, so that the longest start first). Results come back in task order and do not
depend on the number of workers.
"""

from __future__ import annotations

import os
import sys
from concurrent.futures import FIRST_EXCEPTION, Future, ProcessPoolExecutor, wait
from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np
from tqdm import tqdm

from wpam_mj.params import ParameterError


def check_jobs(jobs: int) -> int:
    """Process-pool size: an integer >= 1."""
    if isinstance(jobs, bool) or not isinstance(jobs, (int, np.integer)) or jobs < 1:
        raise ParameterError(f"jobs = {jobs!r} must be an integer >= 1")
    return int(jobs)


def default_jobs() -> int:
    return os.cpu_count() or 1


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
    """

    def __init__(self, jobs: int = 1, *, progress: bool = False, desc: str = "runs") -> None:
        self.jobs = check_jobs(jobs)
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
        if self.jobs == 1:  # a failure propagates at once: nothing else runs
            for i, task in enumerate(tasks):
                futures[i] = Future()
                futures[i].set_result(task.run())
                self._bar.update()
            return futures
        if self._pool is None:
            self._pool = ProcessPoolExecutor(max_workers=self.jobs)
        for i in sorted(range(len(tasks)), key=lambda i: -tasks[i].cost):
            futures[i] = fut = self._pool.submit(_execute, tasks[i])
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
              desc: str = "runs") -> list:
    """Run `task.run()` for every task (see `TaskPool`); results in task order."""
    with TaskPool(jobs, progress=progress, desc=desc) as pool:
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
                desc: str = "runs") -> list:
    """Run the tasks of several studies in one pool and return each study's assembled
    response, in the order given."""
    with TaskPool(jobs, progress=progress, desc=desc) as pool:
        return [response() for response in submit_batches(pool, batches)]
