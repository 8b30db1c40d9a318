"""Interrupts: every signal ends a command promptly with its status, no process and
no temporary file left; pool workers die with their parent however it dies.

Signals are sent the moment the pool's workers exist (the race of the suite's SIGTERM
test) and later; each run is a few seconds. Run under load to mean anything (the target:
ten passes in a row with the machine busy)."""

from __future__ import annotations

import concurrent.futures
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from wpam_mj.infra import termination
from wpam_mj.infra.pool import WorkerPool, open_workers
from wpam_mj.simulation.execution import execute

ROOT = Path(__file__).resolve().parents[1]
STATUS = {signal.SIGINT: 130, signal.SIGTERM: 143, signal.SIGHUP: 129}
MESSAGE = {signal.SIGINT: "interrupted", signal.SIGTERM: "terminated",
           signal.SIGHUP: "hung up"}
EXIT_WITHIN_S = 1.0  # a stopped command is gone within a second
STUDY = """experiment = "step"
dt = 2e-3
[fixed]
duration = 110.0
[vary]
method = "list"
[vary.values]
load = [50, 60, 70, 80, 90, 100, 110, 120]
"""
STATIC = ("static", "--compare-presets", "--load", "100", "--jobs", "2", "--out", "o",
          "--dt", "0.001")  # runs on two batch threads in the command's process
POOL = ("synth", "--jobs", "2", "--out", "o")  # tasks that are not simulations: two processes
needs_proc = pytest.mark.skipif(not Path("/proc/self/task").exists(), reason="Linux /proc")


def _children(pid: int) -> list[int]:
    try:
        return [int(c) for c in Path(f"/proc/{pid}/task/{pid}/children").read_text().split()]
    except OSError:
        return []


def _alive(pid: int) -> bool:
    try:
        return "\nState:\tZ" not in Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return False


def _wait_until(condition, bound_s: float) -> bool:
    deadline = time.monotonic() + bound_s
    while not condition():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.01)
    return True


def _threads(pid: int) -> int:
    try:
        return len(os.listdir(f"/proc/{pid}/task"))
    except OSError:
        return 0


def _start(tmp_path: Path, *argv: str) -> tuple[subprocess.Popen, list[int]]:
    """Start `wpam argv` and return it once its runs have started: the two pool workers
    of `synth` exist; a study has its parts folder; `static`'s output folder is claimed
    and its batch threads run, in the command's own process."""
    (tmp_path / "spec.toml").write_text(STUDY)
    proc = subprocess.Popen([sys.executable, "-m", "wpam_mj", *argv], cwd=tmp_path,
                            env={**os.environ, "PYTHONPATH": str(ROOT)},
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    started = {"study": lambda: (tmp_path / "o" / "parts").exists(),
               "synth": lambda: len(_children(proc.pid)) >= 2,
               "static": lambda: (tmp_path / "o").exists() and _threads(proc.pid) >= 3,
               }[argv[0]]
    if not _wait_until(lambda: started() or proc.poll() is not None, 120):
        proc.kill()
        pytest.fail("the runs never started")
    return proc, _children(proc.pid)


@needs_proc
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM, signal.SIGHUP],
                         ids=lambda s: s.name)
@pytest.mark.parametrize("argv, delay", [
    (STATIC, 0.0),  # while the batch threads start
    (STATIC, 0.5),  # while they run
    (POOL, 0.0),  # while the pool starts
    (POOL, 0.5),  # while it runs
    (("study", "spec.toml", "--jobs", "2", "--out", "o"), 0.3),
], ids=["static-at-start", "static-running", "pool-at-start", "pool-running", "study"])
def test_a_signal_ends_the_command_at_once_with_its_status(tmp_path, sig, argv, delay):
    proc, workers = _start(tmp_path, *argv)
    time.sleep(delay)
    sent = time.monotonic()
    proc.send_signal(sig)
    out, err = proc.communicate(timeout=60)
    took = time.monotonic() - sent
    assert proc.returncode == STATUS[sig], err
    assert err.strip().splitlines()[-1] == f"wpam: {MESSAGE[sig]}", err
    assert "Traceback" not in err and "Exception" not in err, err
    assert took < EXIT_WITHIN_S, f"{took:.2f} s from the signal to the exit"
    assert _wait_until(lambda: not any(_alive(w) for w in workers), 2.0), "workers survived"
    assert not list((tmp_path / "o").rglob(".*")), "temporary files left"


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=lambda s: s.name)
def test_a_signal_during_one_long_run_in_this_process_acts_at_once(tmp_path, sig):
    """One 7,200 s run without a pool: the engine returns between chunks of steps, where
    the signal is raised (before: only when the whole run had finished)."""
    proc = subprocess.Popen([sys.executable, "-m", "wpam_mj", "static", "--load", "100",
                             "--ramp-time", "3600", "--jobs", "1", "--out", "o"],
                            cwd=tmp_path, env={**os.environ, "PYTHONPATH": str(ROOT)},
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    # the output folder is claimed just before the run starts
    assert _wait_until(lambda: (tmp_path / "o").exists() or proc.poll() is not None, 120)
    time.sleep(1.0)  # into the run
    sent = time.monotonic()
    proc.send_signal(sig)
    out, err = proc.communicate(timeout=60)
    assert (proc.returncode, err) == (STATUS[sig], f"wpam: {MESSAGE[sig]}\n")
    assert time.monotonic() - sent < EXIT_WITHIN_S
    assert not (tmp_path / "o").exists(), "the empty output folder is removed"


@needs_proc
def test_ctrl_c_to_the_process_group_of_reproduce_never_hangs(tmp_path):
    """Ctrl-C reaches the command and its workers at once (before: "Exception in thread",
    workers alive, the command hung)."""
    proc = subprocess.Popen([sys.executable, "-m", "wpam_mj", "reproduce", "--jobs", "2",
                             "--out", "o", "--dt", "0.002"], cwd=tmp_path,
                            env={**os.environ, "PYTHONPATH": str(ROOT)},
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)
    assert _wait_until(lambda: len(_children(proc.pid)) >= 2, 120), "the pool never started"
    workers = _children(proc.pid)
    time.sleep(0.5)
    sent = time.monotonic()
    os.killpg(proc.pid, signal.SIGINT)
    out, err = proc.communicate(timeout=60)
    assert time.monotonic() - sent < EXIT_WITHIN_S
    assert (proc.returncode, err) == (130, "wpam: interrupted\n")
    assert _wait_until(lambda: not any(_alive(w) for w in workers), 2.0), "workers survived"
    assert not list((tmp_path / "o").rglob(".*")), "temporary files left"


def test_temporary_files_of_stopped_workers_go_with_the_command(tmp_path):
    """A worker stopped mid-write leaves its hidden temporary file; the command removes
    it as it ends (`outputs.release`), and never touches a live writer's."""
    from wpam_mj.infra import outputs  # noqa: PLC0415
    outputs.claim(tmp_path / "o")
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True).stdout.strip()
    (tmp_path / "o" / "parts").mkdir()
    stale = tmp_path / "o" / "parts" / f".runs.csv.wpam{dead}-x1.csv"
    live = tmp_path / "o" / f".study.csv.wpam{os.getpid()}-x2.csv"
    for path in (stale, live):
        path.write_text("partial")
    outputs.release(failed=True)
    assert not stale.exists() and live.exists()


@needs_proc
def test_pool_workers_exit_when_the_parent_is_killed(tmp_path):
    proc, workers = _start(tmp_path, *POOL)
    assert len(workers) >= 2
    proc.kill()  # SIGKILL: no handler runs in the parent
    proc.communicate(timeout=60)
    assert _wait_until(lambda: not any(_alive(w) for w in workers), 2.0), "orphans left"


class _Sleep:
    cost = 1.0

    def run(self):
        time.sleep(30)


def test_leaving_a_pool_on_an_exception_stops_its_workers_at_once():
    start = time.monotonic()
    with pytest.raises(ZeroDivisionError), open_workers(2) as workers:
        for _ in range(3):
            workers.executor.submit(time.sleep, 30)
        1 / 0
    assert time.monotonic() - start < 5.0  # not the tasks' 30 s
    assert not workers.executor._processes  # shut down


class _Fault:
    cost = 3.0  # the pool starts it first, beside a sleep

    def run(self):
        return {}["missing"]  # a fault, not a failed run


def test_a_fault_while_tasks_run_on_the_pool_stops_its_workers_at_once():
    start = time.monotonic()
    with pytest.raises(KeyError), open_workers(2) as workers:
        execute([_Sleep(), _Sleep(), _Fault()], workers)
    assert time.monotonic() - start < 5.0  # not the tasks' 30 s
    assert not workers.executor._processes


FULL_DISK = """
import errno, sys, time
from wpam_mj.infra.pool import open_workers
from wpam_mj.infra.termination import handle_signals

class Sleep:
    cost = 2.0
    def run(self):
        time.sleep(30)

class Large:  # a figure's records: more than a pipe's buffer once pickled
    cost = 1.0
    def __init__(self):
        self.payload = b"x" * 4_000_000
    def run(self):
        return len(self.payload)

try:
    with handle_signals(), open_workers(2) as workers:  # as the command line runs it
        for task in [Sleep(), Sleep(), *[Large() for _ in range(4)]]:
            workers.executor.submit(task.run)
        time.sleep(0.5)  # the feeder is now blocked on the full pipe to the busy workers
        raise OSError(errno.ENOSPC, "No space left on device")
except OSError as err:
    print(err, file=sys.stderr)
    sys.exit(1)
"""


def test_stopping_a_pool_with_cancelled_tasks_queued_raises_in_no_thread(monkeypatch):
    """Python 3.11's pool manager, finding its workers gone, set an exception on every
    queued task's future and raised InvalidStateError on the cancelled ones: a traceback
    from a thread after `wpam reproduce` had printed its one line (1 run in 10)."""
    import threading  # noqa: PLC0415

    raised = []
    monkeypatch.setattr(threading, "excepthook", lambda args: raised.append(args.exc_value))
    pool = WorkerPool(1)
    futures = [pool.submit(time.sleep, 30)] + [pool.submit(time.sleep, 0) for _ in range(20)]
    time.sleep(0.5)  # the first task runs; the rest wait beyond the call queue
    for f in futures[1:]:
        f.cancel()
    manager = pool._executor_manager_thread
    pool.stop()
    manager.join(10.0)
    assert not manager.is_alive() and raised == []
    assert sum(f.cancelled() for f in futures) >= 18 and all(f.done() for f in futures)


def test_a_pool_left_on_a_full_disk_with_large_tasks_queued_exits_at_once():
    """wpam reproduce --jobs 2 into a full disk hung at exit: the call queue's feeder was
    blocked writing a large task to stopped workers, and the interpreter joined it."""
    start = time.monotonic()
    proc = subprocess.run([sys.executable, "-c", FULL_DISK], capture_output=True, text=True,
                          timeout=20, env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert proc.returncode == 1 and proc.stderr.strip() == "[Errno 28] No space left on device"
    assert time.monotonic() - start < 10.0


def test_a_worker_pool_shut_down_after_a_signal_does_not_wait():
    with termination.handle_signals():
        executor = WorkerPool(2)
        executor.submit(time.sleep, 30)
        with pytest.raises(termination.Terminated):
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(5)  # the handler raises before this ends
        start = time.monotonic()
        executor.shutdown(wait=True)  # e.g. in a `finally` of code that owns the pool
        assert time.monotonic() - start < 2.0


def test_deferred_signals_are_raised_when_the_block_ends():
    with termination.handle_signals():
        with pytest.raises(termination.Interrupted), termination.deferred():
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(0.05)  # the handler has run and only recorded the signal
            termination.check()  # still deferred: no raise
            reached = True
        assert reached and termination.stopping()


def test_a_signal_during_a_wait_is_raised_between_its_polls(monkeypatch):
    """Raised inside `concurrent.futures.wait` (a Condition's wait), the handler's
    exception once left the Condition's lock released twice: "release unlocked lock"
    replaced a HungUp and `wpam synth` ended with status 1 (a .ci/run, pool-at-start
    SIGHUP). `termination.wait` takes it between polls instead."""
    inside = []

    def poll(futures, timeout, return_when):  # concurrent.futures.wait, with the signal
        try:
            os.kill(os.getpid(), signal.SIGHUP)
            time.sleep(0.05)  # the handler runs here
        except BaseException as error:
            inside.append(error)
            raise
        return set(), set(futures)

    monkeypatch.setattr(concurrent.futures, "wait", poll)
    with termination.handle_signals(), pytest.raises(termination.HungUp):
        termination.wait([concurrent.futures.Future()])
    assert inside == []


def test_check_raises_a_pending_signal_once_and_later_signals_only_record():
    with termination.handle_signals():
        with pytest.raises(termination.HungUp):
            os.kill(os.getpid(), signal.SIGHUP)
            time.sleep(5)
        os.kill(os.getpid(), signal.SIGTERM)  # during cleanup: must not raise
        time.sleep(0.05)
        termination.check()
    assert termination.stopped_by_signal()


def test_leaving_dask_workers_on_an_exception_cancels_instead_of_waiting():
    distributed = pytest.importorskip("distributed")
    from wpam_mj.infra.pool import open_workers  # noqa: PLC0415
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as cluster:
        start = time.monotonic()
        with pytest.raises(ZeroDivisionError), open_workers(1, cluster.scheduler_address) as w:
            w.executor.submit(time.sleep, 30)
            1 / 0
        assert time.monotonic() - start < 10.0  # not the task's 30 s


def _can_mount_tmpfs() -> bool:
    if shutil.which("unshare") is None:
        return False
    probe = subprocess.run(["unshare", "-rm", "sh", "-c", "mount -t tmpfs -o size=64k tmpfs /mnt"],
                           capture_output=True, timeout=10)
    return probe.returncode == 0


@pytest.mark.skipif(not _can_mount_tmpfs(), reason="needs unshare -rm and a tmpfs mount")
def test_reproduce_with_two_jobs_into_a_full_disk_exits_with_one_line(tmp_path):
    """The issue's case on a real full disk: a 300 kB tmpfs (in a private mount namespace).
    Before: 'No space left on device', then no exit (killed at 90 s)."""
    disk = tmp_path / "disk"
    disk.mkdir()
    script = (f"mount -t tmpfs -o size=300k tmpfs {disk} && exec {sys.executable} -m wpam_mj "
              f"reproduce --jobs 2 --out {disk}/o")
    start = time.monotonic()
    proc = subprocess.run(["unshare", "-rm", "sh", "-c", script], capture_output=True,
                          text=True, timeout=120, env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert proc.returncode == 1
    assert proc.stderr == "wpam: error: [Errno 28] No space left on device\n"
    assert time.monotonic() - start < 60


def test_a_signal_that_lands_on_another_thread_ends_the_main_threads_wait_at_once():
    """The kernel may deliver a stop signal to any thread; Python runs the handler in the
    main thread, which an unbounded wait on a lock never lets run until the work ends
    (seen: SIGHUP acted on 4.3 s late on a busy machine; with `concurrent.futures.wait`
    here the exception comes only when the worker is released, 3 s on)."""
    release, ident = threading.Event(), []

    def busy() -> None:
        ident.append(threading.get_ident())
        release.wait(3.0)

    with concurrent.futures.ThreadPoolExecutor(1) as threads:
        fut = threads.submit(busy)
        try:
            with termination.handle_signals():
                assert _wait_until(lambda: bool(ident), 10.0)
                threading.Timer(0.2, signal.pthread_kill, (ident[0], signal.SIGTERM)).start()
                sent = time.monotonic()
                with pytest.raises(termination.Terminated):
                    termination.wait([fut])
                took = time.monotonic() - sent
        finally:
            release.set()
    assert took < EXIT_WITHIN_S, f"{took:.2f} s from the signal to the exception"
