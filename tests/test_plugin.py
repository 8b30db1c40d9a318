"""The wpam_mj.muscle actuator plugin: on models of the user's own, against the closed-form
model, against the Python engine (bit for bit), in MuJoCo's state machinery and batches.

The plugin must be built where a C compiler exists (CI has gcc); without one these tests
are skipped with the reason, and the Python engine runs everything else.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest
from mujoco import batch as mjbatch

import wpam_mj  # noqa: F401 (registers the plugin)
from wpam_mj.simulation import engine
from wpam_mj.simulation import plugin
from wpam_mj.experiments.analysis import frequency_response
from wpam_mj.experiments.drives import SineSpec, drive_for_targets, sine_run, step_targets
from wpam_mj.simulation.context import RunContext
from wpam_mj.simulation.loop_contract import REC_FIELDS
from wpam_mj.physics.muscle import MuscleModel
from wpam_mj.physics.params import preset
from wpam_mj.errors import ParameterError
from wpam_mj.units import MPA, STANDARD_GRAVITY
from wpam_mj.simulation.simulate import Drive, simulate

# Where a C compiler exists the plugin must build: these tests then fail, never skip.
pytestmark = pytest.mark.skipif(plugin.compiler() is None or plugin.disabled(),
                                reason="no C compiler (or WPAM_MJ_NO_COMPILE): no plugin")

FRICTIONLESS = {"muscle.friction_coeff": "0", "muscle.friction_const": "0"}


def user_model(config: dict[str, str], *, load: float = 100.0, control: str = "open",
               channels: int = 2) -> str:
    """A model unlike the rig: the muscle's tendon runs from an anchor 0.2 m to the side,
    over a pulley site, down to a load on a vertical slide (MJCF text)."""
    config = {"control": control, **config}
    keys = "\n".join(f'<config key="{k}" value="{v}"/>' for k, v in config.items())
    acts = "\n".join(f'<plugin name="ch{i}" instance="m" tendon="cable"/>'
                     for i in range(channels))
    return f"""
<mujoco>
  <option timestep="0.001" noslip_iterations="2"/>
  <extension><plugin plugin="wpam_mj.muscle"><instance name="m">
    {keys}
  </instance></plugin></extension>
  <worldbody>
    <site name="anchor" pos="0.2 0 1"/>
    <site name="pulley" pos="0 0 1"/>
    <body name="load" pos="0 0 0.65">
      <joint name="lift" type="slide" axis="0 0 1" range="-0.01 0.068" damping="80"/>
      <geom type="sphere" size="0.03" mass="{load / STANDARD_GRAVITY}"/>
      <site name="hook"/>
    </body>
  </worldbody>
  <tendon><spatial name="cable" frictionloss="1">
    <site site="anchor"/><site site="pulley"/><site site="hook"/>
  </spatial></tendon>
  <actuator>{acts}</actuator>
</mujoco>"""


def run(model: mujoco.MjModel, ctrl, seconds: float) -> mujoco.MjData:
    data = mujoco.MjData(model)
    data.ctrl[:len(ctrl)] = ctrl
    for _ in range(round(seconds / model.opt.timestep)):
        mujoco.mj_step(model, data)
    return data


def test_a_users_model_lifts_its_load_to_the_closed_form_equilibrium():
    """Frictionless W-PAM, Po vented, 100 N: the Pi that eqs. 1-3 say holds 30 mm lifts the
    load to 30 mm (< 0.1 mm)."""
    params = preset("wpam").with_values({k: float(v) for k, v in FRICTIONLESS.items()})
    pi = MuscleModel.from_params(params).equilibrium_pressure(0.030, 100.0, 0.0)
    model = mujoco.MjModel.from_xml_string(user_model({"start": "rest", **FRICTIONLESS}))
    x = run(model, (pi, 0.0), 4.0).qpos[0]
    assert abs(x - 0.030) < 0.1e-3, f"x = {x * 1e3:.4f} mm, closed form 30 mm at {pi:.0f} Pa"


def test_the_python_engine_runs_the_same_users_model_bit_for_bit():
    config = {"start": "rest", "preset": "mckibben"}
    xml = user_model(config, channels=1)  # Pi alone: a McKibben muscle takes no Po
    data = run(mujoco.MjModel.from_xml_string(xml), (0.25 * MPA,), 1.0)
    model, muscles = engine.python_model(mujoco.MjSpec.from_string(xml))
    ref = mujoco.MjData(model)
    ref.ctrl[0] = 0.25 * MPA
    engine.step(model, ref, muscles, 1000)
    assert data.qpos[0] == ref.qpos[0] and data.qvel[0] == ref.qvel[0]


@pytest.mark.parametrize("config, what", [
    ({"preset": "steel"}, "preset = 'steel' is not one of: wpam, rlam, mckibben"),
    ({"start": "warm"}, "start = 'warm' is not one of: vented, rest"),
    ({"control": "bang"}, "control = 'bang' is not one of: open, pi, pid, pi_ff"),
])
def test_bad_instance_keys_fail_naming_the_allowed_values(config, what):
    with pytest.raises(ValueError, match=what):
        mujoco.MjModel.from_xml_string(user_model(config))


@pytest.mark.parametrize("control", ["pi", "pid", "pi_ff"])
def test_po_feedback_on_a_muscle_type_without_an_outer_chamber_is_refused_by_both_engines(
        control):
    """The RLAM has nothing for Po to fill: its type says so, and both engines refuse a
    feedback mode on it when the model is made, with the same line."""
    xml = user_model({"preset": "rlam"}, control=control, channels=1)
    what = f"preset 'rlam' has no outer chamber for Po feedback \\(control = '{control}'\\)"
    with pytest.raises(ValueError, match=what):
        mujoco.MjData(mujoco.MjModel.from_xml_string(xml))
    with pytest.raises(ParameterError, match=what):
        engine.python_model(mujoco.MjSpec.from_string(xml))


def test_the_wrong_number_of_input_channels_is_refused():
    with pytest.raises(ValueError, match="control = 'open' takes 2 to 2 actuators"):
        mujoco.MjData(mujoco.MjModel.from_xml_string(user_model({}, channels=1)))


def test_stiction_a_load_at_90_percent_of_the_friction_level_creeps_under_1_um_in_60_s():
    """Po vented, Pi held: the tension falls short of the load by 90 % of the friction
    level, so the load must not move at all (true stiction, per simulation)."""
    params = preset("wpam")
    muscle = MuscleModel.from_params(params)
    x0, pi = 0.0, 0.2 * MPA
    tension, friction = muscle.tension(x0, pi, 0.0), muscle.friction(x0, pi, 0.0)
    load = tension + 0.9 * friction
    model = mujoco.MjModel.from_xml_string(user_model({"start": "rest"}, load=load))
    data = run(model, (pi, 0.0), 60.0)
    assert abs(data.qpos[0] - x0) < 1e-6, f"crept {abs(data.qpos[0] - x0) * 1e6:.3f} um"


def test_the_friction_level_is_the_one_the_solver_holds_the_tendon_with():
    """The plugin writes its friction level into this step's friction row between MuJoCo
    making the rows and solving them (set_friction_level). If MuJoCo ran compute before
    making the rows, the row would hold the model's 1 N; if after the solve, the solver
    could not have held the load with more than 1 N: either way this fails."""
    params = preset("wpam")
    muscle = MuscleModel.from_params(params)
    pi = 0.2 * MPA
    load = muscle.tension(0.0, pi, 0.0) + 0.9 * muscle.friction(0.0, pi, 0.0)
    model = mujoco.MjModel.from_xml_string(user_model({"start": "rest"}, load=load))
    data = run(model, (pi, 0.0), 0.2)
    rows = np.flatnonzero(data.efc_type[:data.nefc]
                          == mujoco.mjtConstraint.mjCNSTR_FRICTION_TENDON)
    assert rows.size == 1 and model.tendon_frictionloss[0] == 1.0
    level = plugin.state_of(model, data, "m")["friction"]
    assert data.efc_frictionloss[rows[0]] == level > 100.0
    assert abs(data.efc_force[rows[0]]) > 0.5 * level  # the stiction the solver applied


def _runs(control: str, params, dt: float):
    """A short staircase (feedback) or ramp (open loop) through simulate."""
    t = np.arange(round(4.0 / dt)) * dt
    if control == "open":
        pi = 0.3 * MPA * np.minimum(t / 2.0, 1.0)
        po = np.where(t > 3.0, 0.02 * MPA, 0.0) if params.outer_chamber else 0.0 * t
        drive = Drive(pi, po, np.full(len(t), np.nan))
    else:
        x_ref = step_targets(t, (0, 10, 20), hold=1.5) * 1e-3
        drive = drive_for_targets(params, 100.0, x_ref, control, dt)
    return [simulate(params, 100.0, drive, dt=dt, control=control, record_dt=0.01,
                     engine=e) for e in ("plugin", "python")]


@pytest.mark.parametrize("name", ["wpam", "rlam", "mckibben"])
@pytest.mark.parametrize("control", ["open", "pi", "pid", "pi_ff"])
@pytest.mark.parametrize("dt", [1e-3, 5e-4])
def test_plugin_and_python_engine_are_bit_identical(name, control, dt):
    params = preset(name)
    if not params.outer_chamber and control != "open":
        pytest.skip(f"the {name} muscle has no outer chamber for Po feedback")
    a, b = _runs(control, params, dt)
    for field in REC_FIELDS:
        np.testing.assert_array_equal(getattr(a, field), getattr(b, field), err_msg=field)


@pytest.mark.parametrize("control", ["open", "pi"])
def test_polytropic_chambers_reach_both_engines_alike(control):
    """pneumatics.polytropic_index goes into every chamber step: adiabatic air (1.4) runs
    bit for bit on both engines, and its chambers follow their regulators faster than
    isothermal ones."""
    params = preset("wpam").with_values({"pneumatics.polytropic_index": 1.4})
    a, b = _runs(control, params, 1e-3)
    for field in REC_FIELDS:
        np.testing.assert_array_equal(getattr(a, field), getattr(b, field), err_msg=field)
    isothermal, _ = _runs(control, preset("wpam"), 1e-3)
    early = a.time < 1.0  # Pi still rising toward its command
    lag = {name: np.mean(np.abs(r.pi - r.pi_reg)[early]) for name, r in
           (("adiabatic", a), ("isothermal", isothermal))}
    assert lag["adiabatic"] < lag["isothermal"], lag


def test_in_plugin_feedforward_equals_the_drives():
    """One channel (x_ref): the plugin computes eq. 5's Pi itself, as control.pi_feedforward."""
    params = preset("wpam")
    dt, load = 1e-3, 100.0
    t = np.arange(3000) * dt
    x_ref = step_targets(t, (0, 10, 20), hold=1.0) * 1e-3
    drive = drive_for_targets(params, load, x_ref, "pi", dt)
    full = simulate(params, load, drive, dt=dt, control="pi", engine="plugin")
    from wpam_mj.simulation.model import rig_spec  # noqa: PLC0415

    def one_channel():
        spec = rig_spec(RunContext(params, dt, load, "pi"), start_at_rest=True,
                        feedforward_load=load)
        spec.delete(spec.actuator("muscle_pi_cmd"))
        return spec

    def run(model, muscles=()):
        data, xs = mujoco.MjData(model), []
        for step in range(len(t)):
            xs.append(data.qpos[0])  # recorded at the start of the step, as simulate
            data.ctrl[0] = x_ref[step]
            if muscles:
                engine.step(model, data, list(muscles))
            else:
                mujoco.mj_step(model, data)
        return np.array(xs)

    compiled = run(one_channel().compile())
    np.testing.assert_allclose(compiled[::10], full.x, atol=1e-12)
    np.testing.assert_array_equal(run(*engine.python_model(one_channel())), compiled)


def test_state_save_restore_and_reset_carry_the_pneumatics():
    """mj_getState/mj_setState and mj_resetData: the plugin's state lives in mjData."""
    model = mujoco.MjModel.from_xml_string(user_model({"start": "rest"}))
    data = run(model, (0.3 * MPA, 0.02 * MPA), 0.5)
    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    saved = np.empty(mujoco.mj_stateSize(model, spec))
    mujoco.mj_getState(model, data, saved, spec)
    first = [mujoco.mj_step(model, data) or data.qpos[0] for _ in range(300)]
    mujoco.mj_setState(model, data, saved, spec)
    again = [mujoco.mj_step(model, data) or data.qpos[0] for _ in range(300)]
    assert first == again
    mujoco.mj_resetData(model, data)
    fresh = mujoco.MjData(model)
    np.testing.assert_array_equal(data.plugin_state, fresh.plugin_state)


def test_batch_results_are_bit_identical_at_any_thread_count_and_to_one_mjdata():
    model = mujoco.MjModel.from_xml_string(user_model({"start": "rest"}))
    nsim, nstep = 6, 400
    ctrl = np.stack([np.full((nstep, 2), (0.1 + 0.04 * i) * MPA) * (1, 0.1)
                     for i in range(nsim)])
    outs = []
    for nthread in (1, 2):
        batch = mjbatch.Batch(model, nsim, nthread=nthread)
        batch.reset()
        outs.append(batch.rollout(nstep, control=ctrl, record=("qpos", "plugin_state")))
    for key in ("qpos", "plugin_state"):
        np.testing.assert_array_equal(outs[0][key], outs[1][key], err_msg=key)
    data = run(model, ctrl[3, 0], nstep * model.opt.timestep)
    assert data.qpos[0] == outs[0]["qpos"][3, -1, 0]


def test_halving_the_step_moves_the_sine_gain_and_lag_little():
    """Time-step convergence on the plugin: 0.25 Hz PI at 100 N, gain < 2 %, lag < 1 deg."""
    spec = SineSpec(0.25, settle_cycles=1, cycles=2)
    points = []
    for dt in (1e-3, 5e-4):
        r = sine_run(preset("wpam"), 100.0, "pi", spec, dt=dt, engine="plugin")
        points.append(frequency_response(r.time, r.x_ref, r.x, spec.freq, settle_cycles=1,
                                         n_cycles=2))
    assert math.isclose(points[0].gain, points[1].gain, rel_tol=0.02), points
    assert abs(points[0].phase_lag_deg - points[1].phase_lag_deg) < 1.0, points


def test_many_runs_equal_simulate_at_any_thread_count():
    """Runs of two layouts (PI and open loop) and three loads through mujoco.batch."""
    from wpam_mj.simulation.execution import execute  # noqa: PLC0415
    from wpam_mj.simulation.simulate import Run  # noqa: PLC0415

    params, dt = preset("wpam"), 1e-3
    t = np.arange(1500) * dt
    x_ref = step_targets(t, (0, 10), hold=0.75) * 1e-3
    runs, singles = [], []
    for load in (60.0, 100.0, 140.0):
        feedback = drive_for_targets(params, load, x_ref, "pi", dt)
        open_loop = Drive(np.full(len(t), 0.2 * MPA), np.zeros(len(t)), np.full(len(t), np.nan))
        for control, drive in (("pi", feedback), ("open", open_loop)):
            runs.append(Run.make(RunContext(params, dt, load, control), drive))
            singles.append(simulate(params, load, drive, dt=dt, control=control,
                                    engine="python"))
    for nthread in (1, 2):
        for got, ref in zip(execute(runs, nthread), singles):
            for field in REC_FIELDS:
                np.testing.assert_array_equal(getattr(got, field), getattr(ref, field),
                                              err_msg=f"{field}, {nthread} threads")


def test_a_conductance_too_fast_for_the_step_is_refused_naming_the_dt_it_needs():
    """1e-6 m^3/(s Pa) is inside the accepted range, but its chamber fills in ~80 us: the
    explicit update at 1 ms would swing the gauge pressure negative."""
    config = {"pneumatics.inner_conductance": "1e-6"}
    with pytest.raises(ValueError, match=r"timestep = 0.001 s is outside the allowed range "
                                         r"\(0, 7.96474e-05\] s \(the explicit update of "
                                         r"the inner chamber, fed through "
                                         r"pneumatics.inner_conductance"):
        mujoco.MjModel.from_xml_string(user_model(config))
    params = preset("wpam").with_values({"pneumatics.inner_conductance": 1e-6})
    n = 100
    drive = Drive(np.full(n, 0.3 * MPA), np.zeros(n), np.full(n, np.nan))
    with pytest.raises(ValueError, match=r"use dt <= 7.96e-05 s"):
        simulate(params, 100.0, drive, dt=1e-3)
    assert simulate(params, 100.0, drive, dt=5e-5, record_dt=5e-5).pi.min() >= 0.0


def test_rk4_is_refused_naming_the_integrators_that_work():
    xml = user_model({}).replace('<option timestep="0.001"', '<option integrator="RK4" '
                                 'timestep="0.001"')
    with pytest.raises(ValueError, match="RK4 integrator .* use Euler, implicit"):
        mujoco.MjModel.from_xml_string(xml)


def test_mujoco_rollout_on_two_threads_equals_one_and_carries_the_state():
    from mujoco import rollout  # noqa: PLC0415

    model = mujoco.MjModel.from_xml_string(user_model({"start": "rest"}))
    nbatch, nstep = 4, 300
    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    data = mujoco.MjData(model)
    initial = np.empty(mujoco.mj_stateSize(model, spec))
    mujoco.mj_getState(model, data, initial, spec)
    ctrl = np.stack([np.full((nstep, 2), (0.1 + 0.05 * i) * MPA) * (1, 0.1)
                     for i in range(nbatch)])
    one = rollout.rollout(model, mujoco.MjData(model), np.tile(initial, (nbatch, 1)), ctrl)[0]
    two = rollout.rollout(model, [mujoco.MjData(model), mujoco.MjData(model)],
                          np.tile(initial, (nbatch, 1)), ctrl)[0]
    np.testing.assert_array_equal(one, two)
    data.ctrl[:] = ctrl[2, 0]
    mujoco.mj_step(model, data, nstep=nstep)
    final = np.empty(mujoco.mj_stateSize(model, spec))
    mujoco.mj_getState(model, data, final, spec)
    np.testing.assert_array_equal(one[2, -1], final)  # plugin state included
    state = plugin.state_of(model, data, "m")
    assert state["pi_cmd"] == ctrl[2, 0, 0] and state["tension"] > 0.0
