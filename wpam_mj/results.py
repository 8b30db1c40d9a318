"""Result objects: recorded time series, exported as CSV (display units) or NPZ (SI)."""

from __future__ import annotations

import io
import os
import tempfile
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Callable

import numpy as np

from wpam_mj.params import MM, MPA


def write_atomic(path: str | Path, write: Callable[[Path], None]) -> Path:
    """Write a file whole or not at all: `write(tmp)` then rename over `path`."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=path.suffix)
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

    def arrays(self) -> dict[str, np.ndarray]:
        return {f.name: getattr(self, f.name) for f in fields(self)
                if isinstance(getattr(self, f.name), np.ndarray)}

    def to_csv_text(self) -> str:
        buf = io.StringIO()
        buf.write(f"# load_n={self.load:g} dt_s={self.dt:g} control={self.control} "
                  f"preset={self.preset}\n")
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
