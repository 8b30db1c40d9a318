"""Result objects: recorded time series, exported as CSV (display units)."""

from __future__ import annotations

import io
from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np

from wpam_mj.infra.files import write_text_atomic
from wpam_mj.errors import ParameterError
from wpam_mj.simulation.context import InContext, RunContext
from wpam_mj.units import MM, MPA

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
class SimResult(InContext):
    """One run, sampled every record_dt. Arrays have shape (n_samples,), SI units.

    time [s], x contraction [m], velocity [m/s], x_ref target [m] (NaN in open loop),
    pi/po chamber gauge pressures [Pa], pi_cmd/po_cmd regulator commands [Pa],
    tension frictionless muscle tension [N], friction dry-friction level [N],
    pi_reg/po_reg the regulators' outlet pressures [Pa] (what the ITV2031's own gauge reads,
    the pressures the paper plots), before the line restriction into the chambers.
    `context`: what the run was made with (parameters, dt, load, controller); `load`,
    `dt`, `control` and `preset` read it.
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
    context: RunContext

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
