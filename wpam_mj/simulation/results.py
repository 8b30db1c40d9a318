"""Result objects: recorded time series, exported as CSV (display units) or NPZ (SI)."""

from __future__ import annotations

import glob
import io
import os
import re
import tempfile
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Callable

import numpy as np

from wpam_mj.physics.params import MM, MPA, ParameterError


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


_CSV_BLOCK_ROWS = 4096

# (field, CSV column, scale from SI to the display unit)
_COLUMNS = (
    ("time", "time_s", 1.0),
    ("x", "x_mm", 1 / MM),
    ("x_ref", "x_ref_mm", 1 / MM),
    ("velocity", "velocity_mm_s", 1 / MM),
    ("pi", "pi_mpa", 1 / MPA),
    ("po", "po_mpa", 1 / MPA),
    ("pi_cmd", "pi_cmd_mpa", 1 / MPA),
    ("po_cmd", "po_cmd_mpa", 1 / MPA),
    ("tension", "tension_n", 1.0),
    ("friction", "friction_n", 1.0),
    ("pi_reg", "pi_reg_mpa", 1 / MPA),
    ("po_reg", "po_reg_mpa", 1 / MPA),
)


@dataclass(frozen=True)
class SimResult:
    """One run, sampled every record_dt. Arrays have shape (n_samples,), SI units.

    time [s], x contraction [m], velocity [m/s], x_ref target [m] (NaN in open loop),
    pi/po chamber gauge pressures [Pa], pi_cmd/po_cmd regulator commands [Pa],
    tension frictionless muscle tension [N], friction dry-friction level [N],
    pi_reg/po_reg the regulators' outlet pressures [Pa] (what the ITV2031's own gauge reads,
    the pressures the paper plots), before the line restriction into the chambers.
    """

    time: np.ndarray
    x: np.ndarray
    velocity: np.ndarray
    x_ref: np.ndarray
    pi: np.ndarray
    po: np.ndarray
    pi_cmd: np.ndarray
    po_cmd: np.ndarray
    tension: np.ndarray
    friction: np.ndarray
    pi_reg: np.ndarray
    po_reg: np.ndarray
    load: float
    dt: float
    control: str
    preset: str

    def __post_init__(self) -> None:
        n = len(np.atleast_1d(self.time))
        for f in fields(self):
            if f.type != "np.ndarray":
                continue
            arr = np.asarray(getattr(self, f.name), dtype=float)
            if arr.shape != (n,):
                raise ParameterError(f"SimResult.{f.name} has shape {arr.shape}; every series "
                                     f"must have the shape of time, ({n},)")
            object.__setattr__(self, f.name, arr)
        if n == 0:
            raise ParameterError("SimResult has no samples (a run of zero duration)")

    def arrays(self) -> dict[str, np.ndarray]:
        return {f.name: getattr(self, f.name) for f in fields(self)
                if isinstance(getattr(self, f.name), np.ndarray)}

    def metadata(self) -> dict[str, float | int | str]:
        """What the CSV does not hold, for the run's manifest (`wpam_mj.infra.manifest`)."""
        return {"load_n": self.load, "dt_s": self.dt, "control": self.control,
                "preset": self.preset, "samples": len(self.time)}

    def to_csv_text(self) -> str:
        """One header line of column names (unit in the name), then one row per sample.

        No comment lines, so ``np.genfromtxt(f, delimiter=",", names=True)`` and
        ``pandas.read_csv(f)`` read it as it is; `metadata` goes into the manifest.
        """
        buf = io.StringIO()
        buf.write(",".join(c for _, c, _ in _COLUMNS) + "\n")
        table = np.column_stack([getattr(self, f) * s for f, _, s in _COLUMNS])
        # one %-format per block of rows: as np.savetxt(fmt="%.6g") writes, ~2x faster
        row = ",".join(["%.6g"] * table.shape[1]) + "\n"
        for start in range(0, len(table), _CSV_BLOCK_ROWS):
            block = table[start:start + _CSV_BLOCK_ROWS]
            buf.write((row * len(block)) % tuple(block.ravel().tolist()))
        return buf.getvalue()

    def to_csv(self, path: str | Path) -> Path:
        """CSV with columns in display units (s, mm, MPa, N)."""
        return write_text_atomic(path, self.to_csv_text())

    def to_npz(self, path: str | Path) -> Path:
        """NPZ of the SI arrays plus metadata."""
        def write(p: Path) -> None:
            with open(p, "wb") as fh:
                np.savez(fh, **self.arrays(), load=self.load, dt=self.dt,
                         control=self.control, preset=self.preset)
        return write_atomic(path, write)
