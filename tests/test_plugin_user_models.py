"""What a user's own model does with the plugin where MuJoCo alone would not stop it: a Po
channel on a muscle without an outer chamber, a tendon's frictionloss zeroed after compile,
a tendon range that lets the braid stretch. Each is refused or flagged alike on both engines.
"""

from __future__ import annotations

import functools
import subprocess
import sys
import textwrap

import mujoco
import pytest

import wpam_mj  # noqa: F401 (registers the plugin)
from wpam_mj.physics.geometry import BraidGeometry
from wpam_mj.physics.params import preset
from wpam_mj.errors import ParameterError
from wpam_mj.simulation import engine, plugin

pytestmark = pytest.mark.skipif(plugin.compiler() is None or plugin.disabled(),
                                reason="no C compiler (or WPAM_MJ_NO_COMPILE): no plugin")


def hanging(preset: str = "wpam", channels: tuple[str, ...] = ("pi", "po"),
            tendon: str = 'limited="true" range="0.3068 0.4"', instance: str = "") -> str:
    """A muscle from a ceiling site to a 5 kg load on a slide: 0.4 m of tendon at qpos0."""
    actuators = "\n".join(f'<plugin name="m_{c}" instance="m" tendon="m" ctrlrange="0 500000"/>'
                          for c in channels)
    return f"""
<mujoco>
  <option timestep="0.001" noslip_iterations="2"/>
  <extension><plugin plugin="wpam_mj.muscle">
    <instance name="m"><config key="preset" value="{preset}"/>{instance}</instance>
  </plugin></extension>
  <worldbody>
    <site name="top" pos="0 0 1"/>
    <body name="load" pos="0 0 0.6">
      <joint name="slide" type="slide" axis="0 0 1" damping="50"/>
      <geom type="sphere" size="0.03" mass="5"/>
      <site name="hook"/>
    </body>
  </worldbody>
  <tendon><spatial name="m" frictionloss="1" {tendon}>
    <site site="top"/><site site="hook"/></spatial></tendon>
  <actuator>{actuators}</actuator>
</mujoco>"""


def both_engines(xml: str) -> list[str]:
    """The line each engine refuses `xml` with ("" where it compiles)."""
    lines = []
    try:
        mujoco.MjModel.from_xml_string(xml)
        lines.append("")
    except ValueError as e:
        lines.append(str(e).split("engine error: ")[-1].splitlines()[0])
    try:
        engine.python_model(mujoco.MjSpec.from_string(xml))
        lines.append("")
    except ParameterError as e:
        lines.append(str(e))
    return lines


# ---------------------------------------------------------------- no outer chamber, no Po

@pytest.mark.parametrize("preset", ["rlam", "mckibben"])
def test_a_po_channel_on_a_muscle_without_an_outer_chamber_is_refused_on_both_engines(preset):
    """Once such a muscle obeyed a Po command (McKibben at Pi 0.25 MPa: 52.2 N, with Po
    0.1 MPa 45.6 N) that `simulate` refuses; now the channel itself is refused, naming the
    preset and what is allowed, and the muscle takes its Pi command alone."""
    plugin_line, python_line = both_engines(hanging(preset))
    assert plugin_line == python_line == (
        f"wpam_mj.muscle instance 'm': preset '{preset}' has no outer chamber, so no Po "
        "channel: control = 'open' takes at most 1 actuator(s) on it, 2 name the instance; "
        "remove actuator 'm_po'")
    assert both_engines(hanging(preset, channels=("pi",))) == ["", ""]
    assert "no outer chamber" in both_engines(hanging(preset, channels=("pi", "po", "x")))[0]
    assert both_engines(hanging("wpam", channels=("pi",)))[0].endswith(
        "control = 'open' takes 2 to 2 actuators (input channels), 1 name the instance")


def test_a_muscle_without_a_po_channel_runs_alike_on_both_engines():
    xml = hanging("mckibben", channels=("pi",))
    model = mujoco.MjModel.from_xml_string(xml)
    data = mujoco.MjData(model)
    data.ctrl[0] = 0.25e6
    mujoco.mj_step(model, data, nstep=500)
    pmodel, muscles = engine.python_model(mujoco.MjSpec.from_string(xml))
    pdata = mujoco.MjData(pmodel)
    pdata.ctrl[0] = 0.25e6
    engine.step(pmodel, pdata, muscles, 500)
    state = plugin.state_of(model, data, "m")
    assert state["po_cmd"] == 0.0 and state["pi"] > 0.0 and state["tension"] > 0.0
    assert pdata.qpos[0] == data.qpos[0]
    assert muscles[0].state(pdata)[plugin.FIELD["po_cmd"]] == 0.0


# ---------------------------------------------------------------- the friction row, after compile

@pytest.fixture
def elsewhere(tmp_path, monkeypatch):
    """MuJoCo appends its warnings to MUJOCO_LOG.TXT in the working folder: not the repo's."""
    monkeypatch.chdir(tmp_path)
    return tmp_path


@pytest.mark.parametrize("change, why", [
    ("m.tendon_frictionloss[0] = 0", "tendon 'm' frictionloss = 0 after the model compiled"),
    ("m.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_FRICTIONLOSS",
     "MuJoCo's frictionloss flag is disabled after the model compiled"),
    ("m.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONSTRAINT",
     "MuJoCo's constraint flag is disabled after the model compiled"),
])
def test_a_muscle_left_without_its_friction_row_stops_with_one_warning(elsewhere, change, why):
    """Zeroing the tendon's frictionloss after compile (refused at compile) once removed the
    muscle's dry friction silently: MuJoCo makes the row the plugin writes the level into
    only for a positive frictionloss, and with its constraint and frictionloss flags on.
    Now the muscle stops with STATUS_MODEL and one MuJoCo warning, as for a changed time
    step; changed back and reset, it runs again."""
    proc = subprocess.run([sys.executable, "-c", textwrap.dedent(f"""
        import mujoco, numpy as np, wpam_mj
        from wpam_mj.simulation import plugin
        m = mujoco.MjModel.from_xml_string({hanging()!r})
        d = mujoco.MjData(m)
        d.ctrl[:] = (0.3e6, 0.0)
        mujoco.mj_step(m, d, nstep=100)
        loss, flags = m.tendon_frictionloss[0], m.opt.disableflags
        {change}
        mujoco.mj_step(m, d, nstep=100)
        assert plugin.state_of(m, d, "m")["status"] == plugin.STATUS_MODEL
        assert np.all(d.actuator_force == 0.0)
        m.tendon_frictionloss[0], m.opt.disableflags = loss, flags
        mujoco.mj_resetData(m, d)
        d.ctrl[:] = (0.3e6, 0.0)
        mujoco.mj_step(m, d, nstep=100)
        assert plugin.state_of(m, d, "m")["status"] == 0 and d.actuator_force[0] < 0.0
        print("ok")
    """)], capture_output=True, text=True, timeout=300, cwd=elsewhere)
    assert proc.returncode == 0 and proc.stdout.strip().endswith("ok"), proc.stderr[-2000:]
    output = (proc.stdout + proc.stderr).splitlines()
    warnings = [line for line in output if line.startswith("WARNING")]
    assert len(warnings) == 1 and f"wpam_mj.muscle instance 'm': {why}" in warnings[0], warnings


def test_the_python_engine_stops_a_muscle_without_its_friction_row_alike(capsys):
    model, muscles = engine.python_model(mujoco.MjSpec.from_string(hanging()))
    data = mujoco.MjData(model)
    data.ctrl[:2] = (0.3e6, 0.0)
    step = functools.partial(step_python, model, muscles, data)
    step(100)
    model.tendon_frictionloss[0] = 0.0
    step(100)
    assert muscles[0].state(data)[plugin.FIELD["status"]] == plugin.STATUS_MODEL
    assert data.ctrl[muscles[0].force_actuator] == 0.0
    err = capsys.readouterr().err
    assert err.count("WARNING: wpam_mj.muscle instance 'm': tendon 'm' frictionloss = 0 after "
                     "the model compiled") == 1, err
    model.tendon_frictionloss[0] = 1.0
    mujoco.mj_resetData(model, data)
    step(100)
    assert muscles[0].state(data)[plugin.FIELD["status"]] == 0
    assert data.ctrl[muscles[0].force_actuator] < 0.0


@pytest.mark.parametrize("flag", ["frictionloss", "constraint"])
def test_a_model_compiled_without_friction_rows_is_refused_on_both_engines(flag):
    xml = hanging().replace("<option ", f'<option><flag {flag}="disable"/></option>\n  <option ')
    plugin_line, python_line = both_engines(xml)
    assert plugin_line == python_line == (
        f"wpam_mj.muscle instance 'm': MuJoCo's {flag} flag is disabled, so no friction row "
        "carries the muscle's dry friction; enable it")


def step_python(model, muscles, data, n):
    engine.step(model, data, muscles, n)


# ---------------------------------------------------------------- the tendon's range

LOOSE = 'limited="true" range="0.3068 1"'  # an upper bound far past the natural length


def test_tendon_range_is_the_stroke_in_tendon_lengths():
    """range = [natural length - x_max, natural length]; the natural length is the
    tendon's length at qpos0 plus contraction0; x_max from the instance's braid."""
    model = mujoco.MjModel.from_xml_string(hanging())  # 0.4 m of tendon at qpos0
    r = plugin.tendon_range(model, "m")
    x_max = BraidGeometry.from_params(preset("wpam").braid).max_contraction
    assert (r.upper, r.max_contraction) == (model.tendon_length0[0], x_max)
    assert r.lower == r.upper - x_max and r.mjcf == f'limited="true" range="{r.lower:.6g} 0.4"'
    narrower = preset("wpam").with_values({"braid.max_diameter": 0.035})
    model = mujoco.MjModel.from_xml_string(hanging(instance=(
        '<config key="contraction0" value="0.02"/>'
        '<config key="braid.max_diameter" value="0.035"/>'), channels=("pi", "po")))
    r = plugin.tendon_range(model, 0)
    assert r.upper == model.tendon_length0[0] + 0.02
    assert r.max_contraction == BraidGeometry.from_params(narrower.braid).max_contraction != x_max


def test_the_range_holds_a_load_at_the_natural_length_where_a_loose_one_lets_it_stretch(
        elsewhere):
    """A vented muscle under 5 kg: with the docs' old upper bound (1 m) gravity stretches
    the inextensible braid tens of mm past its natural length, STATUS_STROKE and one MuJoCo
    warning naming the range; with `tendon_range`'s, it stops within the tolerance."""
    proc = subprocess.run([sys.executable, "-c", textwrap.dedent(f"""
        import mujoco, wpam_mj
        from wpam_mj.simulation import plugin
        for tendon in ({LOOSE!r}, None):
            m = mujoco.MjModel.from_xml_string({hanging(tendon=LOOSE)!r})
            if tendon is None:
                m = mujoco.MjModel.from_xml_string({hanging(tendon=LOOSE)!r}.replace(
                    {LOOSE!r}, plugin.tendon_range(m, "m").mjcf))
            d = mujoco.MjData(m)
            mujoco.mj_step(m, d, nstep=2000)
            s = plugin.state_of(m, d, "m")
            print("x", s["x"], s["status"])
    """)], capture_output=True, text=True, timeout=300, cwd=elsewhere)
    assert proc.returncode == 0, proc.stderr[-2000:]
    output = (proc.stdout + proc.stderr).splitlines()
    (loose_x, loose_status), (held_x, held_status) = [
        tuple(map(float, line.split()[1:])) for line in output if line.startswith("x ")]
    assert loose_x < -0.02 and loose_status == plugin.STATUS_STROKE
    assert -plugin.STROKE_TOLERANCE < held_x <= 0.0 and held_status == 0
    warnings = [line for line in output if line.startswith("WARNING")]
    assert len(warnings) == 1 and "left the stroke [0, 0.0932457] m" in warnings[0], output
    assert 'range="0.306754 0.4" (plugin.tendon_range)' in warnings[0]


def test_the_python_engine_warns_once_when_a_muscle_leaves_its_stroke(capsys):
    model, muscles = engine.python_model(mujoco.MjSpec.from_string(hanging(tendon=LOOSE)))
    data = mujoco.MjData(model)
    step_python(model, muscles, data, 2000)
    state = muscles[0].state(data)
    assert state[plugin.FIELD["status"]] == plugin.STATUS_STROKE
    assert state[plugin.FIELD["x"]] < -0.02
    err = capsys.readouterr().err
    assert err.count("WARNING: wpam_mj.muscle instance 'm': contraction x = ") == 1, err
    assert 'range="0.306754 0.4" (plugin.tendon_range)' in err
