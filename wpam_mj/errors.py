"""Bad input: the one error the package raises for it, and the checks that raise it
(ranges, integers, whole multiples of a step, regular files, TOML files), each with a
one-line message naming the value and what is allowed. A base module: it imports no
other part of the package."""

from __future__ import annotations

import math
import numbers
import os
import stat
import tomllib
from pathlib import Path
from typing import Any

import numpy as np



class ParameterError(ValueError):
    """A parameter or input lies outside its allowed range."""


def shown(value: Any) -> str:
    """A value as a message shows it: numpy scalars as the Python number they hold
    (-100.0, not np.float64(-100.0)), anything else as its repr."""
    if isinstance(value, np.generic):
        value = value.item()
    return repr(value)


def check_range(name: str, value: float, lo: float, hi: float, unit: str = "", *,
                lo_open: bool = False) -> float:
    """Return ``float(value)`` or raise ParameterError naming the value and the range
    (or saying that no value is allowed when a computed range is empty). A unitless
    value ("1", the parameter tables' unit of a ratio) is shown without a unit."""
    unit = "" if unit == "1" else unit
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ParameterError(f"{name} = {shown(value)} is not a number") from None
    if not lo <= hi:
        raise ParameterError(f"{name} = {shown(value)} {unit}: no value is allowed (the "
                             f"lower bound {lo:g} is above the upper {hi:g})")
    below = v <= lo if lo_open else v < lo
    if not math.isfinite(v) or below or v > hi:
        bracket = "(" if lo_open else "["
        raise ParameterError(f"{name} = {shown(value)} {unit} is outside the allowed range "
                             f"{bracket}{lo:g}, {hi:g}] {unit}".replace("  ", " "))
    return v


def is_number(value: Any) -> bool:
    """A real number that is not a bool: TOML strings ("0.1") and booleans are refused,
    although float() would accept them."""
    return isinstance(value, numbers.Real) and not isinstance(value, bool)


def check_int(name: str, value: Any, lo: int, hi: int) -> int:
    """An integer (not a bool) in [lo, hi], else ParameterError naming it and the range."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral) or \
            not lo <= value <= hi:
        raise ParameterError(f"{name} = {shown(value)} must be an integer in [{lo}, {hi}]")
    return int(value)


def whole_steps(period: float, step: float) -> int:
    """How many `step`s make `period` (both [s]); 0 when that is not a whole number of
    them (to 1e-9 of the period): the one test of "a whole multiple of dt"."""
    n = round(period / step)
    return n if n >= 1 and abs(n * step - period) <= 1e-9 * period else 0


def check_whole_steps(name: str, period: float, dt: float) -> int:
    """The steps of `dt` [s] in the period `name` [s]; ParameterError unless whole."""
    n = whole_steps(period, dt)
    if not n:
        raise ParameterError(f"{name} = {period} s must be a whole multiple of dt = {dt} s")
    return n


MAX_TOML_BYTES = 1_000_000  # a parameter file is a few hundred bytes


def file_kind(path: str | Path) -> str:
    """"file", "folder", "missing", or what else `path` is (a named pipe, a device, a
    socket): read only a "file" (opening a named pipe waits for a writer; a device may
    never end)."""
    try:
        mode = os.stat(path).st_mode
    except FileNotFoundError:
        return "missing"
    except OSError as err:
        return f"unreadable ({err.strerror or err})"
    if stat.S_ISREG(mode):
        return "file"
    if stat.S_ISDIR(mode):
        return "folder"
    if stat.S_ISFIFO(mode):
        return "named pipe"
    if stat.S_ISCHR(mode) or stat.S_ISBLK(mode):
        return "device"
    return "socket" if stat.S_ISSOCK(mode) else "special file"


def check_regular_file(path: str | Path, what: str) -> Path:
    """`path` if it is a regular file, else ParameterError saying what it is."""
    kind = file_kind(path)
    if kind == "missing":
        raise ParameterError(f"{what} {path}: no such file")
    if kind != "file":
        raise ParameterError(f"{what} {path} is a {kind}, not a regular file")
    return Path(path)


def load_toml(path: str | Path, what: str = "parameter file") -> dict[str, Any]:
    """Read a TOML file (UTF-8, <= 1 MB): a parameter file (sections as in `Params`, SI
    values) unless `what` names another kind (for messages, e.g. "study file")."""
    check_regular_file(path, what)
    try:
        with open(path, "rb") as fh:
            data = fh.read(MAX_TOML_BYTES + 1)  # bounded: a huge file stops here
    except OSError as err:
        raise ParameterError(f"cannot read {what} {path}: "
                             f"{err.strerror or err}") from None
    if len(data) > MAX_TOML_BYTES:
        raise ParameterError(f"{what} {path} is larger than the allowed "
                             f"{MAX_TOML_BYTES / 1e6:g} MB")
    try:
        return tomllib.loads(data.decode("utf-8"))
    except UnicodeDecodeError as err:
        line = data[:err.start].count(b"\n") + 1
        raise ParameterError(f"{what} {path} is not UTF-8 text: byte "
                             f"0x{data[err.start]:02x} on line {line}") from None
    except tomllib.TOMLDecodeError as err:
        raise ParameterError(f"malformed TOML in {path}: {err}") from None
