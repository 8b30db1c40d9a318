"""SIGTERM handled like Ctrl-C: workers stopped, temporary files removed, one line, exit 143.

`kill PID` signals only the command's own process, not its pool workers (Ctrl-C reaches
the whole process group). `terminate_on_sigterm` makes SIGTERM raise `Terminated` (a
KeyboardInterrupt, so every cleanup that Ctrl-C runs runs too, e.g. `write_atomic`
removing its temporary file) after passing the signal on to the worker processes. A worker
(a forked child, which inherits the handler) dies of the signal at once; the temporary
file it was writing, if any, is removed by `remove_dead_temporaries` once the pool is down.
"""

from __future__ import annotations

import contextlib
import multiprocessing
import os
import re
import signal
import threading
from concurrent.futures import InvalidStateError
from pathlib import Path
from typing import Iterator

from wpam_mj.results import _process_exists

# write_atomic's temporary names: ".<name>.wpam<pid>-<random><suffix>"
_TEMPORARY = re.compile(r"\..+\.wpam(\d+)-\w+(\.\w+)?")


class Terminated(KeyboardInterrupt):
    """SIGTERM received (exit status 143 = 128 + SIGTERM)."""


@contextlib.contextmanager
def terminate_on_sigterm() -> Iterator[None]:
    """Within the block, SIGTERM raises `Terminated` in this process and stops its
    children; the previous handler comes back afterwards. Only in the main thread (where
    Python runs signal handlers); elsewhere a no-op."""
    try:
        previous = signal.signal(signal.SIGTERM, _handler(os.getpid()))
    except ValueError:  # not the main thread
        yield
        return
    hook = threading.excepthook
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)
        threading.excepthook = hook


def _handler(main_pid: int):
    def on_sigterm(signum, frame) -> None:
        if os.getpid() != main_pid:  # a forked pool worker: die of the signal
            signal.signal(signal.SIGTERM, signal.SIG_DFL)
            os.kill(os.getpid(), signal.SIGTERM)
            return
        threading.excepthook = _quiet_broken_pool
        for child in multiprocessing.active_children():
            child.terminate()
        raise Terminated
    return on_sigterm


def _quiet_broken_pool(hook_args) -> None:
    """After SIGTERM, a process pool whose futures were just cancelled finds its workers
    gone and, in Python 3.11, fails to mark the cancelled futures broken
    (InvalidStateError in its manager thread). That is the expected end of the pool, not
    an error worth a traceback; anything else goes to the default hook."""
    if not issubclass(hook_args.exc_type, InvalidStateError):
        threading.__excepthook__(hook_args)


def remove_dead_temporaries(folder: str | Path) -> list[Path]:
    """Delete write_atomic's temporary files under `folder` whose writer has exited;
    returns them. A live process's file is kept (a concurrent run is not disturbed)."""
    removed = []
    for path in Path(folder).rglob(".*.wpam*"):
        match = _TEMPORARY.fullmatch(path.name)
        if match and path.is_file() and not _process_exists(int(match.group(1))):
            path.unlink(missing_ok=True)
            removed.append(path)
    return removed

