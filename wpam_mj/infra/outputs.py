"""Output folders of one command: locked while it runs, gone again if it fails unused.

Two commands writing into one folder at once would interleave their files (a manifest
listing the other run's CSV). `claim` takes an exclusive lock on the folder itself
(`flock` on the directory: no lock file appears among the outputs) and holds it until
`release`, so a second command into the same folder waits (saying so once on stderr)
and then writes its whole set after the first. The kernel drops the lock when the
process dies, however it dies.

A command refused, failed or stopped must leave neither temporary files nor an empty
folder behind: `claim` remembers the folders it had to create, and `release(failed=True)`
removes the dead writers' temporary files and those folders still empty.
"""

from __future__ import annotations

import fcntl
import os
import sys
import tempfile
from pathlib import Path

from wpam_mj.errors import ParameterError
from wpam_mj.infra.termination import remove_dead_temporaries

_held: dict[Path, int | None] = {}  # resolved folder -> the descriptor holding its lock
# (None: a folder that cannot be locked)
_created: list[Path] = []  # folders claim made, parents before children


def claim(path: str | Path, name: str = "--out") -> Path:
    """Create `path` if needed, check that files can be written in it and lock it for
    this command (waiting while another holds it); returns `path`."""
    path = Path(path)
    try:
        _created.extend(_make_dirs(path))
        with tempfile.TemporaryFile(dir=path):
            pass
        _lock(path)
    except OSError as err:
        raise ParameterError(f"{name} {path}: cannot write there "
                             f"({err.strerror or err})") from None
    return path


def release(failed: bool) -> None:
    """Unlock every claimed folder; after a failure (or a signal), first remove the
    temporary files of writers that died (stopped pool workers), then the folders this
    command created that are still empty."""
    for folder, fd in _held.items():
        if failed:
            remove_dead_temporaries(folder)
        if fd is not None:
            os.close(fd)  # closing the last descriptor drops the flock
    _held.clear()
    if failed:
        for folder in reversed(_created):
            try:
                folder.rmdir()  # only if empty
            except OSError:
                pass
    _created.clear()


def _make_dirs(path: Path) -> list[Path]:
    """mkdir -p `path`; the folders it created, outermost first."""
    missing = [p for p in (path, *path.parents) if not p.exists()][::-1]
    path.mkdir(parents=True, exist_ok=True)
    return missing


def _lock(path: Path) -> None:
    key = path.resolve()
    if key in _held:  # a second file of this command in the same folder
        return
    try:
        fd = os.open(key, os.O_RDONLY | os.O_DIRECTORY)
    except OSError as err:  # e.g. a folder we may write but not list
        _held[key] = _unlocked(path, err)
        return
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            print(f"wpam: waiting for another wpam command writing to {path}",
                  file=sys.stderr, flush=True)
            fcntl.flock(fd, fcntl.LOCK_EX)  # a signal interrupts the wait (PEP 475)
    except OSError as err:  # no locks on this file system (e.g. some NFS mounts)
        os.close(fd)
        _held[key] = _unlocked(path, err)
        return
    except BaseException:
        os.close(fd)
        raise
    _held[key] = fd


def _unlocked(path: Path, err: OSError) -> None:
    """Write without the lock where the folder cannot be locked: say so; None."""
    print(f"wpam: note: cannot lock {path} ({err.strerror or err}); another command "
          "writing there at the same time could mix its files with these", file=sys.stderr)
