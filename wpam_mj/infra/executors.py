"""Where independent runs execute: this process, a local process pool, or a Dask cluster.

Everything that runs many simulations takes a `concurrent.futures.Executor`, so the
choice is made once, here:

  * jobs = 1, no scheduler: no executor (runs in this process, in order);
  * jobs > 1: a `wpam_mj.infra.pool.WorkerPool` of `jobs` processes (the default);
  * a Dask scheduler address (`--scheduler tcp://host:8786` or the environment variable
    DASK_SCHEDULER_ADDRESS): `distributed.Client(address).get_executor()`, the Executor
    interface of Dask distributed. Workers must have wpam_mj installed.

Dask is an optional dependency (`pip install ".[cluster]"`), imported only when asked for.
"""

from __future__ import annotations

import os
from concurrent.futures import Executor
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Iterator

from wpam_mj.physics.params import ParameterError
from wpam_mj.infra.pool import WorkerPool

SCHEDULER_ENV = "DASK_SCHEDULER_ADDRESS"
CONNECT_TIMEOUT_S = 10.0  # our choice: a scheduler that does not answer in 10 s is not there


@dataclass(frozen=True)
class Workers:
    """An executor (None: run in this process) and how many tasks it runs at once."""

    executor: Executor | None
    slots: int
    where: str  # for messages: "this process", "2 local processes", "Dask at tcp://..."


def scheduler_address(scheduler: str | None) -> str | None:
    """The Dask scheduler to use: `scheduler`, else $DASK_SCHEDULER_ADDRESS, else None."""
    return scheduler or os.environ.get(SCHEDULER_ENV) or None


@contextmanager
def open_workers(jobs: int = 1, scheduler: str | None = None) -> Iterator[Workers]:
    """Context manager yielding the `Workers` for `jobs` local processes or a Dask
    scheduler (see the module docstring); shuts them down (or disconnects) on exit."""
    address = scheduler_address(scheduler)
    if address is not None:
        with _dask_executor(address) as workers:
            yield workers
    elif jobs == 1:
        yield Workers(None, 1, "this process")
    else:
        with WorkerPool(jobs) as pool:  # stops its workers at once on an exception
            yield Workers(pool, jobs, f"{jobs} local processes")


@contextmanager
def executor_for(jobs: int = 1, executor: Executor | None = None) -> Iterator[Executor | None]:
    """`executor` if given (the caller's: not shut down here), else the executor of
    `open_workers(jobs)` (None: run in this process)."""
    if executor is not None:
        yield executor
        return
    with open_workers(jobs) as workers:
        yield workers.executor


@contextmanager
def _dask_executor(address: str) -> Iterator[Workers]:
    try:
        from distributed import Client  # noqa: PLC0415 (optional dependency)
    except ImportError:
        raise ParameterError(f"Dask scheduler {address}: Dask distributed is not installed; "
                             'pip install ".[cluster]"') from None
    try:
        client = Client(address, timeout=CONNECT_TIMEOUT_S)
    except (OSError, ValueError) as err:  # TimeoutError is an OSError
        raise ParameterError(f"Dask scheduler {address}: cannot connect "
                             f"({' '.join(str(err).split())})") from None
    try:
        slots = sum(client.nthreads().values())  # threads of the workers connected now
        executor = client.get_executor()
        try:
            yield Workers(executor, max(slots, 1), f"Dask at {address}")
        except BaseException:
            executor.shutdown(wait=False)  # cancel the cluster's tasks; do not wait for them
            raise
        executor.shutdown(wait=True)
    finally:
        client.close()
