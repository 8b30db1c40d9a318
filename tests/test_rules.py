"""The declared rule set (`wpam_mj.physics.rules`): every rule of the table, broken on its
own, is refused by the compiled plugin and the Python engine with the same one line, which
names the instance, the attribute, the value and the allowed range; so are words, unknown
keys, empty values and channels on another tendon (where MuJoCo lets the plugin see them)."""

from __future__ import annotations

import math
import re

import mujoco
import pytest

import wpam_mj  # noqa: F401 (registers the plugin)
from wpam_mj.physics import rules
from wpam_mj.physics.params import preset
from wpam_mj.errors import ParameterError
from wpam_mj.simulation import engine, plugin

pytestmark = pytest.mark.skipif(plugin.compiler() is None or plugin.disabled(),
                                reason="no C compiler (or WPAM_MJ_NO_COMPILE): no plugin")

PREFIX = "wpam_mj.muscle instance 'm': "
BASE = preset("wpam")


def model_xml(config: dict[str, str], *, timestep: float = 1e-3, acts: str | None = None,
              extra_instance: str = "") -> str:
    """Two tendons, one muscle "m" on "cable" with the given attributes (MJCF text)."""
    keys = "".join(f'<config key="{k}" value="{v}"/>' for k, v in config.items())
    acts = acts or ('<plugin name="pi" instance="m" tendon="cable"/>'
                    '<plugin name="po" instance="m" tendon="cable"/>')
    return f"""
<mujoco>
  <option timestep="{timestep!r}"/>
  <extension><plugin plugin="wpam_mj.muscle">
    <instance name="m">{keys}</instance>{extra_instance}
  </plugin></extension>
  <worldbody>
    <site name="top" pos="0 0 1"/>
    <body pos="0 0 0.65"><joint name="lift" type="slide" axis="0 0 1"/>
      <geom size="0.03" mass="10"/><site name="hook"/></body>
    <body pos="0.2 0 0.65"><joint name="other" type="slide" axis="0 0 1"/>
      <geom size="0.03" mass="10"/><site name="hook2"/></body>
  </worldbody>
  <tendon>
    <spatial name="cable" frictionloss="1"><site site="top"/><site site="hook"/></spatial>
    <spatial name="cable2" frictionloss="1"><site site="top"/><site site="hook2"/></spatial>
  </tendon>
  <actuator>{acts}</actuator>
</mujoco>"""


def both_refuse(xml: str) -> str:
    """The line the compiled plugin fails the compile with, after checking that the Python
    engine refuses the same model with the same line."""
    with pytest.raises(ValueError) as compiled:
        mujoco.MjModel.from_xml_string(xml)
    with pytest.raises(ParameterError) as python:
        engine.python_model(mujoco.MjSpec.from_string(xml))
    line = str(python.value)
    assert "\n" not in line
    assert str(compiled.value).splitlines()[0] == f"Error: engine error: {line}"
    return line


def _just_outside(bound: float, below: bool, is_open: bool) -> float:
    """A number just outside the bound (the bound itself where it is open)."""
    if is_open:
        return bound
    step = 1e-3 * abs(bound) if bound else 1e-3
    return bound - step if below else bound + step


def _cases():
    """(rule, side, config, timestep): every rule of the table broken on one side."""
    values = {key: BASE.value(key) for key, _ in plugin.parameter_fields()}
    values.update(feedforward_load=0.0, contraction0=0.0, timestep=1e-3)
    cases = []
    for rule in rules.all_rules():
        for side in ("lo", "hi"):
            limit = rules.bound(getattr(rule, side), values.__getitem__)
            if not math.isfinite(limit):
                continue
            v = _just_outside(limit, side == "lo", getattr(rule, f"{side}_open"))
            if rule.subject == rules.TIMESTEP:  # broken through what bounds it
                if side == "lo" and rule.lo == 0.0:
                    continue  # MuJoCo refuses a time step <= 0 itself
                config = ({"pneumatics.dead_time": "1"} if side == "lo" else
                          {f"pneumatics.{rule.hi.split('_')[0]}_conductance": "1e-6"})
                cases.append(pytest.param(rule, config, 5e-7 if side == "lo" else 1e-3,
                                          id=f"timestep-{rule.hi if side == 'hi' else 'lo'}"))
                continue
            own = next(r for r in rules.field_rules() if r.subject == rule.subject)
            if rule in rules.CROSS_RULES and rules.violation(own, {rule.subject: v}.__getitem__):
                continue  # the field's own range refuses this side first
            cases.append(pytest.param(rule, {rule.subject: repr(v)}, 1e-3,
                                      id=f"{rule.subject}-{side}-{rule.why[:12] or 'own'}"))
    return cases


@pytest.mark.parametrize("rule, config, timestep", _cases())
def test_every_rule_is_refused_by_both_engines_with_one_line(rule, config, timestep):
    line = both_refuse(model_xml(config, timestep=timestep))
    expected = re.escape(f"{PREFIX}{rule.subject} = ")
    assert re.match(expected, line), line
    assert "is outside the allowed range" in line and (rule.why in line), line


def test_the_table_covers_every_parameter_and_every_cross_rule():
    cases = _cases()
    subjects = {c.values[0].subject for c in cases}
    assert {key for key, _ in plugin.parameter_fields()} <= subjects
    assert {r for r in rules.CROSS_RULES} <= {c.values[0] for c in cases}


@pytest.mark.parametrize("config, line", [
    ({"muscle.output_coeff": "abc"},
     "muscle.output_coeff = 'abc' is not a number; allowed: (0, 1]"),
    ({"pneumatics.dead_time": "1e-2x"},
     "pneumatics.dead_time = '1e-2x' is not a number; allowed: [0, 1] s"),
    ({"contraction0": "nan"}, "contraction0 = 'nan' is not a number; allowed: (-inf, inf) m"),
    ({"controller.po_cap": "6e5"},
     "controller.po_cap = 600000 Pa is outside the allowed range [5000, 500000] Pa (within "
     "the regulator's range, pneumatics.p_min to pneumatics.p_max)"),
    ({"contraction0": "-0.05"},
     "contraction0 = -0.05 m is outside the allowed range [0, 0.0932"),
    ({"preset": "steel"}, "preset = 'steel' is not one of: wpam, rlam, mckibben"),
    ({"end_fittings": "glued"}, "end_fittings = 'glued' is not one of: free, guided"),
])
def test_words_and_values_get_their_own_line(config, line):
    assert both_refuse(model_xml(config)).startswith(PREFIX + line)


def test_a_channel_on_another_tendon_is_refused():
    acts = ('<plugin name="pi" instance="m" tendon="cable"/>'
            '<plugin name="po" instance="m" tendon="cable2"/>')
    assert both_refuse(model_xml({}, acts=acts)) == (
        f"{PREFIX}actuator 'po' does not act on the muscle's tendon 'cable'; every input "
        "channel names the muscle's tendon")


def test_two_muscles_on_one_tendon_are_refused():
    acts = ('<plugin name="pi" instance="m" tendon="cable"/>'
            '<plugin name="po" instance="m" tendon="cable"/>'
            '<plugin name="pi2" instance="n" tendon="cable"/>'
            '<plugin name="po2" instance="n" tendon="cable"/>')
    xml = model_xml({}, acts=acts, extra_instance='<instance name="n"/>')
    assert both_refuse(xml) == ("wpam_mj.muscle instances 'm' and 'n' both pull tendon "
                                "'cable'; one muscle per tendon")


def test_unknown_keys_and_empty_values_get_their_own_line_where_the_plugin_sees_them():
    """MuJoCo refuses an unknown key before any plugin code runs, and stores an empty value
    as no value; the Python engine, which reads the MJCF itself, names both."""
    with pytest.raises(ValueError, match="unrecognized attribute 'plugin:bogus'"):
        mujoco.MjModel.from_xml_string(model_xml({"bogus": "1"}))
    for config, line in (({"bogus": "1"}, "unknown attribute 'bogus'; the attributes are "),
                         ({"muscle.damping": ""}, "muscle.damping is empty")):
        with pytest.raises(ParameterError) as err:
            engine.python_model(mujoco.MjSpec.from_string(model_xml(config)))
        assert str(err.value).startswith(PREFIX + line), err.value


def test_params_refuse_the_same_rules_as_the_plugin():
    with pytest.raises(ParameterError, match=r"^controller\.po_cap = 600000 Pa is outside "
                                             r"the allowed range \[5000, 500000\] Pa"):
        BASE.replace(controller={"po_cap": 6e5})
