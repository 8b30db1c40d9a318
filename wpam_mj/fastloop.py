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
from pathlib import Path

import mujoco
import numpy as np

from wpam_mj import pneumatics as pn
from wpam_mj.control import CONTROLLERS, PoController, PoFeedback
from wpam_mj.model import MuscleIndex
from wpam_mj.params import MM
from wpam_mj.loop_contract import (REC_FIELDS, REC_ROWS, RunConstants, contraction_diverged,
                                   pressure_diverged)

SOURCE = Path(__file__).with_name("_fastloop.c")
MUJOCO_DIR = Path(mujoco.__file__).resolve().parent
# -ffp-contract=off: no FMA contraction; no -ffast-math: IEEE order of operations kept.
# Both are what makes the results bit-identical to Python floats (see _fastloop.c).
CFLAGS = ("-O2", "-fPIC", "-shared", "-std=c11", "-ffp-contract=off", "-fno-fast-math")

# Layout of the float64 constants array passed to wpam_run: the WPAM_CONSTANTS list of
# _fastloop.c, which exports its names; `_load` refuses a library whose names differ.
# Integers (steps, flags, indices) are stored exactly as floats.
_CONSTS = (
    # RunConstants
    "dt", "record_every", "controller", "lag_alpha", "delay_steps", "atmosphere", "p_max",
    "conductance_i", "conductance_o", "critical_ratio", "tube_volume", "bag_volume",
    # wpam_mj.pneumatics
    "rt0", "rho0", "r_laminar",
    # MuscleModel
    "output_coeff", "friction_coeff", "friction_const", "axial_area", "pi_kr",
    "natural_diameter",
    # BraidGeometry
    "natural_length", "thread_sq", "volume_denom", "diameter_denom",
    # PoFeedback (zeros for the open loop)
    "kp", "ki", "kd", "tf", "po_lo", "po_hi", "mm", "pa_per_unit", "integral0",
    # MuJoCo addresses
    "qpos_adr", "dof_adr", "actuator_id", "tendon_id",
)
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


def _controller_constants(controller: PoController) -> dict[str, float]:
    """The PoFeedback constants of the layout (zeros for a controller without them)."""
    if not isinstance(controller, PoFeedback):
        return dict.fromkeys(("kp", "ki", "kd", "tf", "po_lo", "po_hi", "mm", "pa_per_unit",
                              "integral0"), 0.0)
    c = controller
    return dict(kp=c.kp, ki=c.ki, kd=c.kd, tf=c.tf, po_lo=c.lo, po_hi=c.hi, mm=MM,
                pa_per_unit=c.pa_per_unit, integral0=c.integral)


def pack_constants(model, muscle, controller: PoController, k: RunConstants) -> np.ndarray:
    """The `_CONSTS` array for one run.

    Derived values use the exact expressions of the Python code they stand for (for
    example ``4.0 * math.pi * turns ** 2`` from BraidGeometry.area), so they round the
    same way; C evaluates the rest in the Python order.
    """
    g = muscle.geometry
    idx = MuscleIndex.of(model)
    values = dict(
        dt=k.dt, record_every=k.record_every,
        controller=compiled_controllers().index(controller.name),
        lag_alpha=k.lag_alpha, delay_steps=k.delay_steps, atmosphere=k.atmosphere,
        p_max=k.p_max, conductance_i=k.conductance_i, conductance_o=k.conductance_o,
        critical_ratio=k.critical_ratio,
        tube_volume=k.tube_volume, bag_volume=k.bag_volume,
        rt0=pn.RT0, rho0=pn.RHO_0, r_laminar=pn.R_LAMINAR,
        output_coeff=muscle.output_coeff, friction_coeff=muscle.friction_coeff,
        friction_const=muscle.friction_const, axial_area=muscle.axial_area,
        pi_kr=math.pi * muscle.rubber_stiffness,  # MuscleModel.rubber_force
        natural_diameter=muscle.natural_diameter,
        natural_length=g.natural_length,
        thread_sq=g.thread_length ** 2,  # BraidGeometry.diameter/volume/area
        volume_denom=4.0 * math.pi * g.turns ** 2,  # BraidGeometry.volume/area
        diameter_denom=g.turns * math.pi,  # BraidGeometry.diameter
        **_controller_constants(controller),
        qpos_adr=idx.qpos, dof_adr=idx.dof, actuator_id=idx.actuator, tendon_id=idx.tendon,
    )
    if values.keys() != set(_CONSTS):
        raise RuntimeError(f"pack_constants fills {sorted(values.keys() ^ set(_CONSTS))} "
                           "inconsistently with _CONSTS")
    return np.array([values[name] for name in _CONSTS], dtype=np.float64)


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
    consts = pack_constants(model, muscle, controller, k)
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


def _build(target: Path, libmujoco: Path) -> None:
    """Compile _fastloop.c to `target`, atomically (temp name, then os.replace)."""
    cc = os.environ.get("CC") or "gcc"
    if shutil.which(cc) is None:
        raise FileNotFoundError(f"C compiler {cc!r} not found")
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


def _check_layout(lib: ctypes.CDLL, function: str, python: tuple[str, ...]) -> None:
    """Raise unless the C list `function` names exactly `python`, in the same order."""
    c_names = exported_names(lib, function)
    if c_names != python:
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
    if os.environ.get("WPAM_MJ_NO_COMPILE", "") not in ("", "0"):
        _reason = "disabled by WPAM_MJ_NO_COMPILE"
        return None
    try:
        target, libmujoco = _library_path()
        if not target.exists():
            _build(target, libmujoco)
        lib = ctypes.CDLL(str(target))
        if not lib.wpam_abi_ok():
            raise RuntimeError("MuJoCo headers and library versions differ")
        for layout, python in (("wpam_const_names", _CONSTS),
                               ("wpam_record_fields", REC_FIELDS)):
            _check_layout(lib, layout, python)
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
