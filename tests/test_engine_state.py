"""The Python engine keeps each muscle's state in the MjData (userdata, laid out as the
plugin's plugin_state): mj_resetData, several MjData of one model, copies, pickles, threads
and compiling other models meanwhile behave as on the compiled plugin, bit for bit."""

from __future__ import annotations

import copy
import pickle
import threading

import mujoco
import numpy as np
import pytest

from wpam_mj import preset
from wpam_mj.simulation import engine, plugin
from wpam_mj.simulation.context import RunContext
from wpam_mj.simulation.model import INSTANCE, rig_spec

DT = 1e-3
PI_HIGH, PI_LOW = 0.3e6, 0.2e6  # Pa gauge, the Pi commands of the runs


def spec() -> mujoco.MjSpec:
    return rig_spec(RunContext(preset("wpam"), DT, 100.0))


@pytest.fixture(scope="module")
def python():
    return engine.python_model(spec())


def run_python(model, muscles, data, pi, n):
    data.ctrl[muscles[0].channels[0]] = pi
    engine.step(model, data, muscles, n)
    return data


def state_python(muscles, data):
    return np.array(muscles[0].state(data))


def plugin_run(pi, n, reset_after=0):
    """(qpos, muscle state) of the plugin after n steps at Pi, optionally after
    `reset_after` steps at the other Pi and mj_resetData."""
    if not plugin.available():
        pytest.skip(f"the compiled plugin is unavailable ({plugin.unavailable_reason()})")
    model = spec().compile()
    data = mujoco.MjData(model)
    ctrl = model.actuator(f"{INSTANCE}_pi_cmd").id
    if reset_after:
        data.ctrl[ctrl] = PI_LOW
        mujoco.mj_step(model, data, nstep=reset_after)
        mujoco.mj_resetData(model, data)
    data.ctrl[ctrl] = pi
    mujoco.mj_step(model, data, nstep=n)
    start = plugin.state_address(model)
    size = int(model.plugin_statenum[0])
    return data.qpos.copy(), data.plugin_state[start:start + size].copy()


def assert_same(data, muscles, expected):
    qpos, state = expected
    np.testing.assert_array_equal(data.qpos, qpos)
    np.testing.assert_array_equal(state_python(muscles, data), state)


def test_the_state_is_the_plugins_layout_in_userdata(python):
    model, muscles = python
    data = run_python(model, muscles, mujoco.MjData(model), PI_HIGH, 300)
    assert_same(data, muscles, plugin_run(PI_HIGH, 300))


def test_mj_reset_data_resets_the_muscle(python):
    """Before: the Python engine's muscle kept its pressures across mj_resetData (load at
    41.6 mm against 8.45 mm fresh after 300 steps at 0.3 MPa)."""
    model, muscles = python
    data = run_python(model, muscles, mujoco.MjData(model), PI_LOW, 500)
    mujoco.mj_resetData(model, data)
    run_python(model, muscles, data, PI_HIGH, 300)
    fresh = run_python(model, muscles, mujoco.MjData(model), PI_HIGH, 300)
    np.testing.assert_array_equal(data.qpos, fresh.qpos)
    assert_same(data, muscles, plugin_run(PI_HIGH, 300, reset_after=500))


def test_two_data_of_one_model_have_a_muscle_each(python):
    model, muscles = python
    a, b = mujoco.MjData(model), mujoco.MjData(model)
    for _ in range(300):  # interleaved, step by step
        run_python(model, muscles, a, PI_HIGH, 1)
        run_python(model, muscles, b, PI_LOW, 1)
    assert_same(a, muscles, plugin_run(PI_HIGH, 300))
    assert_same(b, muscles, plugin_run(PI_LOW, 300))


@pytest.mark.parametrize("how", ["copy.copy", "mj_copyData", "pickle"])
def test_a_copy_carries_the_muscle_and_goes_its_own_way(python, how):
    model, muscles = python
    data = run_python(model, muscles, mujoco.MjData(model), PI_HIGH, 150)
    if how == "copy.copy":
        other = copy.copy(data)
    elif how == "mj_copyData":
        other = mujoco.MjData(model)
        mujoco.mj_copyData(other, model, data)
    else:
        other = pickle.loads(pickle.dumps(data))
    run_python(model, muscles, data, PI_HIGH, 150)
    run_python(model, muscles, other, PI_HIGH, 150)
    assert_same(data, muscles, plugin_run(PI_HIGH, 300))
    assert_same(other, muscles, plugin_run(PI_HIGH, 300))


def test_other_models_compile_while_the_engine_steps_on_threads(python):
    """Before: the engine installed a Python mjcb_control, and compiling any model while
    it was installed failed ("engine error: Python exception raised"), so threaded runs
    on the Python engine (WPAM_MJ_NO_COMPILE=1) failed."""
    model, muscles = python
    results: dict[str, mujoco.MjData] = {}
    errors: list[BaseException] = []

    def work(name: str, pi: float) -> None:
        try:
            data = mujoco.MjData(model)
            for _ in range(30):
                run_python(model, muscles, data, pi, 10)
                engine.python_model(spec())  # compiles a model meanwhile
            results[name] = data
        except BaseException as err:  # noqa: BLE001 (reported by the main thread)
            errors.append(err)

    threads = [threading.Thread(target=work, args=(name, pi))
               for name, pi in (("high", PI_HIGH), ("low", PI_LOW))]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors, errors
    assert_same(results["high"], muscles, plugin_run(PI_HIGH, 300))
    assert_same(results["low"], muscles, plugin_run(PI_LOW, 300))
