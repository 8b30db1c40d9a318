"""Optional compiled simulation loop: `_fastloop.c`, built with gcc at first use.

`run_compiled` is a drop-in for `wpam_mj.simulate.run_python` (same arguments, same
return convention, bit-identical results; tests/test_fastloop.py checks this) that runs
the whole loop, mj_step included, in C, for the controllers the C file implements
(`compiled_controllers`). The Python loop costs about 17 us/step; the
compiled one stays within 2x of a bare mj_step (benchmarks/bench_step.py).

The shared library is cached per user in ``$XDG_CACHE_HOME/wpam_mj`` (default
``~/.cache/wpam_mj``) under a name that hashes the C source, the compiler flags and the
MuJoCo wheel it was built against, so a new source or MuJoCo version rebuilds it. Several
processes may build at once: each compiles to its own temporary name, then renames it
into place atomically.

Set ``WPAM_MJ_NO_COMPILE=1`` to disable the compiled path (`available()` is then False).
Limitation: a MuJoCo fatal error (mju_error) inside mj_step cannot propagate through the
C loop as a Python exception; for this 1-DOF model MuJoCo only issues warnings.
"""

from __future__ import annotations

import ctypes
import hashlib
import math
import os
import shutil
import subprocess
import tempfile
from dataclasses import fields
from pathlib import Path
from typing import Callable

import mujoco
import numpy as np

from wpam_mj import pneumatics as pn
from wpam_mj.control import CONTROLLERS, PoController, PoFeedback
from wpam_mj.model import MuscleIndex
from wpam_mj.muscle import MuscleModel
from wpam_mj.params import MM
from wpam_mj.loop_contract import (REC_FIELDS, REC_ROWS, RunConstants, contraction_diverged,
                                   pressure_diverged)

SOURCE = Path(__file__).with_name("_fastloop.c")
MUJOCO_DIR = Path(mujoco.__file__).resolve().parent
# -ffp-contract=off: no FMA contraction; no -ffast-math: IEEE order of operations kept.
# Both are what makes the results bit-identical to Python floats (see _fastloop.c).
CFLAGS = ("-O2", "-fPIC", "-shared", "-std=c11", "-ffp-contract=off", "-fno-fast-math")

# The constants array passed to wpam_run holds, in the order of the WPAM_CONSTANTS list of
# _fastloop.c (whose names the library exports), every number of RunConstants, MuscleModel
# and MuscleIndex under its own field name, plus the values below, each computed with
# the exact expression of the Python code it stands for (so it rounds the same way).
# `_load` refuses a library whose names differ from these. A new field of RunConstants or
# MuscleModel therefore reaches C by name; only _fastloop.c must read it.


def _feedback(attr: str) -> Callable[[MuscleModel, PoController], float]:
    """A PoFeedback attribute; 0 for a controller without it."""
    return lambda muscle, ctl: getattr(ctl, attr) if isinstance(ctl, PoFeedback) else 0.0


_DERIVED: dict[str, Callable[[MuscleModel, PoController], float]] = {
    "controller": lambda muscle, ctl: compiled_controllers().index(ctl.name),
    # wpam_mj.pneumatics module constants
    "rt0": lambda muscle, ctl: pn.RT0,
    "rho0": lambda muscle, ctl: pn.RHO_0,
    "r_laminar": lambda muscle, ctl: pn.R_LAMINAR,
    # BraidGeometry.diameter/volume/area
    "natural_length": lambda muscle, ctl: muscle.geometry.natural_length,
    "thread_sq": lambda muscle, ctl: muscle.geometry.thread_length ** 2,
    "volume_denom": lambda muscle, ctl: 4.0 * math.pi * muscle.geometry.turns ** 2,
    "diameter_denom": lambda muscle, ctl: muscle.geometry.turns * math.pi,
    # PoFeedback (kd is 0 for PI; integral0 is the bumpless initial integral)
    "kp": _feedback("kp"), "ki": _feedback("ki"), "kd": _feedback("kd"),
    "tf": _feedback("tf"), "po_lo": _feedback("lo"), "po_hi": _feedback("hi"),
    "integral0": _feedback("integral"),
    "mm": lambda muscle, ctl: MM,
    "pa_per_unit": _feedback("pa_per_unit"),
}


def _numbers(obj) -> dict[str, float]:
    """The int and float fields of a dataclass instance, by name."""
    return {f.name: getattr(obj, f.name) for f in fields(obj) if f.type in ("int", "float")}


def constant_names() -> set[str]:
    """Names of every constant Python hands the compiled loop (see `pack_constants`)."""
    return {f.name for cls in (RunConstants, MuscleModel, MuscleIndex) for f in fields(cls)
            if f.type in ("int", "float")} | set(_DERIVED)


_FAIL_CONTRACTION, _FAIL_PRESSURE = 1, 2  # fail_info[0] codes of _fastloop.c

_lib: ctypes.CDLL | None = None
_reason: str | None = None  # why the compiled path is unavailable
_checked = False


def available() -> bool:
    """True when the compiled loop is built (or cached) and loads; never raises."""
    return _load() is not None


def unavailable_reason() -> str | None:
    """Why `available()` is False (None when it is True)."""
    _load()
    return _reason


def compiled_controllers() -> tuple[str, ...]:
    """Names of the controllers the compiled loop implements (() when unavailable)."""
    lib = _load()
    return () if lib is None else exported_names(lib, "wpam_controllers")


def pack_constants(lib: ctypes.CDLL, model, muscle: MuscleModel, controller: PoController,
                   k: RunConstants) -> np.ndarray:
    """The constants array of one run, in the order the library `lib` declares."""
    values = {**_numbers(k), **_numbers(muscle), **_numbers(MuscleIndex.of(model)),
              **{name: value(muscle, controller) for name, value in _DERIVED.items()}}
    return np.array([values[name] for name in exported_names(lib, "wpam_const_names")],
                    dtype=np.float64)


def run_compiled(model, data, muscle, controller: PoController, k: RunConstants, drive,
                 rec: np.ndarray):
    """Compiled `run_python`: same arguments, fills `rec` the same way.

    Returns None, or (step, reason) when the state diverged at `step`.
    Raises RuntimeError when the compiled loop is unavailable or does not implement
    the controller.
    """
    lib = _load()
    if lib is None:
        raise RuntimeError(f"the compiled loop is unavailable ({_reason}); "
                           "use engine='python' or engine='auto'")
    if controller.name not in compiled_controllers():
        raise RuntimeError(f"the compiled loop does not implement controller "
                           f"{controller.name!r}; use engine='python' or engine='auto'")
    n = len(drive.pi_cmd)
    if rec.dtype != np.float64 or not rec.flags.c_contiguous or rec.shape[0] != REC_ROWS:
        raise ValueError(f"rec must be a C-contiguous float64 array of shape ({REC_ROWS}, n_rec)")
    if n >= 2**31:
        raise ValueError(f"{n} steps exceed the compiled loop's int range; split the run")
    consts = pack_constants(lib, model, muscle, controller, k)
    fail = np.zeros(3)

    def ptr(a: np.ndarray):
        return a.ctypes.data_as(ctypes.POINTER(ctypes.c_double))

    status = lib.wpam_run(ctypes.c_void_p(model._address), ctypes.c_void_p(data._address),
                          ptr(consts), n, ptr(drive.pi_cmd), ptr(drive.po_cmd),
                          ptr(drive.x_ref), ptr(rec), rec.shape[1], ptr(fail))
    if status == 0:
        return None
    if status < 0:
        raise RuntimeError(f"wpam_run rejected its arguments (code {status})")
    step = status - 1
    if fail[0] == _FAIL_CONTRACTION:
        return step, contraction_diverged(float(fail[1]))
    return step, pressure_diverged(float(fail[1]), float(fail[2]))


def cache_dir() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "wpam_mj"


def _library_path() -> tuple[Path, Path]:
    """(shared library to build, libmujoco it links to)."""
    libs = sorted(MUJOCO_DIR.glob("libmujoco.so.*"))
    if not libs:
        raise FileNotFoundError(f"no libmujoco.so.* in {MUJOCO_DIR}")
    key = hashlib.sha256()
    for part in (SOURCE.read_bytes(), mujoco.__version__.encode(), str(libs[-1]).encode(),
                 " ".join(CFLAGS).encode()):
        key.update(part)
        key.update(b"\0")
    return cache_dir() / f"fastloop-{key.hexdigest()[:16]}.so", libs[-1]


def compiler() -> str | None:
    """Path of the C compiler the loop is built with ($CC, default gcc), None if absent."""
    return shutil.which(os.environ.get("CC") or "gcc")


def disabled() -> bool:
    """True when WPAM_MJ_NO_COMPILE turns the compiled path off."""
    return os.environ.get("WPAM_MJ_NO_COMPILE", "") not in ("", "0")


def _build(target: Path, libmujoco: Path) -> None:
    """Compile _fastloop.c to `target`, atomically (temp name, then os.replace)."""
    cc = compiler()
    if cc is None:
        raise FileNotFoundError(f"C compiler {os.environ.get('CC') or 'gcc'!r} not found")
    include = MUJOCO_DIR / "include"
    if not (include / "mujoco" / "mujoco.h").exists():
        raise FileNotFoundError(f"MuJoCo headers not found in {include}")
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=target.parent, prefix=f".{target.stem}.", suffix=".so")
    os.close(fd)
    try:
        cmd = [cc, *CFLAGS, f"-I{include}", "-o", tmp, str(SOURCE), str(libmujoco),
               f"-Wl,-rpath,{libmujoco.parent}", "-lm"]
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
        if proc.returncode != 0:
            raise RuntimeError(f"{' '.join(cmd)} failed:\n{proc.stderr.strip()}")
        os.replace(tmp, target)
    finally:
        Path(tmp).unlink(missing_ok=True)


def exported_names(lib: ctypes.CDLL, function: str) -> tuple[str, ...]:
    """The comma-separated name list that `function` of the C library returns."""
    getter = getattr(lib, function)
    getter.restype = ctypes.c_char_p
    return tuple(name for name in getter().decode().split(",") if name)


def _check_layout(lib: ctypes.CDLL, function: str, python: tuple[str, ...] | set[str]) -> None:
    """Raise unless the C list `function` names exactly `python` (in the same order when
    `python` is a tuple: the record rows are written by position)."""
    c_names = exported_names(lib, function)
    if (c_names if isinstance(python, tuple) else set(c_names)) != python:
        missing = [n for n in python if n not in c_names]
        extra = [n for n in c_names if n not in python]
        raise RuntimeError(f"{function} of {SOURCE.name} differs from Python: "
                           f"missing {missing}, extra {extra}, C order {list(c_names)}")


def _load() -> ctypes.CDLL | None:
    """Build (once per source and MuJoCo version) and load the library; cache the answer."""
    global _lib, _reason, _checked
    if _checked:
        return _lib
    _checked = True
    if disabled():
        _reason = "disabled by WPAM_MJ_NO_COMPILE"
        return None
    try:
        target, libmujoco = _library_path()
        if not target.exists():
            _build(target, libmujoco)
        lib = ctypes.CDLL(str(target))
        if not lib.wpam_abi_ok():
            raise RuntimeError("MuJoCo headers and library versions differ")
        _check_layout(lib, "wpam_const_names", constant_names())
        _check_layout(lib, "wpam_record_fields", REC_FIELDS)
        unknown = set(exported_names(lib, "wpam_controllers")) - set(CONTROLLERS)
        if unknown:
            raise RuntimeError(f"{SOURCE.name} implements controllers {sorted(unknown)} "
                               "that wpam_mj.control.CONTROLLERS does not have")
    except Exception as err:  # noqa: BLE001 (any failure means: use the Python loop)
        _reason = f"{type(err).__name__}: {err}"
        return None
    p = ctypes.POINTER(ctypes.c_double)
    lib.wpam_run.argtypes = [ctypes.c_void_p, ctypes.c_void_p, p, ctypes.c_int, p, p, p, p,
                             ctypes.c_int, p]
    lib.wpam_run.restype = ctypes.c_int
    _lib = lib
    return lib
