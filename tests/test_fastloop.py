"""The compiled loop (wpam_mj/_fastloop.c) matches the Python reference loop bit for bit.

Fast paths must match a plain reference loop exactly (docs/mujoco_notes.md; as mujoco's
python/mujoco/rollout_test.py does for rollout vs. mj_step): every recorded array of
engine="c" must equal engine="python" byte for byte, for open loop, PI and PID, with and
without regulator dead time, and both engines must report a divergence the same way.
"""

from __future__ import annotations

import ast
import os
import subprocess
import sys
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest

from wpam_mj import Drive, SimulationDiverged, fastloop, preset
from wpam_mj.simulate import simulate
from wpam_mj.control import CONTROLLERS, CONTROLS, PIControl, make_controller
from wpam_mj.experiments import drive_for_targets
from wpam_mj.loop_contract import REC_FIELDS, RunConstants
from wpam_mj.model import build_model
from wpam_mj.muscle import MuscleModel
from wpam_mj.params import MPA, PRESETS, ParameterError

# Skipped only where the loop cannot be built by design; with a compiler, a build failure
# fails these tests (test_compiled_loop_builds says why).
_SKIP = ("compiled loop disabled by WPAM_MJ_NO_COMPILE" if fastloop.disabled() else
         "no C compiler ($CC or gcc): the compiled loop cannot be built"
         if fastloop.compiler() is None else None)
pytestmark = pytest.mark.skipif(_SKIP is not None, reason=_SKIP or "")

LOAD = 100.0  # N (paper §4.1)
DT = 1e-3  # s

# Dead times [s]: none, the default one step, and several steps (the ring buffer wraps).
DEAD_TIMES = {"no_dead_time": 0.0, "dead_time_1ms": 1e-3, "dead_time_4ms": 4e-3}


def _params(name: str, dead_time: str):
    return preset(name).replace(pneumatics={"dead_time": DEAD_TIMES[dead_time]})


def test_compiled_loop_builds():
    """With a C compiler present, the compiled loop builds and loads."""
    assert fastloop.available(), fastloop.unavailable_reason()


def assert_engines_identical(params, drive, **kwargs) -> None:
    """Run both engines and compare every SimResult array byte for byte."""
    ref = simulate(params, LOAD, drive, engine="python", **kwargs)
    fast = simulate(params, LOAD, drive, engine="c", **kwargs)
    assert ref.time.size > 0
    for name, want in ref.arrays().items():
        got = fast.arrays()[name]
        assert got.shape == want.shape, name
        # tobytes: exact equality that also tells -0.0 from 0.0 and compares NaNs
        if got.tobytes() != want.tobytes():
            diff = np.abs(got - want)
            first = int(np.flatnonzero(~((got == want) | (np.isnan(got) & np.isnan(want))))[0])
            pytest.fail(f"{name} differs between engines: first at t = {ref.time[first]} s, "
                        f"max |c - python| = {np.nanmax(diff):.3g}")


def open_loop_drive(po_down: float = 0.04 * MPA) -> Drive:
    """Pi ramp up then down, Po = `po_down` on the way down (the paper's Fig. 9)."""
    n = int(3.0 / DT)
    t = np.arange(n) * DT
    up = t < 1.5
    pi = np.where(up, t / 1.5, (3.0 - t) / 1.5) * 0.4 * MPA
    po = np.where(up, 0.0, po_down)
    return Drive(pi_cmd=pi, po_cmd=po, x_ref=np.full(n, np.nan))


def tracking_drive(params, control: str = "pi") -> Drive:
    """Target 10 mm, a 20 mm step at 1 s (Figs. 12-13), then a 0.5 Hz sine about 25 mm
    from 2 s (Fig. 17): saturation, anti-windup and the derivative filter all act."""
    n = int(3.5 / DT)
    t = np.arange(n) * DT
    x_ref = np.where(t < 1.0, 0.01, np.where(t < 2.0, 0.03,
                                             0.025 + 0.015 * np.sin(np.pi * (t - 2.0))))
    return drive_for_targets(params, LOAD, x_ref, control, DT)


@pytest.mark.parametrize("dead_time", DEAD_TIMES)
@pytest.mark.parametrize("control", CONTROLS)
@pytest.mark.parametrize("name", PRESETS)
def test_engines_identical(name, control, dead_time):
    """Every preset x every control mode x dead time: every array, every step recorded.
    A controller without a compiled twin must run in the Python loop under "auto"."""
    params = _params(name, dead_time)
    feedback = CONTROLLERS[control].feedback
    if not params.outer_chamber:  # the bare RLAM: Po stays 0, no Po feedback
        if feedback:
            with pytest.raises(ParameterError, match="no outer chamber"):
                simulate(params, LOAD, tracking_drive(params, control), control=control)
            return
        drive = open_loop_drive(po_down=0.0)
    else:
        drive = tracking_drive(params, control) if feedback else open_loop_drive()
    if control in fastloop.compiled_controllers():
        assert_engines_identical(params, drive, control=control, record_dt=DT)
    else:
        auto = simulate(params, LOAD, drive, control=control, record_dt=DT)
        ref = simulate(params, LOAD, drive, control=control, record_dt=DT, engine="python")
        assert auto.x.tobytes() == ref.x.tobytes()


def test_divergence_reported_by_both_engines():
    """A huge conductance at a coarse step overshoots the chambers: same error, same text."""
    params = preset("wpam").replace(pneumatics={"inner_conductance": 1e-6,
                                                "outer_conductance": 1e-6})
    dt = 0.005
    n = int(1.0 / dt)
    drive = Drive(pi_cmd=np.full(n, 0.3 * MPA), po_cmd=np.zeros(n), x_ref=np.full(n, np.nan))
    messages = []
    for engine in ("python", "c"):
        with pytest.raises(SimulationDiverged, match="chamber pressure") as err:
            simulate(params, LOAD, drive, dt=dt, engine=engine)
        messages.append(str(err.value))
    assert messages[0] == messages[1]


def test_env_var_disables_compiled_path():
    """WPAM_MJ_NO_COMPILE=1: available() is False and engine="auto" uses Python."""
    code = ("import importlib; from wpam_mj import fastloop; "
            "s = importlib.import_module('wpam_mj.simulate'); "
            "print(fastloop.available(), s._select_engine('auto', 'pi') is s.run_python)")
    env = dict(os.environ, WPAM_MJ_NO_COMPILE="1")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                         text=True, check=True).stdout.split()
    assert out == ["False", "True"]


def test_missing_compiler_falls_back_to_python_with_one_notice(tmp_path):
    """No compiler and no cached library: engine="auto" runs the Python loop and says
    why, once per process; WPAM_MJ_NO_COMPILE=1 (the user's choice) stays quiet."""
    code = ("import numpy as np; from wpam_mj import preset; "
            "from wpam_mj.experiments import drive_for_targets; "
            "from wpam_mj.simulate import simulate; p = preset('wpam'); "
            "d = drive_for_targets(p, 100.0, np.full(50, 0.02), 'pi', 1e-3); "
            "simulate(p, 100.0, d); simulate(p, 100.0, d)")
    env = dict(os.environ, CC=str(tmp_path / "no-such-cc"), XDG_CACHE_HOME=str(tmp_path))
    err = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                         text=True, check=True).stderr.strip().splitlines()
    assert len(err) == 1 and "compiled loop is unavailable" in err[0] \
        and "no-such-cc" in err[0] and "Python loop" in err[0]
    env["WPAM_MJ_NO_COMPILE"] = "1"
    assert subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                          text=True, check=True).stderr == ""


def test_layout_checked_by_name():
    """The C library's constant and record names are compared with Python's when it
    loads: a constant missing on either side, or a reordered record row, is refused
    with both lists in the message. Constants are packed by name, in C's order."""
    lib = fastloop._load()
    assert set(fastloop.exported_names(lib, "wpam_const_names")) == fastloop.constant_names()
    assert fastloop.exported_names(lib, "wpam_record_fields") == REC_FIELDS
    with pytest.raises(RuntimeError, match=r"wpam_const_names .*missing \['leak'\]"):
        fastloop._check_layout(lib, "wpam_const_names", fastloop.constant_names() | {"leak"})
    with pytest.raises(RuntimeError, match=r"extra \['dt'\]"):
        fastloop._check_layout(lib, "wpam_const_names", fastloop.constant_names() - {"dt"})
    swapped = (REC_FIELDS[1], REC_FIELDS[0], *REC_FIELDS[2:])
    with pytest.raises(RuntimeError, match="wpam_record_fields .* C order"):
        fastloop._check_layout(lib, "wpam_record_fields", swapped)


def test_constants_packed_by_name():
    """Each packed value sits at the index C reads it from."""
    lib = fastloop._load()
    params = preset("mckibben")
    model = build_model(params, LOAD, DT)
    muscle = MuscleModel.from_params(params)
    consts = fastloop.pack_constants(lib, model, muscle, make_controller("pid", params, DT),
                                     RunConstants.make(params, DT, DT))
    at = dict(zip(fastloop.exported_names(lib, "wpam_const_names"), consts))
    assert at["rubber_stiffness"] == params.muscle.rubber_stiffness > 0.0
    assert at["kd"] == params.controller.kd and at["dt"] == DT
    assert at["controller"] == fastloop.compiled_controllers().index("pid")


def _imported_modules(module) -> set[str]:
    tree = ast.parse(Path(module.__file__).read_text())
    return {node.module for node in ast.walk(tree) if isinstance(node, ast.ImportFrom)} | {
        f"wpam_mj.{a.name}" for node in ast.walk(tree) if isinstance(node, ast.ImportFrom)
        and node.module == "wpam_mj" for a in node.names}


def test_loops_do_not_import_each_other():
    """`import wpam_mj.simulate` yields the module, and the compiled loop does not import
    the Python loop (their shared contract is wpam_mj.loop_contract)."""
    import wpam_mj.simulate as python_loop  # noqa: PLC0415

    assert isinstance(python_loop, ModuleType)
    assert "wpam_mj.simulate" not in _imported_modules(fastloop)
    assert "wpam_mj.loop_contract" in _imported_modules(fastloop)


class _SlowPI(PIControl):
    """A controller the compiled loop does not implement (PI under another name)."""

    name = "slow_pi"


def test_unknown_controller_runs_in_python_with_a_notice(monkeypatch, capfd):
    """A controller the C file does not declare runs in the Python loop under
    engine="auto", announced by one line on stderr; engine="c" refuses it."""
    monkeypatch.setitem(CONTROLLERS, "slow_pi", _SlowPI)
    assert "slow_pi" not in fastloop.compiled_controllers()
    params = preset("wpam")
    x_ref = np.full(500, 0.02)
    drive = drive_for_targets(params, LOAD, x_ref, "pi", DT)
    auto = simulate(params, LOAD, drive, control="slow_pi")
    simulate(params, LOAD, drive, control="slow_pi")  # announced once per process
    notice = capfd.readouterr().err.strip().splitlines()
    assert len(notice) == 1 and "'slow_pi' has no compiled loop" in notice[0]
    ref = simulate(params, LOAD, drive, control="pi", engine="python")
    assert auto.po_cmd.tobytes() == ref.po_cmd.tobytes()  # ran as the Python PI
    with pytest.raises(RuntimeError, match="does not implement controller 'slow_pi'"):
        simulate(params, LOAD, drive, control="slow_pi", engine="c")


def test_compiled_controllers_are_registered_ones():
    """The C file implements registered controllers only (checked at load), among them
    the paper's open loop, PI and PID."""
    assert {"open", "pi", "pid"} <= set(fastloop.compiled_controllers()) <= set(CONTROLLERS)
