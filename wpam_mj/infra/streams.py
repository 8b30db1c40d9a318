"""The standard streams of a command started with one of them closed (`wpam ... >&-`).

Python then sets `sys.stdout` (or stdin, stderr) to None, and the next file the command
opens takes the free descriptor: a figure would be written where the shell expects
output, and a child such as ffmpeg would inherit it as its stdout. `reopen_closed` puts
/dev/null on every closed descriptor 0-2 before anything is opened, so printing goes
nowhere (as to a reader that has gone) and files get descriptors of their own.
"""

from __future__ import annotations

import os
import sys

_NAMES = ("stdin", "stdout", "stderr")


def reopen_closed() -> set[str]:
    """Attach /dev/null to each closed standard descriptor; the names of those closed."""
    closed = set()
    for fd, name in enumerate(_NAMES):
        try:
            os.fstat(fd)
        except OSError:
            closed.add(name)
    for name in sorted(closed, key=_NAMES.index):  # lowest first: open() takes the lowest
        fd = _NAMES.index(name)
        null = os.open(os.devnull, os.O_RDONLY if fd == 0 else os.O_WRONLY)
        if null != fd:
            os.dup2(null, fd)
            os.close(null)
        setattr(sys, name, open(fd, "r" if fd == 0 else "w", closefd=False))
    return closed
