"""The Python engine: the muscle's readable definition, run as a MuJoCo control callback.

Any model that declares ``wpam_mj.muscle`` actuators (docs/plugin.md) runs either on the
compiled plugin (`wpam_mj.simulation.plugin`, the product) or here, where `python_model` replaces
each instance's actuators by plain motors that carry no force (their ctrl stays the input
channels) plus one force motor on the muscle's tendon, and `PythonMuscle` computes the
muscle in Python, piece for piece what ``muscle_plugin.c`` does in C:

  compute (installed as ``mjcb_control``, which MuJoCo calls after the constraint rows are
    made and before actuation and the solve, as it calls a plugin's compute): x, v from the
    tendon; the commands; the controller's Po output, evaluated but not kept; the tendon
    force from the chamber pressures -> the force motor; the friction level -> this
    simulation's friction row of the tendon (`d.efc_frictionloss`).
  advance (after mj_step, once per step): the controller's state kept, the regulators and
    chambers advanced (`wpam_mj.simulation.plant.Plant.step`).

Configurations are checked against the rule table `wpam_mj.physics.rules`, with the same
line as the compiled plugin (`InstanceConfig.from_config`, `python_model`).

`stepping` installs the callback for the duration of a ``with`` block only: MuJoCo's
callbacks are process-global, and a Python one makes every model compilation fail while it
is installed. Within the block, ``mj_step`` then `advance` is one step; a loop that only
calls ``mj_step`` (a viewer) also works, as compute advances the previous step when the
time has moved on. tests/test_plugin.py checks that the plugin is bit-identical to this.
"""

from __future__ import annotations

import contextlib
import ctypes
import math
import re
import sys
from dataclasses import dataclass
from typing import Iterator

import mujoco
import numpy as np

from wpam_mj.simulation import plugin
from wpam_mj.control.controllers import CONTROLLERS, PoController, make_controller, pi_feedforward
from wpam_mj.simulation.loop_contract import REC_FIELDS, RunConstants, SimulationDiverged
from wpam_mj.physics import rules
from wpam_mj.physics.muscle import MuscleModel
from wpam_mj.physics.params import ParameterError, Params, parameter_fields, preset
from wpam_mj.simulation.plant import Plant

_RK4 = int(mujoco.mjtIntegrator.mjINT_RK4)


@dataclass(frozen=True)
class InstanceConfig:
    """One plugin instance's configuration, read from its MJCF `config` attributes."""

    name: str
    params: Params
    control: str
    start_at_rest: bool
    guided: bool  # end fittings held on one axis (MuscleModel.tendon_force)
    feedforward_load: float  # [N]
    contraction0: float  # contraction in the model's reference pose [m]

    @classmethod
    def from_config(cls, name: str, config: dict[str, str], timestep: float,
                    integrator: int = 0) -> "InstanceConfig":
        """Read and check the attributes as the compiled plugin does when the model
        compiles (its `read_config`: the same order, rules and line), for a model of this
        `timestep` [s] and integrator; raises ParameterError with that line."""
        prefix = f"wpam_mj.muscle instance '{name}': "
        known = set(plugin.attribute_names())
        for key, value in config.items():
            if key not in known:
                raise ParameterError(f"{prefix}unknown attribute {key!r}; the attributes are "
                                     f"{', '.join(plugin.INSTANCE_KEYS)} and every parameter"
                                     " by its section.field name (models/README.md)")
            if value == "":  # the compiled plugin cannot see this: MuJoCo drops it
                raise ParameterError(f"{prefix}{key} is empty; give it a value or leave the "
                                     "attribute out")
        words = {}
        for key, allowed in {**plugin.INSTANCE_WORDS, "control": tuple(CONTROLLERS)}.items():
            words[key] = config.get(key) or allowed[0]
            if words[key] not in allowed:
                raise ParameterError(f"{prefix}{key} = '{words[key]}' is not one of: "
                                     f"{', '.join(allowed)}")
        base = preset(words["preset"])
        values: dict[str, float] = {key: base.value(key) for key, _ in parameter_fields()}
        values.update(feedforward_load=0.0, contraction0=0.0)
        own = {r.subject: r for r in rules.field_rules()}
        for key in values:
            text = config.get(key)
            if text is None:
                continue
            rule = own[key]
            value = rules.parse_number(text)
            if value is None:
                raise ParameterError(rules.not_a_number(prefix, key, text, rule))
            bad = rules.violation(rule, {key: value}.__getitem__)
            if bad is not None:
                raise ParameterError(rules.message(prefix, key, *bad, rule.lo_open,
                                                   rule.hi_open))
            values[key] = value
        control = words["control"]
        if CONTROLLERS[control].feedback and not base.outer_chamber:
            raise ParameterError(f"{prefix}preset '{base.preset}' has no outer chamber for Po "
                                 f"feedback (control = '{control}'); use control = 'open'")
        values[rules.TIMESTEP] = timestep
        rules.check(rules.CROSS_RULES, values.__getitem__, prefix)
        if integrator == _RK4:
            raise ParameterError(f"{prefix}the RK4 integrator evaluates each step four times; "
                                 "use Euler, implicit or implicitfast (the pneumatics advance "
                                 "once per step)")
        params = base.with_values({k: v for k, v in values.items() if "." in k})
        return cls(name, params, control, words["start"] == "rest",
                   words["end_fittings"] == "guided", values["feedforward_load"],
                   values["contraction0"])


def instance_configs(spec: mujoco.MjSpec) -> dict[str, InstanceConfig]:
    """Every wpam_mj.muscle instance of `spec`, by name."""
    return {p.name: InstanceConfig.from_config(p.name, dict(p.config), spec.option.timestep,
                                               int(spec.option.integrator))
            for p in spec.plugins if p.plugin_name == plugin.NAME}


class PythonMuscle:
    """One muscle instance computed in Python on a model made by `python_model`."""

    def __init__(self, model: mujoco.MjModel, config: InstanceConfig,
                 channels: list[int], force_actuator: int) -> None:
        self.config = config
        self.params = config.params
        self.channels = channels
        self.force_actuator = force_actuator
        self.tendon = int(model.actuator_trnid[force_actuator, 0])
        self.length0 = float(model.tendon_length0[self.tendon])
        self.dt = float(model.opt.timestep)
        self.integrator = int(model.opt.integrator)
        self.muscle = MuscleModel.from_params(self.params)
        self.feedback = plugin.control_mode(config.control).feedback
        self.friction_row = 0  # where the tendon's friction row was last step
        # each channel's ctrlrange where it is limited (read_commands clamps to it)
        self.ctrl_limits = [tuple(map(float, model.actuator_ctrlrange[a]))
                            if model.actuator_ctrllimited[a] else None for a in channels]
        self.refused = False  # the model's options changed after it was made (warned)
        self.reset()

    def reset(self) -> None:
        """Vented chambers, empty regulators, controller at its start (plugin reset)."""
        self.plant = Plant(self.muscle, RunConstants.make(self.params, self.dt, self.dt),
                           guided=self.config.guided)
        self.controller: PoController = make_controller(self.config.control, self.params,
                                                        self.dt)
        self.rest_pending = self.config.start_at_rest
        self.pending: tuple | None = None  # what compute computed and advance keeps
        self.status_bits = 0  # plugin.STATUS_* bits
        self.inputs = [0.0] * plugin.MAX_CHANNELS  # each channel's last finite command
        self.record = dict.fromkeys(REC_FIELDS[1:], 0.0)
        self.record["x_ref"] = math.nan

    @property
    def status(self) -> str:
        """Why the muscle's state left its range, in one line ("" while it has not)."""
        if not self.status_bits:
            return ""
        p_i, p_o = (c.pressure for c in (self.plant.chamber_i, self.plant.chamber_o))
        return plugin.status_message(self.status_bits, self.record["x"], p_i, p_o)

    @property
    def stopped(self) -> bool:
        """A muscle whose state left its range, or whose model changed, steps no more."""
        return bool(self.status_bits & (plugin.STATUS_PRESSURE | plugin.STATUS_MODEL))

    def _inputs(self, ctrl: np.ndarray) -> tuple[float, float, float]:
        """(x_ref, Pi command, Po command or feedforward) from the input channels (the
        plugin's read_commands): each clamped to its ctrlrange where limited, a
        non-finite one replaced by the channel's last finite value, x_ref held to the
        stroke."""
        values = []
        for i, (a, limits) in enumerate(zip(self.channels, self.ctrl_limits)):
            c = float(ctrl[a])
            if limits is not None:
                c = min(max(c, limits[0]), limits[1])
            if math.isfinite(c):
                self.inputs[i] = c
            values.append(self.inputs[i])
        if not self.feedback:  # no Po channel on a muscle without an outer chamber
            return math.nan, values[0], values[1] if len(values) > 1 else 0.0
        x_ref = self.muscle.geometry.in_stroke(values[0])
        if len(values) > 1:
            pi_cmd = values[1]
        else:
            pi_cmd = float(pi_feedforward(self.muscle, self.params, x_ref,
                                          self.config.feedforward_load,
                                          self.params.controller.po_feedforward))
        return x_ref, pi_cmd, values[2] if len(values) > 2 else 0.0

    def _options_changed(self, model: mujoco.MjModel) -> bool:
        """The plugin's refusal of a timestep or integrator changed after compile, or of a
        model left without the muscle's friction row (`no_friction_row`): status, and one
        warning line."""
        opt = model.opt
        if opt.timestep == self.dt and opt.integrator == self.integrator:
            why = no_friction_row(model, self.config.name, self.tendon, after=True)
            if why is None:
                self.refused = False
                return False
        else:
            what = "timestep" if model.opt.timestep != self.dt else "integrator"
            why = (f"wpam_mj.muscle instance '{self.config.name}': the {what} changed after "
                   f"the model compiled (timestep {model.opt.timestep:.6g} s, integrator "
                   f"{plugin.INTEGRATORS[int(model.opt.integrator)]}); the muscle stops "
                   "until it is changed back or the model recompiled")
        if not self.refused:
            print(f"WARNING: {why}", file=sys.stderr)
        self.refused = True
        self.status_bits |= plugin.STATUS_MODEL
        return True

    def _left_stroke(self, x: float) -> None:
        """The plugin's left_stroke: STATUS_STROKE, and the first time since the reset one
        warning line naming the tendon range that holds the muscle in its stroke."""
        if not self.status_bits & plugin.STATUS_STROKE:
            x_max = self.muscle.geometry.max_contraction
            natural = self.length0 + self.config.contraction0  # the tendon's length at x = 0
            print(f"WARNING: wpam_mj.muscle instance '{self.config.name}': contraction x = "
                  f"{x:.6g} m left the stroke [0, {x_max:.6g}] m by more than "
                  f"{plugin.STROKE_TOLERANCE:.6g} m (status {plugin.STATUS_STROKE}); limit "
                  "its tendon from the full bag to the natural length: "
                  f'range="{natural - x_max:.6g} {natural:.6g}" (plugin.tendon_range)',
                  file=sys.stderr)
        self.status_bits |= plugin.STATUS_STROKE

    def compute(self, model: mujoco.MjModel, data: mujoco.MjData) -> None:
        """The step's force and friction level; nothing kept but what advance needs."""
        if self.pending is not None and data.time != self.pending[0]:
            self.advance()  # a loop that only calls mj_step: the last step ends here
        if self._options_changed(model) or self.stopped:
            data.ctrl[self.force_actuator] = 0.0
            return
        x = self.config.contraction0 + (self.length0 - float(data.ten_length[self.tendon]))
        v = -float(data.ten_velocity[self.tendon])
        x_ref, pi_cmd, po_in = self._inputs(data.ctrl)
        po_cmd, ctl_state = self.controller.evaluate(x, x_ref, po_in)
        if self.rest_pending:
            self.plant.rest(pi_cmd, po_cmd)
        force, friction = self.plant.forces(x)
        tolerance = plugin.STROKE_TOLERANCE
        if not -tolerance <= x <= self.muscle.geometry.max_contraction + tolerance:
            self._left_stroke(x)
        if not math.isfinite(x):  # MuJoCo's state is already bad: add nothing to it
            force, friction = 0.0, self.params.muscle.friction_const
        pi, po = self.plant.pressures
        self.record.update(x=x, velocity=v, x_ref=x_ref, pi=pi, po=po, pi_cmd=pi_cmd,
                           po_cmd=po_cmd, tension=force, friction=friction)
        data.ctrl[self.force_actuator] = -force  # along the tendon's length
        self.friction_row = set_friction_level(data, self.tendon, friction,
                                               self.friction_row)
        self.pending = (float(data.time), x, v, pi_cmd, po_cmd, ctl_state)

    def advance(self) -> None:
        """Keep the controller's state, advance the regulators and chambers."""
        if self.pending is None or self.stopped:
            return
        _, x, v, pi_cmd, po_cmd, ctl_state = self.pending
        self.pending = None
        self.controller.commit(ctl_state)
        self.rest_pending = False
        try:
            self.plant.step(x, v, pi_cmd, po_cmd)
        except SimulationDiverged:
            self.status_bits |= plugin.STATUS_PRESSURE
        self.record["pi_reg"], self.record["po_reg"] = self.plant.set_points


_FRICTION_TENDON = int(mujoco.mjtConstraint.mjCNSTR_FRICTION_TENDON)
_NO_FRICTION_ROW = {"constraint": int(mujoco.mjtDisableBit.mjDSBL_CONSTRAINT),
                    "frictionloss": int(mujoco.mjtDisableBit.mjDSBL_FRICTIONLOSS)}


def no_friction_row(model: mujoco.MjModel, instance: str, tendon: int, *,
                    after: bool) -> str | None:
    """The plugin's no_friction_row: the line saying why MuJoCo makes no friction row for
    the muscle's tendon (its frictionloss not positive, or MuJoCo's constraint or
    frictionloss flag disabled), at compile or `after` it; None while it makes one."""
    prefix = f"wpam_mj.muscle instance '{instance}': "
    stop = "; the muscle stops until it is changed back and the data reset"
    name = model.tendon(tendon).name
    loss = float(model.tendon_frictionloss[tendon])
    if not loss > 0.0:
        if after:
            return (f"{prefix}tendon '{name}' frictionloss = {loss:.6g} after the model "
                    "compiled; it needs a positive one (any value; the plugin sets the level "
                    f"every step){stop}")
        return (f"{prefix}tendon '{name}' needs a positive frictionloss (any value; the "
                "plugin sets the level every step)")
    for flag, bit in _NO_FRICTION_ROW.items():
        if model.opt.disableflags & bit:
            return (f"{prefix}MuJoCo's {flag} flag is disabled"
                    f"{' after the model compiled' if after else ''}, so no friction row "
                    f"carries the muscle's dry friction{stop if after else '; enable it'}")
    return None


def set_friction_level(data: mujoco.MjData, tendon: int, friction: float,
                       row: int = 0) -> int:
    """Write this step's friction level [N] into the tendon's friction row (made by MuJoCo
    because the model's tendon_frictionloss is positive; the model stays untouched): the
    plugin's set_friction_level, which says why this runs at the right point of the step.
    `row`: where to look first (the row keeps its place while the set of equality and
    friction constraints before it does). Returns the row, `row` if there is none."""
    kinds, ids = data.efc_type, data.efc_id
    if not (row < data.nefc and kinds[row] == _FRICTION_TENDON and ids[row] == tendon):
        rows = np.flatnonzero((kinds[:data.nefc] == _FRICTION_TENDON)
                              & (ids[:data.nefc] == tendon))
        if not rows.size:
            return row
        row = int(rows[0])
    data.efc_frictionloss[row] = friction
    return row


def _channel_error(spec: mujoco.MjSpec, instance: str, config: InstanceConfig,
                   acts: list, others: dict[str, str]) -> str | None:
    """The plugin's bind_channels on the spec: the line of the first channel error."""
    prefix = f"wpam_mj.muscle instance '{instance}': "
    control = plugin.control_mode(config.control)
    n, nmax = len(acts), len(control.channels_for(config.params.outer_chamber))
    nmin = min(control.required, nmax)
    if n > nmax < len(control.channels):
        return (f"{prefix}preset '{config.params.preset}' has no outer chamber, so no Po "
                f"channel: control = '{control.name}' takes at most {nmax} actuator(s) on "
                f"it, {n} name the instance; remove actuator '{acts[nmax].name or '(unnamed)'}'")
    if not nmin <= n <= nmax:
        return (f"{prefix}control = '{control.name}' takes {nmin} to {nmax} actuators "
                f"(input channels), {n} name the instance")
    if acts[0].trntype != mujoco.mjtTrn.mjTRN_TENDON:
        return f"{prefix}its first actuator must act on a tendon (the muscle)"
    tendon = acts[0].target
    for act in acts[1:]:
        if act.trntype != mujoco.mjtTrn.mjTRN_TENDON or act.target != tendon:
            return (f"{prefix}actuator '{act.name}' does not act on the muscle's tendon "
                    f"'{tendon}'; every input channel names the muscle's tendon")
    names = list(others)
    for other, other_tendon in others.items():
        if other != instance and other_tendon == tendon:
            first, second = sorted((instance, other), key=names.index)
            return (f"wpam_mj.muscle instances '{first}' and '{second}' both pull tendon "
                    f"'{tendon}'; one muscle per tendon")
    return None


def python_model(spec: mujoco.MjSpec) -> tuple[mujoco.MjModel, list[PythonMuscle]]:
    """Compile `spec` with its wpam_mj.muscle actuators replaced for the Python engine.

    Each plugin actuator becomes a motor of gear 0 in place (same name, index, ctrl and
    ctrlrange: an input channel), and each instance gets a force motor, named
    "<instance>_force", on its first actuator's tendon, appended after the model's
    actuators. Returns the model and the muscles, one per instance. Raises ParameterError
    with the compiled plugin's line for a configuration it refuses.
    """
    configs = instance_configs(spec)
    acts: dict[str, list] = {name: [] for name in configs}
    for act in spec.actuators:
        if act.plugin.active and act.plugin.name in configs:
            acts[act.plugin.name].append(act)
    first_tendons = {name: (a[0].target if a and a[0].trntype == mujoco.mjtTrn.mjTRN_TENDON
                            else None) for name, a in acts.items()}
    for instance, config in configs.items():
        error = _channel_error(spec, instance, config, acts[instance], first_tendons)
        if error:
            raise ParameterError(error)
    for instance_acts in acts.values():
        for act in instance_acts:
            act.plugin.active = False
            act.plugin.name = ""
            act.plugin.plugin_name = ""
            act.gear[0] = 0.0  # an input channel only
            act.gaintype = mujoco.mjtGain.mjGAIN_FIXED
            act.biastype = mujoco.mjtBias.mjBIAS_NONE
    for p in [p for p in spec.plugins if p.name in configs]:
        spec.delete(p)
    for instance in configs:
        spec.add_actuator(name=f"{instance}_force", target=first_tendons[instance],
                          trntype=mujoco.mjtTrn.mjTRN_TENDON)
    model = spec.compile()
    muscles = []
    for instance, config in configs.items():
        why = no_friction_row(model, instance, model.tendon(first_tendons[instance]).id,
                              after=False)
        if why is not None:
            raise ParameterError(why)
        muscles.append(PythonMuscle(model, config,
                                    [model.actuator(a.name).id for a in acts[instance]],
                                    model.actuator(f"{instance}_force").id))
    return model, muscles


@contextlib.contextmanager
def stepping(model: mujoco.MjModel, muscles: list[PythonMuscle]) -> Iterator[None]:
    """Install the muscles' compute as MuJoCo's control callback for this block only."""
    address = model._address

    def control(m: mujoco.MjModel, d: mujoco.MjData) -> None:
        if m._address == address:  # the callback is global: other models pass through
            for muscle in muscles:
                muscle.compute(m, d)

    previous = mujoco.get_mjcb_control()
    mujoco.set_mjcb_control(control)
    try:
        yield
    finally:
        mujoco.set_mjcb_control(previous)


# ---- a stand-in registration, so that MJCF naming the plugin parses without a compiler ----

def _plugin_struct() -> type[ctypes.Structure]:
    """ctypes' mjpPlugin, field for field as the installed mujoco's mjplugin.h declares
    it (pointers, function pointers and ints; any other field type is refused)."""
    header = (plugin.MUJOCO_DIR / "include" / "mujoco" / "mjplugin.h").read_text()
    found = re.search(r"typedef struct mjpPlugin_ \{(.*?)\} mjpPlugin;", header, re.S)
    if found is None:
        raise RuntimeError("mjplugin.h declares no mjpPlugin")
    fields = []
    for declaration in re.sub(r"//[^\n]*|/\*.*?\*/", "", found.group(1), flags=re.S).split(";"):
        declaration = " ".join(declaration.split())
        callback = re.fullmatch(r"[^(]*\(\s*\*\s*(\w+)\s*\)\s*\(.*\)", declaration)
        field = re.fullmatch(r"(.*?)\s*(\w+)", declaration)
        if callback:
            fields.append((callback.group(1), ctypes.c_void_p))
        elif field and "*" in field.group(1):
            fields.append((field.group(2), ctypes.c_void_p))
        elif field and field.group(1) == "int":
            fields.append((field.group(2), ctypes.c_int))
        elif declaration:
            raise RuntimeError(f"mjplugin.h: mjpPlugin field '{declaration}' is of a type the "
                               "stand-in does not lay out")
    return type("MjpPlugin", (ctypes.Structure,), {"_fields_": fields})


_NSTATE = ctypes.CFUNCTYPE(ctypes.c_int, ctypes.c_void_p, ctypes.c_int)
_INIT = ctypes.CFUNCTYPE(ctypes.c_int, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_int)
_RESET = ctypes.CFUNCTYPE(None, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p,
                          ctypes.c_int)
_COMPUTE = ctypes.CFUNCTYPE(None, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_int,
                            ctypes.c_int)
_keep: list = []  # the registration's C objects live as long as the process
INSTEAD = ("model, muscles = wpam_mj.simulation.engine.python_model(mujoco.MjSpec.from_file("
           "PATH)), stepped inside `with engine.stepping(model, muscles):` (docs/plugin.md)")


def _refuse(model, data, instance) -> int:
    print(f"wpam_mj: this model's muscles need the compiled plugin, unavailable here "
          f"({plugin.unavailable_reason()}); load it on the Python engine instead: {INSTEAD}",
          file=sys.stderr)
    return -1


def register_stand_in() -> None:
    """Register a ``wpam_mj.muscle`` that declares the plugin's attributes and computes
    nothing, so that an MJCF naming the plugin parses where the compiled plugin cannot be
    built; `python_model` then removes it before compiling, and compiling such a model
    directly fails, with one line saying what to call instead. Does nothing when a
    plugin of that name is registered (the compiled one, or the stand-in already)."""
    from wpam_mj.simulation import plugin_build  # noqa: PLC0415 (loaded only here)

    if plugin.available() or plugin_build.registered():
        return
    names = plugin.attribute_names()
    attributes = (ctypes.c_char_p * len(names))(*[n.encode() for n in names])
    name = ctypes.create_string_buffer(plugin.NAME.encode())
    # init fails: a model compiled with the stand-in itself has no muscle and must not run
    callbacks = (_NSTATE(lambda m, i: 0), _INIT(_refuse),
                 _RESET(lambda m, s, p, i: None), _COMPUTE(lambda m, d, i, c: None))
    lib = plugin_build.libmujoco()
    stand_in = _plugin_struct()()
    lib.mjp_defaultPlugin(ctypes.byref(stand_in))
    stand_in.name = ctypes.addressof(name)
    stand_in.nattribute = len(names)
    stand_in.attributes = ctypes.addressof(attributes)
    stand_in.capabilityflags = 1  # mjPLUGIN_ACTUATOR
    for field, callback in zip(("nstate", "init", "reset", "compute"), callbacks):
        setattr(stand_in, field, ctypes.cast(callback, ctypes.c_void_p).value)
    lib.mjp_registerPlugin(ctypes.byref(stand_in))
    _keep.extend([stand_in, name, attributes, callbacks])
