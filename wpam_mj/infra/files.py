"""Files written whole or not at all, and the temporary files of writers that died.

A file another program or person reads (a CSV, a figure, a manifest) is either the old
one or the complete new one, never half written: `write_atomic` writes beside it and
renames over it.
"""

from __future__ import annotations

import csv
import glob
import io
import os
import re
import tempfile
from pathlib import Path
from typing import Any, Callable, Iterable, Mapping, Sequence

import numpy as np


def write_atomic(path: str | Path, write: Callable[[Path], None]) -> Path:
    """Write a file whole or not at all: `write(tmp)` then rename over `path`.

    The temporary file sits beside `path` as ``.<name>.wpam<pid>-<random><suffix>``. A
    process killed before the rename (SIGKILL, or a helper such as ffmpeg finishing the
    file after its parent died) leaves it behind under that hidden name, never under
    `path`; the next write of `path` removes such files whose process has gone.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    _remove_stale_temporaries(path)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.wpam{os.getpid()}-",
                               suffix=path.suffix)
    os.close(fd)
    umask = os.umask(0)
    os.umask(umask)
    try:
        os.chmod(tmp, 0o666 & ~umask)  # mkstemp makes 0600; give the usual permissions
        write(Path(tmp))
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def _remove_stale_temporaries(path: Path) -> None:
    """Delete write_atomic's leftovers for `path` whose writing process no longer exists.

    A live process's file is kept: a concurrent writer of the same path is not disturbed.
    """
    pattern = re.compile(rf"\.{re.escape(path.name)}\.wpam(\d+)-\w+{re.escape(path.suffix)}")
    for candidate in path.parent.glob(f".{glob.escape(path.name)}.wpam*"):
        match = pattern.fullmatch(candidate.name)
        if match and not _process_exists(int(match.group(1))):
            candidate.unlink(missing_ok=True)


def _process_exists(pid: int) -> bool:
    try:
        os.kill(pid, 0)  # signal 0: existence check only
    except ProcessLookupError:
        return False
    except (PermissionError, OverflowError):  # another user's process / not a pid
        return True
    return True


def write_text_atomic(path: str | Path, text: str) -> Path:
    return write_atomic(path, lambda p: p.write_text(text))


def exact_cell(value: Any) -> str:
    """CSV text that reads back to the same value (repr of a float is exact; numpy's
    scalars are written as the Python values they hold, not as 'np.float64(...)')."""
    if isinstance(value, (bool, np.bool_)):
        return "true" if value else "false"
    return repr(float(value)) if isinstance(value, (float, np.floating)) else str(value)


def csv_text(rows: Iterable[Mapping[str, Any]], columns: Sequence[str] | None = None,
             cell: Callable[[Any], Any] = exact_cell) -> str:
    """`rows` as CSV under one header line: `columns`, or every key of the rows in the
    order first seen (a key a row lacks: an empty cell)."""
    rows = list(rows)
    columns = list(columns or dict.fromkeys(k for r in rows for k in r))
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(columns)
    writer.writerows([cell(row[c]) if c in row else "" for c in columns] for row in rows)
    return buf.getvalue()
