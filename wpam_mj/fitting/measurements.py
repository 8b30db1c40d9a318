"""Measured experiments: the CSV format `wpam fit` reads and `wpam synth` writes.

One file per experiment (a static ramp, a step run, a sine, any mix), comma-separated,
lines starting with '#' ignored, then a header row naming the columns (any order; other
columns are ignored):

    time_s      sample time [s], strictly increasing
    load_n      hanging load [N], the same on every row (one load per experiment)
    pi_mpa      inner-chamber gauge pressure as read at its regulator [MPa]
    po_mpa      outer-chamber gauge pressure as read at its regulator [MPa]
    x_mm        contraction [mm], positive = shorter muscle
  optional:
    pi_cmd_mpa  Pi regulator command [MPa]
    po_cmd_mpa  Po regulator command [MPa]
    x_ref_mm    target contraction of a feedback run [mm] (shown, not replayed)

Every value must be a finite number (an empty cell or NaN is a gap and is refused), except
x_ref_mm, which may be empty where there is no target. `read_experiment` refuses, with one
line naming the file, line and column, data that are malformed or physically impossible
for the muscle it will be fitted to: a missing column, time not increasing, pressures that
look like kPa or lie outside the regulator range, contraction beyond the braid's limit.

Inside, an `Experiment` holds SI arrays (s, N, Pa, m).
"""

from __future__ import annotations

import io
import math
from array import array
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from wpam_mj.physics.geometry import BraidGeometry
from wpam_mj.simulation.context import check_load
from wpam_mj.infra.budget import check_duration
from wpam_mj.physics.params import Params
from wpam_mj.errors import ParameterError, check_regular_file, file_kind
from wpam_mj.units import MM, MPA
from wpam_mj.infra.files import write_text_atomic

REQUIRED = ("time_s", "load_n", "pi_mpa", "po_mpa", "x_mm")
OPTIONAL = ("pi_cmd_mpa", "po_cmd_mpa", "x_ref_mm")
# column -> (Experiment field, factor from the column's unit to SI)
_UNITS = {"time_s": ("time", 1.0), "load_n": ("load", 1.0), "pi_mpa": ("pi", MPA),
          "po_mpa": ("po", MPA), "x_mm": ("x", MM), "pi_cmd_mpa": ("pi_cmd", MPA),
          "po_cmd_mpa": ("po_cmd", MPA), "x_ref_mm": ("x_ref", MM)}

MIN_ROWS = 10
# Tolerances for measured (noisy) values against hard limits: a gauge reading may pass a
# limit by sensor noise, not by more (2 % of the ITV2031's 0.5 MPa span; 1 mm of x).
PRESSURE_TOL = 0.01 * MPA  # Pa
CONTRACTION_TOL = 1.0 * MM  # m
MIN_CONTRACTION = -5.0 * MM  # m: a hanging muscle cannot stretch this far past its length
LOAD_RTOL = 0.01  # one load per file: rows agree within 1 %
KPA_LOOKALIKE = 10.0  # MPa: a gauge column above this is in kPa or Pa, not MPa
MAX_SAMPLE_INTERVAL = 1.0  # s: a median step above this means time is not in seconds


@dataclass(frozen=True)
class Experiment:
    """One measured run, SI units; arrays of shape (n,).

    time [s]; load [N]; pi, po regulator gauge pressures [Pa]; x contraction [m];
    pi_cmd, po_cmd regulator commands [Pa] or None; x_ref target [m] (NaN where none) or None;
    path the file it was read from (None when made in memory).
    """

    name: str
    load: float
    time: np.ndarray
    pi: np.ndarray
    po: np.ndarray
    x: np.ndarray
    pi_cmd: np.ndarray | None = None
    po_cmd: np.ndarray | None = None
    x_ref: np.ndarray | None = None
    path: Path | None = None  # the file it was read from

    @property
    def has_commands(self) -> bool:
        """Both regulator commands were recorded (the replay then uses them)."""
        return self.pi_cmd is not None and self.po_cmd is not None

    @property
    def duration(self) -> float:
        return float(self.time[-1] - self.time[0])

    def to_csv_text(self) -> str:
        cols = [c for c in (*REQUIRED, *OPTIONAL)
                if c == "load_n" or getattr(self, _UNITS[c][0]) is not None]
        buf = io.StringIO()
        buf.write(f"# {self.name}: measurement format of wpam_mj.fitting.measurements\n")
        buf.write(",".join(cols) + "\n")
        table = np.column_stack([
            np.full(len(self.time), self.load) if c == "load_n"
            else getattr(self, _UNITS[c][0]) / _UNITS[c][1] for c in cols])
        fmt = ",".join("%.9g" if c == "time_s" else "%.6g" for c in cols) + "\n"
        data = "".join(fmt % tuple(row) for row in table.tolist())
        buf.write(data.replace("nan", ""))  # an empty x_ref_mm cell: no target there
        return buf.getvalue()

    def to_csv(self, path: str | Path) -> Path:
        """Write the experiment in the measurement format, whole or not at all."""
        return write_text_atomic(path, self.to_csv_text())


def read_experiment(path: str | Path, params: Params) -> Experiment:
    """Read and check one measurement CSV against the muscle `params` (regulator range,
    braid limit). Raises ParameterError with one line naming file, line and column, or
    saying that the file is too large for the memory this process may use."""
    path = check_regular_file(path, "measurement file")
    try:
        cols, where = _read_columns(path)
        _check(cols, params, where)
        check_duration(f"{path} (rows from {cols['time_s'][0]:g} to {cols['time_s'][-1]:g} s)",
                       float(cols["time_s"][-1] - cols["time_s"][0]))
        si = {_UNITS[c][0]: v * _UNITS[c][1] for c, v in cols.items()}
    except (OSError, UnicodeDecodeError) as err:
        raise ParameterError(f"{path}: cannot read ({getattr(err, 'strerror', None) or err})") \
            from None
    except MemoryError:
        raise ParameterError(f"{path}: {path.stat().st_size / 1e6:.0f} MB of data does not fit "
                             "in the memory this process may use; split the experiment into "
                             "shorter files") from None
    load = float(si.pop("load")[0])
    return Experiment(name=path.stem, load=load, **si, path=path)


def _is_data(line: str) -> bool:
    """A line that is neither blank nor a '#' comment."""
    return bool(line.strip()) and not line.lstrip().startswith("#")


def _read_columns(path: Path) -> tuple[dict[str, np.ndarray], "_Where"]:
    """The known columns of the file as float arrays (x_ref_mm NaN in its gaps). Numbers
    are parsed by numpy straight into arrays (a file of millions of rows needs little more
    memory than its numbers); a file numpy refuses, or holding a gap or a non-finite
    value, is read again cell by cell to name the line and column at fault."""
    with path.open(encoding="utf-8") as fh:
        header_line, header = next(((i, ln) for i, ln in enumerate(fh, 1) if _is_data(ln)),
                                   (0, ""))
    if not header_line:
        raise ParameterError(f"{path}: no header row (expected columns {', '.join(REQUIRED)})")
    where = _Where(path, header_line)
    names = [h.strip() for h in header.split(",")]
    missing = [c for c in REQUIRED if c not in names]
    if missing:
        raise ParameterError(f"{where.at(header_line)}: missing column(s) {', '.join(missing)} "
                             f"(header has {', '.join(names)})")
    known = [c for c in (*REQUIRED, *OPTIONAL) if c in names]
    gaps = {names.index("x_ref_mm"): _number_or_gap} if "x_ref_mm" in names else None
    try:
        table = np.loadtxt(path, delimiter=",", comments="#", skiprows=header_line,
                           ndmin=2, converters=gaps, encoding="utf-8")
    except ValueError:
        table = None
    if table is not None and table.shape[1] == len(names):
        cols = {c: table[:, names.index(c)] for c in known}
        if all(np.isfinite(v).all() if c != "x_ref_mm" else not np.isinf(v).any()
               for c, v in cols.items()):
            if len(table) < MIN_ROWS:
                raise ParameterError(f"{path}: {len(table)} data rows; at least {MIN_ROWS} "
                                     "needed")
            return cols, where
    return _read_cells(path, names, known, where), where


def _number_or_gap(cell: str) -> float:
    """x_ref_mm's cells: an empty cell is a gap (NaN)."""
    return float(cell) if cell.strip() else math.nan


def _read_cells(path: Path, names: list[str], known: list[str],
                where: "_Where") -> dict[str, np.ndarray]:
    """The known columns, line by line into compact arrays, with one line naming the first
    bad row or cell."""
    index = {c: names.index(c) for c in known}
    out = {c: array("d") for c in known}
    rows = 0
    with path.open(encoding="utf-8") as fh:
        for n, ln in enumerate(fh, 1):
            if n <= where.header_line or not _is_data(ln):
                continue
            parts = ln.rstrip("\r\n").split(",")
            if len(parts) != len(names):
                raise ParameterError(f"{where.at(n)}: {len(parts)} values, the header has "
                                     f"{len(names)} columns")
            for c, i in index.items():
                out[c].append(_cell(parts[i], c, lambda: where.at(n, c)))
            rows += 1
    if rows < MIN_ROWS:
        raise ParameterError(f"{path}: {rows} data rows; at least {MIN_ROWS} needed")
    return {c: np.array(v) for c, v in out.items()}


class _Where:
    """Names a place in the file: `file line N column c`; data row i's line is found by
    reading the file again, only when an error names it."""

    def __init__(self, path: Path, header_line: int) -> None:
        self.path, self.header_line = path, header_line

    def at(self, line: int, column: str | None = None) -> str:
        return f"{self.path} line {line}" + (f" column {column}" if column else "")

    def row(self, i: int, column: str) -> str:
        with self.path.open(encoding="utf-8") as fh:
            data = (n for n, ln in enumerate(fh, 1) if n > self.header_line and _is_data(ln))
            return self.at(next(n for k, n in enumerate(data) if k == i), column)


def _cell(text: str, column: str, place: Callable[[], str]) -> float:
    """One cell's number; a gap (empty or NaN, then NaN) only in x_ref_mm. `place` names
    the cell in an error."""
    s = text.strip()
    if s == "" or s.lower() == "nan":
        if column != "x_ref_mm":
            raise ParameterError(f"{place()}: empty or NaN (a gap in the data; every row "
                                 "needs a value)")
        return math.nan
    try:
        value = float(s)
    except ValueError:
        raise ParameterError(f"{place()}: {s!r} is not a number") from None
    if not math.isfinite(value):
        raise ParameterError(f"{place()}: {s!r} is not a finite number")
    return value


def _check(cols: dict[str, np.ndarray], params: Params, where: _Where) -> None:
    """Refuse malformed or physically impossible data (see the module docstring)."""
    t = cols["time_s"]
    back = np.flatnonzero(np.diff(t) <= 0.0)
    if back.size:
        i = back[0] + 1
        raise ParameterError(f"{where.row(i, 'time_s')}: time {t[i]:g} s does not increase "
                             f"(previous row {t[i - 1]:g} s)")
    step = float(np.median(np.diff(t)))
    if step > MAX_SAMPLE_INTERVAL:
        raise ParameterError(f"{where.row(1, 'time_s')}: median sample interval {step:g} s "
                             f"exceeds {MAX_SAMPLE_INTERVAL:g} s; is time in ms? (seconds "
                             "expected)")
    load = cols["load_n"]
    check_load_cell(load[0], where.row(0, "load_n"))
    off = np.flatnonzero(np.abs(load - load[0]) > LOAD_RTOL * abs(load[0]))
    if off.size:
        i = off[0]
        raise ParameterError(f"{where.row(i, 'load_n')}: load {load[i]:g} N differs from the "
                             f"first row's {load[0]:g} N; one load per file")
    p_max = params.pneumatics.p_max
    for c in ("pi_mpa", "po_mpa", "pi_cmd_mpa", "po_cmd_mpa"):
        if c not in cols:
            continue
        v = cols[c] * MPA
        tol = 0.0 if "cmd" in c else PRESSURE_TOL
        i = int(np.argmax(v))
        if v[i] > KPA_LOOKALIKE * MPA:
            raise ParameterError(f"{where.row(i, c)}: {cols[c][i]:g} MPa; the column is in MPa "
                                 "(is it in kPa or Pa?)")
        if v[i] > p_max + tol:
            raise ParameterError(f"{where.row(i, c)}: {cols[c][i]:g} MPa is above the "
                                 f"regulator range [0, {p_max / MPA:g}] MPa "
                                 "(pneumatics.p_max)")
        i = int(np.argmin(v))
        if v[i] < -tol:
            raise ParameterError(f"{where.row(i, c)}: {cols[c][i]:g} MPa is below the "
                                 f"regulator range [0, {p_max / MPA:g}] MPa (gauge pressure)")
    x_max = BraidGeometry.from_params(params.braid).max_contraction
    for c in ("x_mm", "x_ref_mm"):
        if c not in cols:
            continue
        v = cols[c] * MM
        with np.errstate(invalid="ignore"):
            over = np.flatnonzero(v > x_max + CONTRACTION_TOL)
            under = np.flatnonzero(v < MIN_CONTRACTION)
        if over.size:
            i = over[0]
            raise ParameterError(f"{where.row(i, c)}: {cols[c][i]:g} mm is beyond the braid's "
                                 f"limit of {x_max / MM:.1f} mm contraction (the bag at "
                                 "braid.max_diameter)")
        if under.size:
            i = under[0]
            raise ParameterError(f"{where.row(i, c)}: {cols[c][i]:g} mm; contraction is "
                                 f"positive and at least {MIN_CONTRACTION / MM:g} mm (is the "
                                 "sign or the unit off?)")


def check_load_cell(value: float, where: str) -> float:
    try:
        return check_load(value)
    except ParameterError as err:
        raise ParameterError(f"{where}: {err}") from None


def experiment_files(paths: list[str | Path]) -> list[Path]:
    """The CSV files named by `paths`: files as given, folders by their *.csv (sorted)."""
    out: list[Path] = []
    for p in map(Path, paths):
        if file_kind(p) == "folder":
            found = sorted(p.glob("*.csv"))
            if not found:
                raise ParameterError(f"{p}: no *.csv files in this folder")
            out += found
        elif file_kind(p) == "missing":
            raise ParameterError(f"{p}: no such file or folder")
        else:
            out.append(check_regular_file(p, "measurement file"))
    if len({f.resolve() for f in out}) != len(out):
        raise ParameterError("the same file is given twice: " + ", ".join(map(str, out)))
    return out
