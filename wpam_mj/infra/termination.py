"""Signals: SIGINT, SIGTERM and SIGHUP end a command at once, with one line and its status.

`handle_signals` installs one handler for the three. The first signal raises its
exception (`Interrupted` for SIGINT, `Terminated`, `HungUp`; all KeyboardInterrupts, so
every cleanup that Ctrl-C runs runs too, e.g. `write_atomic` removing its temporary file)
in the main thread; later signals only record themselves, so that the cleanup they
interrupt is not itself interrupted. Inside `deferred()` (e.g. while a process pool
starts, whose half-made state cannot be torn down) a signal is recorded and raised when
the block ends.

A loop that runs long in compiled code without returning to Python calls `check()`
between chunks: it costs one attribute read, and raises the pending signal's exception.
The main thread waits for other threads' or processes' work with `wait`, never an
unbounded wait: the kernel may deliver a signal to any thread of the process, and one
that lands on another thread (a pool's manager, a batch thread) does not wake the main
thread from a lock, where Python runs every handler.
Pool workers (`wpam_mj.infra.pool.WorkerPool`) ignore SIGINT and die of SIGTERM; the process
that started them stops them (`stopping()` tells it not to wait for their tasks).
"""

from __future__ import annotations

import concurrent.futures
import contextlib
import os
import re
import signal
import sys
import threading
from pathlib import Path
from typing import Iterable, Iterator

from wpam_mj.infra.files import _process_exists

SIGNAL_POLL_S = 0.1  # our choice: how late a signal landing on another thread is acted on

# write_atomic's temporary names: ".<name>.wpam<pid>-<random><suffix>"
_TEMPORARY = re.compile(r"\..+\.wpam(\d+)-\w+(\.\w+)?")


class Interrupted(KeyboardInterrupt):
    """SIGINT received (exit status 130 = 128 + SIGINT)."""

    status, message = 130, "interrupted"


class Terminated(Interrupted):
    """SIGTERM received (exit status 143 = 128 + SIGTERM)."""

    status, message = 143, "terminated"


class HungUp(Interrupted):
    """SIGHUP received, e.g. the terminal closed (exit status 129 = 128 + SIGHUP)."""

    status, message = 129, "hung up"


_EXCEPTIONS = {getattr(signal, name): exc for name, exc in  # no SIGHUP on Windows
               (("SIGINT", Interrupted), ("SIGTERM", Terminated), ("SIGHUP", HungUp))
               if hasattr(signal, name)}
STOP_SIGNALS = tuple(sig for sig in _EXCEPTIONS if sig != signal.SIGINT)


class _State:
    """What the handler has seen, in this process (reset by `handle_signals`)."""

    def __init__(self) -> None:
        self.main_pid = os.getpid()
        self.pending: type[Interrupted] | None = None  # received, not yet raised
        self.raised = False  # the command is stopping: later signals are only noted
        self.defer = 0  # depth of `deferred()` blocks


_state = _State()
_last_signalled = False


def check() -> None:
    """Raise the exception of a signal received but not yet raised (see the docstring)."""
    if _state.pending is not None and not _state.raised and not _state.defer:
        _raise_pending()


def stopping() -> bool:
    """Whether a signal has been received: cleanup must not wait for running work."""
    return _state.pending is not None


def stopped_by_signal() -> bool:
    """Whether the last `handle_signals` block ended because of a signal."""
    return _last_signalled


def exit_now(status: int) -> None:
    """End the process with `status` once its own cleanup is done: flush the standard
    streams and skip the interpreter's teardown (about a second with MuJoCo and
    matplotlib loaded, on a busy machine), so that a signal ends it promptly."""
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):  # e.g. a closed pipe: nothing left to say
            stream.flush()
    os._exit(status)


def wait(futures: Iterable[concurrent.futures.Future],
         return_when: str = concurrent.futures.ALL_COMPLETED):
    """`concurrent.futures.wait` without a timeout, woken every SIGNAL_POLL_S so that the
    main thread runs a signal's handler at once wherever the signal landed (module
    docstring; unbounded, a busy machine saw SIGHUP acted on 2.7-4.3 s late)."""
    futures = list(futures)
    while True:
        # deferred: the handler's exception raised inside a Condition's wait can leave its
        # lock released twice (seen once: "release unlocked lock" replaced a HungUp, and
        # the command ended with status 1); raised between polls it is at most one late
        with deferred():
            done, not_done = concurrent.futures.wait(futures, SIGNAL_POLL_S, return_when)
        if not not_done or (return_when == concurrent.futures.FIRST_COMPLETED and done) or (
                return_when == concurrent.futures.FIRST_EXCEPTION and any(
                    not f.cancelled() and f.exception() is not None for f in done)):
            return done, not_done


@contextlib.contextmanager
def deferred() -> Iterator[None]:
    """A block no signal interrupts; a signal received inside is raised when it ends."""
    _state.defer += 1
    try:
        yield
    finally:
        _state.defer -= 1
    check()


@contextlib.contextmanager
def handle_signals() -> Iterator[None]:
    """Within the block, SIGINT, SIGTERM and SIGHUP raise their exception in this process
    (see the module docstring); the previous handlers come back afterwards. Only in the
    main thread (where Python runs signal handlers); elsewhere a no-op."""
    global _state, _last_signalled
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    _state = _State()
    _last_signalled = False
    previous = {sig: signal.signal(sig, _on_signal) for sig in _EXCEPTIONS}
    hook = threading.excepthook
    threading.excepthook = _quiet_broken_pool
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        threading.excepthook = hook
        _last_signalled = _state.pending is not None
        _state = _State()


class RequirementError(ImportError):
    """A dependency the package cannot run with (e.g. a MuJoCo older than the pinned one)."""

    status = 1


@contextlib.contextmanager
def importing(package: str) -> Iterator[None]:
    """The import of `package` (the heavy imports and the plugin's build), ended cleanly by
    a signal or a missing requirement.

    In the main thread, SIGINT, SIGTERM and SIGHUP whose handlers are Python's defaults
    raise `Interrupted`, `Terminated` and `HungUp` within the block, so that what the
    import started is undone on the way out (the compiler's process group killed, its
    build folder removed); the previous handlers come back afterwards. Such an exception,
    or a `RequirementError`, leaving the block is raised on (a program may catch it); if
    nothing does, the process ends with one line ("<package>: terminated", or what the
    requirement needs) and the signal's status (130, 143, 129; 1 for a requirement)
    instead of a traceback. An
    interactive session (the REPL) keeps its usual KeyboardInterrupt.
    """
    global _state
    mine = {sig for sig in _EXCEPTIONS if signal.getsignal(sig) in (
        signal.default_int_handler, signal.SIG_DFL)}
    if threading.current_thread() is not threading.main_thread():
        mine = set()
    if mine:
        _state = _State()
    previous = {sig: signal.signal(sig, _on_signal) for sig in mine}
    try:
        yield
        if mine and _state.pending is not None:
            # raised inside an extension module's initialisation, which swallowed it
            # (measured: MuJoCo's pybind11 modules), so the import went on
            raise _state.pending()
    except BaseException as error:
        stop = error
        if mine and _state.pending is not None and not isinstance(error, Interrupted):
            stop = _state.pending()  # e.g. wrapped in an extension module's ImportError
        if isinstance(stop, RequirementError) or (mine and isinstance(stop, Interrupted)):
            _end_uncaught(package, stop)
        if stop is error:
            raise
        raise stop from None
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        if mine:
            _state = _State()


def _end_uncaught(package: str, stop: BaseException) -> None:
    """Have `stop`, if nothing catches it, end the process with one line and its status."""
    hook = sys.excepthook
    interactive = hasattr(sys, "ps1") or sys.flags.interactive

    def one_line(exc_type, value, tb) -> None:
        sys.excepthook = hook
        if value is not stop or (interactive and type(stop) is Interrupted):
            hook(exc_type, value, tb)
            return
        text = f"{package}: {stop.message}" if isinstance(stop, Interrupted) else str(stop)
        print(" ".join(text.split()), file=sys.stderr)
        exit_now(stop.status)

    sys.excepthook = one_line


def _on_signal(signum, frame) -> None:
    if os.getpid() != _state.main_pid:  # a forked child that kept the handler: die of it
        signal.signal(signum, signal.SIG_DFL)
        os.kill(os.getpid(), signum)
        return
    if _state.pending is None:
        _state.pending = _EXCEPTIONS[signal.Signals(signum)]
    check()


def _raise_pending() -> None:
    _state.raised = True
    raise _state.pending


def _quiet_broken_pool(hook_args) -> None:
    """A process pool whose workers were just stopped fails, in Python 3.11, to mark its
    cancelled futures broken (InvalidStateError in its manager thread). That is the
    expected end of the pool, not an error worth a traceback; anything else goes to the
    default hook."""
    from concurrent.futures import InvalidStateError  # noqa: PLC0415 (light at import)

    if not issubclass(hook_args.exc_type, InvalidStateError):
        threading.__excepthook__(hook_args)


def remove_dead_temporaries(folder: str | Path) -> list[Path]:
    """Delete write_atomic's temporary files in `folder` and its subfolders (one level,
    where the commands write: parts/, plots/, holdout/) whose writer has exited; returns
    them. A live process's file is kept (a concurrent run is not disturbed). Not deeper:
    `folder` may be a large tree (calibrate writes into the current folder)."""
    removed = []
    folder = Path(folder)
    for path in (*folder.glob(".*.wpam*"), *folder.glob("*/.*.wpam*")):
        match = _TEMPORARY.fullmatch(path.name)
        if match and path.is_file() and not _process_exists(int(match.group(1))):
            path.unlink(missing_ok=True)
            removed.append(path)
    return removed
