"""Where and how independent, deterministic runs execute: in this process, in one local
process pool, or on a Dask cluster.

Everything that runs many simulations takes a `concurrent.futures.Executor`, so the
choice is made once, here (`open_workers`, or `executor_for` where a caller may bring
its own):

  * jobs = 1, no scheduler: no executor (runs in this process, in order);
  * jobs > 1: a `WorkerPool` of `jobs` processes (the default), whose workers never
    outlive the command;
  * a Dask scheduler address (`--scheduler tcp://host:8786` or the environment variable
    DASK_SCHEDULER_ADDRESS): `distributed.Client(address).get_executor()`, the Executor
    interface of Dask distributed. Workers must have wpam_mj installed. Dask is an
    optional dependency (`pip install ".[cluster]"`), imported only when asked for.

A task is any picklable object with `.run()` (its result) and `.cost` (a relative run
time, so that the longest start first); `TaskPool` runs them, results in task order,
not depending on the number of workers. Studies, fits, the calibration and the search run
their tasks through `wpam_mj.simulation.execution` instead, which takes these same
workers: local processes stand for this machine's cores (the simulations run on as many
`mujoco.batch` threads in this process), a Dask executor for the cluster's workers.
"""

from __future__ import annotations

import ctypes
import os
import signal
import sys
from concurrent.futures import FIRST_EXCEPTION, Executor, Future, ProcessPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Callable, Iterator, Sequence

import numpy as np
from tqdm import tqdm

from wpam_mj.infra import termination
from wpam_mj.physics.params import ParameterError, shown

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
    `executor`: any concurrent.futures.Executor (e.g. Dask's, from `open_workers`) to
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

    def __exit__(self, exc_type, exc, tb) -> None:
        for fut in self._submitted:
            fut.cancel()
        if self._pool is not None:
            self._pool.__exit__(exc_type, exc, tb)  # on an exception: stop the workers now
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
            self._pool = WorkerPool(self.jobs)
        pool = self._pool if self._executor is None else self._executor
        with termination.deferred():  # every future recorded, so that all are cancelled
            for i in sorted(range(len(tasks)), key=lambda i: -tasks[i].cost):
                futures[i] = fut = pool.submit(_execute, tasks[i])
                fut.add_done_callback(lambda _: self._bar.update())
            self._submitted += futures
        return futures

    def results(self, futures: Sequence[Future]) -> list:
        """The results of `futures` (from `submit`), in order; raises the first failure."""
        done, _ = termination.wait(futures, FIRST_EXCEPTION)
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


# ---- the choice of workers

SCHEDULER_ENV = "DASK_SCHEDULER_ADDRESS"
CONNECT_TIMEOUT_S = 10.0  # our choice: a scheduler that does not answer in 10 s is not there


@dataclass(frozen=True)
class Workers:
    """An executor (None: run in this process) and how many tasks it runs at once."""

    executor: Executor | None
    slots: int
    where: str  # for messages: "this process", "2 local cores", "Dask at tcp://..."


def scheduler_address(scheduler: str | None) -> str | None:
    """The Dask scheduler to use: `scheduler`, else $DASK_SCHEDULER_ADDRESS, else None."""
    return scheduler or os.environ.get(SCHEDULER_ENV) or None


@dataclass(frozen=True)
class Cluster:
    """A Dask scheduler given where a library call takes `jobs` (`search`, `calibrate`,
    `estimation.fit`: `jobs=Cluster("tcp://host:8786")`), for `open_workers`."""

    address: str


@contextmanager
def open_workers(jobs: int | Cluster = 1, scheduler: str | None = None) -> Iterator[Workers]:
    """Context manager yielding the `Workers` for `jobs` local processes or a Dask
    scheduler (see the module docstring); shuts them down (or disconnects) on exit."""
    if isinstance(jobs, Cluster):
        jobs, scheduler = 1, jobs.address
    address = scheduler_address(scheduler)
    if address is not None:
        with _dask_executor(address) as workers:
            yield workers
    elif jobs == 1:
        yield Workers(None, 1, "this process")
    else:
        with WorkerPool(jobs) as workers:  # stops its workers at once on an exception
            yield Workers(workers, jobs, f"{jobs} local cores")


@contextmanager
def executor_for(jobs: int | Cluster = 1,
                 executor: Executor | None = None) -> Iterator[Executor | None]:
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
