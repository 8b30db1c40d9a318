"""The plugin in models nobody here wrote, and under misuse: a muscle only pulls, is defined
at every tendon length, and no input, option edit or copy of its data crashes the host,
poisons the state with NaN or starts MuJoCo's reset loop.

Each case names what it guards against; cases that could take the interpreter down run in
a child process, so a crash fails the test instead of ending the run.
"""

from __future__ import annotations

import math
import pickle
import subprocess
import sys
import textwrap

import mujoco
import numpy as np
import pytest
from mujoco import rollout

import wpam_mj  # noqa: F401 (registers the plugin)
from wpam_mj.paths import MODELS_DIR
from wpam_mj.physics.geometry import BraidGeometry
from wpam_mj.physics.muscle import MuscleModel
from wpam_mj.physics.params import preset
from wpam_mj.simulation import engine, plugin
from wpam_mj.simulation.simulate import Drive, simulate

pytestmark = pytest.mark.skipif(plugin.compiler() is None or plugin.disabled(),
                                reason="no C compiler (or WPAM_MJ_NO_COMPILE): no plugin")

ELBOW = MODELS_DIR / "elbow" / "elbow.xml"
STOP = BraidGeometry.from_params(preset("wpam").braid).max_contraction


def finger(flexor: str = "", extensor: str = '<config key="contraction0" value="0.05"/>',
           flexor_control: str = "pi") -> str:
    """A new user's two-joint finger: a W-PAM flexor (PI on its target) and a McKibben
    extensor mounted pre-contracted by 50 mm, over wrapping cylinders, with a plain motor
    and a free body beside them."""
    return f"""
<mujoco model="finger">
  <option timestep="0.001" noslip_iterations="2"/>
  <extension><plugin plugin="wpam_mj.muscle">
    <instance name="flexor"><config key="control" value="{flexor_control}"/>
      <config key="start" value="rest"/>
      <config key="feedforward_load" value="20"/>{flexor}</instance>
    <instance name="extensor"><config key="preset" value="mckibben"/>{extensor}</instance>
  </plugin></extension>
  <worldbody>
    <site name="flexor_origin" pos="-0.03 0 0.45"/>
    <site name="extensor_origin" pos="0.03 0 0.45"/>
    <body name="proximal" pos="0 0 0">
      <joint name="mcp" type="hinge" axis="0 1 0" range="-0.6 1.4" damping="0.3"/>
      <geom name="mcp_pulley" type="cylinder" size="0.015 0.01" zaxis="0 1 0" mass="0"/>
      <site name="mcp_front" pos="-0.03 0 0"/><site name="mcp_back" pos="0.03 0 0"/>
      <geom type="capsule" fromto="0 0 0 0 0 -0.05" size="0.01" mass="0.1"/>
      <site name="flexor_mid" pos="-0.02 0 -0.025"/>
      <site name="extensor_mid" pos="0.02 0 -0.025"/>
      <body name="distal" pos="0 0 -0.05">
        <joint name="pip" type="hinge" axis="0 1 0" range="-0.2 1.6" damping="0.2"/>
        <geom name="pip_pulley" type="cylinder" size="0.012 0.01" zaxis="0 1 0" mass="0"/>
        <site name="pip_front" pos="-0.03 0 0"/><site name="pip_back" pos="0.03 0 0"/>
        <geom type="capsule" fromto="0 0 0 0 0 -0.04" size="0.009" mass="0.05"/>
        <site name="flexor_insertion" pos="-0.01 0 -0.03"/>
        <site name="extensor_insertion" pos="0.01 0 -0.03"/>
      </body>
    </body>
    <body name="pebble" pos="0.3 0 0.2"><freejoint/><geom size="0.02" mass="0.1"/></body>
  </worldbody>
  <tendon>
    <spatial name="flexor" frictionloss="1" limited="true" range="0.38 0.6">
      <site site="flexor_origin"/><geom geom="mcp_pulley" sidesite="mcp_front"/>
      <site site="flexor_mid"/><geom geom="pip_pulley" sidesite="pip_front"/>
      <site site="flexor_insertion"/>
    </spatial>
    <spatial name="extensor" frictionloss="1">
      <site site="extensor_origin"/><geom geom="mcp_pulley" sidesite="mcp_back"/>
      <site site="extensor_mid"/><geom geom="pip_pulley" sidesite="pip_back"/>
      <site site="extensor_insertion"/>
    </spatial>
  </tendon>
  <actuator>
    <plugin name="flexor_x_ref" instance="flexor" tendon="flexor" ctrlrange="0 0.08"/>
    <plugin name="extensor_pi" instance="extensor" tendon="extensor" ctrlrange="0 500000"/>
    <motor name="wrist_motor" joint="pip" gear="0.01"/>
  </actuator>
</mujoco>"""


def step_python(model, muscles, data, n):
    engine.step(model, data, muscles, n)


# ---------------------------------------------------------------- a muscle pulls

def test_the_tendon_force_never_pushes_and_guided_fittings_carry_the_bags_push():
    """MuscleModel.tendon_force: max(T, 0) on free fittings; the braid's pull less A_ax Po
    on guided ones. At zero pressure a pre-contracted McKibben (rubber term) and a W-PAM at
    Po = 80 kPa (A_ax Po) would push; they pull nothing instead."""
    mck = MuscleModel.from_params(preset("mckibben"))
    wpam = MuscleModel.from_params(preset("wpam"))
    assert mck.tension(0.05, 0.0, 0.0) < -50.0 and mck.tendon_force(0.05, 0.0, 0.0) == 0.0
    assert wpam.tension(0.03, 0.0, 80e3) < -50.0 and wpam.tendon_force(0.03, 0.0, 80e3) == 0.0
    assert wpam.tendon_force(0.03, 0.0, 80e3, guided=True) == -wpam.axial_area * 80e3
    for x, pi, po in ((0.03, 0.3e6, 0.02e6), (0.0, 0.1e6, 0.0)):  # pulling: all agree
        t = wpam.tension(x, pi, po)
        assert t > 0 and wpam.tendon_force(x, pi, po) == t == wpam.tendon_force(x, pi, po, True)


def test_a_users_finger_flexes_stays_finite_and_never_pushes_at_zero_pressure():
    model = mujoco.MjModel.from_xml_string(finger())
    data = mujoco.MjData(model)
    data.ctrl[:] = (0.0, 0.0, 0.0)  # flexor asked for no contraction, extensor vented
    mujoco.mj_step(model, data, nstep=1000)
    for name in ("flexor", "extensor"):
        state = plugin.state_of(model, data, name)
        assert state["tension"] >= 0.0 and state["status"] == 0.0, (name, state)
    assert np.all(data.actuator_force[:2] <= 0.0)  # along the tendons' lengths: pulls only
    rest = data.qpos[0]
    data.ctrl[0] = 0.03  # flexor: contract 30 mm
    mujoco.mj_step(model, data, nstep=3000)
    flexor = plugin.state_of(model, data, "flexor")
    assert data.qpos[0] > rest + 0.3, (rest, data.qpos[0])  # flexed
    assert 0.0 < flexor["x"] < STOP and flexor["status"] == 0.0, flexor
    assert np.all(np.isfinite(data.qpos)) and not any(w.number for w in data.warning)


def test_the_finger_is_bit_identical_across_thread_counts_and_engines():
    xml = finger()
    model = mujoco.MjModel.from_xml_string(xml)
    nstep, nbatch = 600, 4
    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    initial = np.empty(mujoco.mj_stateSize(model, spec))
    mujoco.mj_getState(model, mujoco.MjData(model), initial, spec)
    ctrl = np.stack([np.tile((0.01 * i, 0.1e6, 0.0), (nstep, 1)) for i in range(nbatch)])
    one = rollout.rollout(model, mujoco.MjData(model), np.tile(initial, (nbatch, 1)), ctrl)[0]
    two = rollout.rollout(model, [mujoco.MjData(model), mujoco.MjData(model)],
                          np.tile(initial, (nbatch, 1)), ctrl)[0]
    np.testing.assert_array_equal(one, two)
    pmodel, muscles = engine.python_model(mujoco.MjSpec.from_string(xml))
    pdata = mujoco.MjData(pmodel)
    pdata.ctrl[:3] = ctrl[3, 0]
    step_python(pmodel, muscles, pdata, nstep)
    np.testing.assert_array_equal(pdata.qpos, one[3, -1, 1:1 + model.nq])


def test_a_stretched_mount_is_refused_when_the_model_compiles():
    bad = finger(extensor='<config key="contraction0" value="-0.05"/>')
    with pytest.raises(ValueError, match=r"instance 'extensor': contraction0 = -0.05 m is "
                                         r"outside the allowed range \[0, 0.0932"):
        mujoco.MjModel.from_xml_string(bad)


# ---------------------------------------------------------------- defined at every length

def test_the_geometry_beyond_its_stroke_is_that_of_its_nearest_end():
    geom = BraidGeometry.from_params(preset("wpam").braid)
    for f in (geom.diameter, geom.volume, geom.area):
        assert f(-0.05) == f(0.0) and f(0.2) == f(geom.max_contraction)
        assert np.array_equal(f(np.array([-1.0, 0.0, 5.0])),
                              [f(0.0), f(0.0), f(geom.max_contraction)])
    assert geom.area(geom.max_contraction) > 0.0  # continuous: no force step at the end


@pytest.mark.parametrize("contraction0, qpos", [("0.05", -1.2), ("0.0", 1.4)],
                         ids=["beyond-the-full-bag", "past-the-natural-length"])
def test_a_muscle_forced_far_past_its_stroke_stays_finite_and_says_so(contraction0, qpos):
    """The extensor held beyond its full bag, or stretched past its natural length, by
    the hand forced into place every step: finite force, a status, no MuJoCo warning."""
    xml = finger(extensor=f'<config key="contraction0" value="{contraction0}"/>')
    model = mujoco.MjModel.from_xml_string(xml)
    data = mujoco.MjData(model)
    data.ctrl[:] = (0.02, 0.3e6, 0.0)
    for _ in range(200):
        data.qpos[:2], data.qvel[:2] = qpos, 0.0
        mujoco.mj_step(model, data)
    ext = plugin.state_of(model, data, "extensor")
    geom = BraidGeometry.from_params(preset("mckibben").braid)
    tolerance = plugin.STROKE_TOLERANCE
    assert not -tolerance <= ext["x"] <= geom.max_contraction + tolerance, ext["x"]
    assert ext["status"] == plugin.STATUS_STROKE and np.isfinite(ext["tension"])
    assert ext["tension"] >= 0.0 and np.all(np.isfinite(data.qacc))
    assert "left the muscle's stroke" in plugin.status_of(model, data, "extensor")
    assert not any(w.number for w in data.warning)


def test_the_rigs_soft_stop_holds_its_harshest_load_within_the_tolerance():
    """The rig's lower stop is a stiff joint limit: a 1 N load under 0.5 MPa of Po (the bag
    pushing the guided fittings with A_ax Po, 1 kN) sinks into it by about 2 mm, which the
    status tolerates; its run succeeds."""
    n = 2000
    result = simulate(preset("wpam"), 1.0, Drive(np.zeros(n), np.full(n, 0.5e6),
                                                  np.full(n, np.nan)), engine="plugin")
    assert -plugin.STROKE_TOLERANCE < result.x.min() < -0.5e-3


# ---------------------------------------------------------------- commands

@pytest.mark.parametrize("bad, held", [(math.nan, (0.0, 0.0)), (math.inf, (0.0, 0.5e6)),
                                       (-0.0285, (0.0, 0.0)), (1e300, (STOP, 0.5e6)),
                                       (-1e300, (0.0, 0.0))])
def test_no_command_poisons_a_muscle(bad, held):
    """A bad target or pressure command is clamped (its ctrlrange first, then the stroke) or,
    non-finite, replaced by the channel's last finite value (0 at the start; MuJoCo warns
    BADCTRL): the run equals one given those values instead, bit for bit, and the state
    stays finite on both engines."""
    xml = finger().replace(' ctrlrange="0 0.08"', "")

    def plugin_run(first):
        model = mujoco.MjModel.from_xml_string(xml)
        data = mujoco.MjData(model)
        data.ctrl[:3] = (*first, 0.0)
        mujoco.mj_step(model, data, nstep=50)
        data.ctrl[:3] = (0.02, 0.1e6, 0.0)
        mujoco.mj_step(model, data, nstep=1000)
        return model, data

    model, data = plugin_run((bad, bad))
    np.testing.assert_array_equal(data.qpos, plugin_run(held)[1].qpos)
    for name in ("flexor", "extensor"):
        state = plugin.state_of(model, data, name)
        assert all(math.isfinite(v) for k, v in state.items() if k != "x_ref"), state
        assert state["status"] == 0.0, state
    # the Python engine (MuJoCo zeroes every ctrl of a step with a bad one, its force
    # motors' too, so the engines part there; both stay finite)
    pmodel, muscles = engine.python_model(mujoco.MjSpec.from_string(xml))
    pdata = mujoco.MjData(pmodel)
    pdata.ctrl[:3] = (bad, bad, 0.0)
    step_python(pmodel, muscles, pdata, 50)
    pdata.ctrl[:3] = (0.02, 0.1e6, 0.0)
    step_python(pmodel, muscles, pdata, 1000)
    assert np.all(np.isfinite(pdata.qpos)) and not any(m.status(pdata) for m in muscles)
    assert all(math.isfinite(v) for m in muscles
               for k, v in zip(plugin.STATE_FIELDS, m.state(pdata)) if k != "x_ref")


# ---------------------------------------------------------------- options edited after compile

@pytest.fixture(autouse=True)
def _elsewhere(tmp_path, monkeypatch):
    """MuJoCo appends its warnings to MUJOCO_LOG.TXT in the working folder: not the repo's."""
    monkeypatch.chdir(tmp_path)


def run_child(code: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", textwrap.dedent(code)], capture_output=True,
                          text=True, timeout=300)


@pytest.mark.parametrize("xml, change", [
    ("elbow", "m.opt.timestep = 1e-5"),
    ("elbow", "m.opt.timestep = 5e-4"),
    ("arm", "m.opt.timestep = 1e-4"),
    ("elbow", "m.opt.integrator = mujoco.mjtIntegrator.mjINT_RK4"),
])
def test_an_option_changed_after_compile_stops_the_muscle_with_one_warning(xml, change):
    """MuJoCo's viewer edits the time step and integrator of a compiled model: the muscle's
    dead-time queues were sized at compile (they once overran: heap corruption, SIGSEGV).
    Now: a warning line, the status, no force, nothing written past the state; changed
    back and reset, it runs again."""
    proc = run_child(f"""
        import mujoco, numpy as np, wpam_mj
        from wpam_mj.simulation import plugin
        m = mujoco.MjModel.from_xml_path("{MODELS_DIR / xml / (xml + '.xml')}")
        d = mujoco.MjData(m)
        d.ctrl[0] = 0.05 if m.nu == 2 and "{xml}" == "arm" else 0.3e6
        mujoco.mj_step(m, d, nstep=100)
        dt, integrator = m.opt.timestep, m.opt.integrator
        {change}
        mujoco.mj_step(m, d, nstep=2000)
        names = [mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_PLUGIN, i) for i in range(m.nplugin)]
        assert all(plugin.state_of(m, d, n)["status"] == plugin.STATUS_MODEL for n in names)
        assert np.all(d.actuator_force == 0.0) and np.all(np.isfinite(d.qpos))
        m.opt.timestep, m.opt.integrator = dt, integrator
        mujoco.mj_resetData(m, d)
        mujoco.mj_step(m, d, nstep=100)
        assert all(plugin.state_of(m, d, n)["status"] == 0 for n in names)
        print("ok")
    """)
    assert proc.returncode == 0 and proc.stdout.strip().endswith("ok"), proc.stderr
    output = (proc.stdout + proc.stderr).splitlines()
    warnings = [line for line in output if line.startswith("WARNING")]
    assert len(warnings) == len({"elbow": 1, "arm": 2}[xml] * [1]), proc.stdout
    assert "changed after the model compiled" in warnings[0], warnings


def test_the_python_engine_refuses_a_changed_time_step_alike(capsys):
    model, muscles = engine.python_model(mujoco.MjSpec.from_file(str(ELBOW)))
    data = mujoco.MjData(model)
    data.ctrl[0] = 0.3e6
    step_python(model, muscles, data, 10)
    model.opt.timestep = 1e-5
    step_python(model, muscles, data, 10)
    assert muscles[0].status(data).startswith("the model's timestep or integrator changed")
    assert data.ctrl[muscles[0].force_actuator] == 0.0
    assert capsys.readouterr().err.count("changed after the model compiled") == 1


# ---------------------------------------------------------------- copies of an MjData

def test_a_pickled_mjdata_steps_on_its_own_memory():
    """pickle copies plugin_data raw (multiprocessing pickles): once a double free. The
    copy steps as the original does, outlives it, and every copy (pickled or deep) is
    freed once."""
    proc = run_child(f"""
        import copy, gc, pickle, mujoco, wpam_mj
        m = mujoco.MjModel.from_xml_path("{ELBOW}")
        d = mujoco.MjData(m)
        d.ctrl[0] = 0.2e6
        mujoco.mj_step(m, d, nstep=300)
        c = pickle.loads(pickle.dumps(d))
        mujoco.mj_step(m, d, nstep=300)
        mujoco.mj_step(m, c, nstep=300)
        import numpy as np
        assert c.qpos[0] == d.qpos[0]
        assert np.array_equal(c.plugin_state, d.plugin_state, equal_nan=True)
        reference = d.qpos[0]
        del d
        gc.collect()
        mujoco.mj_step(m, c, nstep=300)
        again, deep = pickle.loads(pickle.dumps(c)), copy.deepcopy(c)
        for other in (again, deep):
            mujoco.mj_step(m, other, nstep=10)
        del c, again, deep
        gc.collect()
        print("ok", reference)
    """)
    assert proc.returncode == 0 and proc.stdout.startswith("ok"), (proc.returncode,
                                                                    proc.stderr[-2000:])


def test_an_mjdata_unpickled_in_another_process_steps_like_the_original(tmp_path):
    model = mujoco.MjModel.from_xml_path(str(ELBOW))
    data = mujoco.MjData(model)
    data.ctrl[0] = 0.2e6
    mujoco.mj_step(model, data, nstep=300)
    (tmp_path / "data.pkl").write_bytes(pickle.dumps((model, data)))
    mujoco.mj_step(model, data, nstep=300)
    proc = run_child(f"""
        import pickle, mujoco, wpam_mj
        with open("{tmp_path / 'data.pkl'}", "rb") as fh:
            m, d = pickle.load(fh)
        mujoco.mj_step(m, d, nstep=300)
        print(repr(float(d.qpos[0])))
    """)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert float(proc.stdout.split()[-1]) == data.qpos[0]
