"""Where many independent, deterministic runs execute, chosen once: `open_workers`.

  * jobs = 1, no scheduler: this process, one batch thread;
  * jobs > 1: this process's `jobs` `mujoco.batch` threads for the simulations, and a
    `WorkerPool` of `jobs` processes (started on first use, its workers never outlive the
    command) for tasks that are not simulations (figures, files, static fits);
  * a Dask scheduler address (`--scheduler tcp://host:8786` or the environment variable
    DASK_SCHEDULER_ADDRESS): `distributed.Client(address).get_executor()`; every task is
    shipped to the cluster's workers. Workers must have wpam_mj installed. Dask is an
    optional dependency (`pip install ".[cluster]"`), imported only when asked for.

The `Workers` it yields say which; `wpam_mj.simulation.execution.execute` runs tasks on
them (docs/cluster.md).
"""

from __future__ import annotations

import ctypes
import gc
import logging
import os
import signal
import sys
import time
from concurrent.futures import BrokenExecutor, Executor, Future, ProcessPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Iterator

import numpy as np

from wpam_mj.infra import termination
from wpam_mj.errors import ParameterError, shown

_PR_SET_PDEATHSIG = 1  # prctl option (linux/prctl.h): signal this process when its parent dies
_STOP_GRACE_S = 0.5  # our choice: a worker still alive this long after SIGTERM is killed


def check_jobs(jobs: int) -> int:
    """Process-pool size: an integer >= 1."""
    if isinstance(jobs, bool) or not isinstance(jobs, (int, np.integer)) or jobs < 1:
        raise ParameterError(f"jobs = {shown(jobs)} must be an integer >= 1")
    return int(jobs)


def default_jobs() -> int:
    return os.cpu_count() or 1


def _worker_init(parent: int) -> None:
    """Pool worker start-up: die with the parent, leave signals to it.

    SIGINT (Ctrl-C reaches the whole process group) is ignored: the parent stops the
    workers itself, so they print no tracebacks. SIGTERM kills at once, even in compiled
    code. On Linux the kernel sends SIGKILL when the parent dies, however it dies
    (SIGKILL included); a parent gone before that was set up ends the worker here.
    """
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    for stop in termination.STOP_SIGNALS:
        signal.signal(stop, signal.SIG_DFL)
    if sys.platform.startswith("linux"):
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(_PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
    if os.getppid() != parent:
        os._exit(1)


class WorkerPool(ProcessPoolExecutor):
    """A process pool whose workers never outlive the command.

    Its workers die with this process (`_worker_init`); submitting is shielded from
    signals (`termination.deferred`: a pool half started cannot be torn down); and leaving
    it on an exception, or shutting it down after a signal, stops the workers at once
    instead of waiting for their tasks.
    """

    def __init__(self, jobs: int) -> None:
        super().__init__(max_workers=check_jobs(jobs), initializer=_worker_init,
                         initargs=(os.getpid(),))

    def submit(self, fn, /, *args, **kwargs) -> Future:
        with termination.deferred():
            return super().submit(fn, *args, **kwargs)

    def shutdown(self, wait: bool = True, *, cancel_futures: bool = False) -> None:
        if termination.stopping():
            self.stop()
        else:
            super().shutdown(wait, cancel_futures=cancel_futures)

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.shutdown(wait=True)
        else:
            self.stop()

    def stop(self) -> None:
        """Stop the workers now (SIGTERM, SIGKILL after a grace), drop queued tasks.

        The call queue's feeder thread may be blocked writing a task into a pipe no worker
        will read again (a task larger than the pipe's buffer: a figure's records); it is
        not joined, so that neither this pool's manager nor the interpreter's exit waits
        for it forever."""
        self._call_queue.cancel_join_thread()
        # Queued tasks are dropped now. Python 3.11's manager thread, finding the workers
        # gone, sets an exception on every pending task's future and raises on those
        # cancelled (fixed in 3.12): a cancelled task gets a future that takes it silently.
        for item in list(self._pending_work_items.values()):
            if item.future.cancel():
                item.future = _Dropped()
        workers = list((self._processes or {}).values())
        for proc in workers:
            proc.terminate()
        for proc in workers:
            proc.join(_STOP_GRACE_S)
            if proc.is_alive():
                proc.kill()
                proc.join()
        super().shutdown(wait=False, cancel_futures=True)


class _Dropped(Future):
    """A cancelled task's stand-in future: the broken pool's error has no one to tell."""

    def __init__(self) -> None:
        super().__init__()
        self.cancel()

    def set_exception(self, exception) -> None:
        pass


# ---- the choice of workers

SCHEDULER_ENV = "DASK_SCHEDULER_ADDRESS"
CONNECT_TIMEOUT_S = 10.0  # our choice: a scheduler that does not answer in 10 s is not there
LOST_AFTER_S = 10.0  # our choice: a cluster with no worker (or no scheduler) this long is gone


class WorkersLost(BrokenExecutor):
    """The cluster can no longer run tasks: its scheduler or every worker is gone."""


@dataclass(frozen=True)
class Workers:
    """Where tasks run, as `open_workers` chose (module docstring).

    executor: None (this process only); local: the process pool for tasks that are not
      simulations; remote: the cluster, every task.
    slots: tasks at once: batch threads here (local), the cluster's worker threads (remote).
    where: for messages: "this process", "2 local cores", "Dask at tcp://...".
    """

    executor: Executor | None
    slots: int
    where: str
    remote: bool = False

    def lost(self) -> str | None:
        """Why the cluster can no longer run tasks, or None while it can (local: never)."""
        client = getattr(self.executor, "_client", None)
        return None if client is None else _dask_lost(client)


def scheduler_address(scheduler: str | None) -> str | None:
    """The Dask scheduler to use: `scheduler`, else $DASK_SCHEDULER_ADDRESS, else None."""
    return scheduler or os.environ.get(SCHEDULER_ENV) or None


@dataclass(frozen=True)
class Cluster:
    """A Dask scheduler given where a library call takes `jobs` (`search`, `calibrate`,
    `estimation.fit`: `jobs=Cluster("tcp://host:8786")`), for `open_workers`."""

    address: str


@contextmanager
def open_workers(jobs: int | Cluster | Workers | Executor | None = 1,
                 scheduler: str | None = None) -> Iterator[Workers]:
    """Context manager yielding the `Workers` for `jobs` (module docstring): a number of
    local cores, a `Cluster`, or workers the caller opened (a `Workers` or any
    concurrent.futures.Executor: yielded as they are, not shut down here; None: this
    process). Shuts what it opened down (or disconnects) on exit."""
    if jobs is None or isinstance(jobs, (Workers, Executor)):
        yield _given(jobs)
        return
    if isinstance(jobs, Cluster):
        jobs, scheduler = 1, jobs.address
    jobs = check_jobs(jobs)
    address = scheduler_address(scheduler)
    if address is not None:
        with _dask_executor(address) as workers:
            yield workers
    elif jobs == 1:
        yield Workers(None, 1, "this process")
    else:
        with WorkerPool(jobs) as pool:  # stops its workers at once on an exception
            yield Workers(pool, jobs, f"{jobs} local cores")


def _given(where: Workers | Executor | None) -> Workers:
    """The `Workers` of an executor opened elsewhere."""
    if where is None or isinstance(where, Workers):
        return where or Workers(None, 1, "this process")
    if isinstance(where, ProcessPoolExecutor):  # local processes: as many cores here
        return Workers(where, where._max_workers, f"{where._max_workers} local cores")
    client = getattr(where, "_client", None)  # Dask's executor
    where_text = type(where).__name__ if client is None else \
        f"Dask at {client.scheduler.address}"
    return Workers(where, 1, where_text, remote=True)


@contextmanager
def _dask_executor(address: str) -> Iterator[Workers]:
    try:
        from distributed import Client  # noqa: PLC0415 (optional dependency)
    except ImportError:
        raise ParameterError(f"Dask scheduler {address}: Dask distributed is not installed; "
                             'pip install ".[cluster]"') from None
    with _quiet_dask():
        failure = None
        try:
            client = Client(address, timeout=CONNECT_TIMEOUT_S)
        except (OSError, ValueError) as err:  # TimeoutError is an OSError
            failure = f"cannot connect ({_reason(err)})"
        except Exception:  # noqa: BLE001 (what Dask makes of another service's answer:
            # a frame length of exabytes, MemoryError)
            failure = "the service there does not answer as a Dask scheduler"
        if failure is not None:
            # The half-made Client closes itself in __del__, which waits for its IO loop:
            # collected later inside a new IO loop's start, it stalls that start past
            # distributed's fixed 10 s. Raised outside the except (no traceback keeps it)
            # and collected here, it closes now, in this thread.
            gc.collect()
            raise ParameterError(f"Dask scheduler {address}: {failure}")
        try:
            slots = sum(client.nthreads().values())  # threads of the workers connected now
            executor = client.get_executor()
            try:
                yield Workers(executor, max(slots, 1), f"Dask at {address}", remote=True)
            except BaseException:
                executor.shutdown(wait=False)  # cancel the cluster's tasks; no waiting
                raise
            executor.shutdown(wait=True)
        finally:
            _UNHEALTHY_SINCE.pop(id(client), None)
            client.close(timeout=CONNECT_TIMEOUT_S)


def _reason(err: BaseException) -> str:
    return " ".join(str(err).split()) or type(err).__name__


_UNHEALTHY_SINCE: dict[int, float] = {}  # client id -> since when it could run nothing


def _dask_lost(client) -> str | None:
    """Why `client` can no longer run tasks: its scheduler unreachable, or no worker,
    for LOST_AFTER_S (the scheduler would wait for a worker forever)."""
    if client.status != "running":
        why = f"the scheduler is gone (no answer for {LOST_AFTER_S:g} s)"
    elif not client.scheduler_info().get("workers"):  # refreshed by the client every 2 s
        why = f"every worker is gone (none for {LOST_AFTER_S:g} s)"
    else:
        _UNHEALTHY_SINCE.pop(id(client), None)
        return None
    since = _UNHEALTHY_SINCE.setdefault(id(client), time.monotonic())
    return why if time.monotonic() - since >= LOST_AFTER_S else None


@contextmanager
def _quiet_dask() -> Iterator[None]:
    """Dask's own logging off while we use it: its errors reach the command as one line
    (`WorkersLost`, a refused address), not as the tracebacks its loggers print."""
    names = [n for n in logging.root.manager.loggerDict
             if n.split(".")[0] in ("distributed", "tornado", "asyncio")]
    loggers = [logging.getLogger(n) for n in ("distributed", "tornado", "asyncio", *names)]
    levels = [lg.level for lg in loggers]
    for lg in loggers:
        lg.setLevel(logging.CRITICAL + 1)
    try:
        yield
    finally:
        for lg, level in zip(loggers, levels):
            lg.setLevel(level)
