"""The Python engine: the muscle's readable definition, run as a MuJoCo control callback.

Any model that declares ``wpam_mj.muscle`` actuators (docs/plugin.md) runs either on the
compiled plugin (`wpam_mj.simulation.plugin`, the product) or here, where `python_model` replaces
each instance's actuators by plain motors that carry no force (their ctrl stays the input
channels) plus one force motor on the muscle's tendon, and `PythonMuscle` computes the
muscle in Python, piece for piece what ``muscle_plugin.c`` does in C:

  compute (installed as ``mjcb_control``, which MuJoCo calls after the constraint rows are
    made and before actuation and the solve, as it calls a plugin's compute): x, v from the
    tendon; the controller's Po output, evaluated but not kept; the tension from the
    chamber pressures -> the force motor; the friction level -> this simulation's friction
    row of the tendon (`d.efc_frictionloss`).
  advance (after mj_step, once per step): the controller's state kept, the regulators and
    chambers advanced (`wpam_mj.simulation.plant.Plant.step`).

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
from wpam_mj.simulation.loop_contract import (REC_FIELDS, RunConstants, SimulationDiverged,
                                   contraction_diverged)
from wpam_mj.physics.muscle import MuscleModel
from wpam_mj.physics.params import ParameterError, Params, check_range, preset
from wpam_mj.simulation.plant import Plant

FEEDFORWARD_LOAD_RANGE_N = (0.0, 1e5)
CONTRACTION0_RANGE_M = (-1.0, 1.0)


@dataclass(frozen=True)
class InstanceConfig:
    """One plugin instance's configuration, read from its MJCF `config` attributes."""

    name: str
    params: Params
    control: str
    start_at_rest: bool
    feedforward_load: float  # [N]
    contraction0: float  # contraction in the model's reference pose [m]

    @classmethod
    def from_config(cls, name: str, config: dict[str, str]) -> "InstanceConfig":
        """Validate the attributes as the plugin does at compile time (same ranges, same
        names), raising ParameterError naming the attribute, value and allowed range."""
        known = set(plugin.INSTANCE_KEYS) | {key for key, _ in plugin.parameter_fields()}
        for key in config:
            if key not in known:
                raise ParameterError(f"wpam_mj.muscle instance '{name}': unknown attribute "
                                     f"{key!r}")
        params = preset(config.get("preset") or "wpam")
        values = {}
        for key, value in config.items():
            if key in plugin.INSTANCE_KEYS or value == "":
                continue
            try:
                values[key] = float(value)
            except ValueError:
                raise ParameterError(f"wpam_mj.muscle instance '{name}': {key} = {value!r} "
                                     "is not a number") from None
        params = params.with_values(values)
        control = config.get("control") or "open"
        if control not in CONTROLLERS:
            raise ParameterError(f"wpam_mj.muscle instance '{name}': control = {control!r} "
                                 f"is not one of: {', '.join(CONTROLLERS)}")
        if CONTROLLERS[control].feedback and not params.outer_chamber:
            raise ParameterError(f"wpam_mj.muscle instance '{name}': preset "
                                 f"'{params.preset}' has no outer chamber for Po feedback "
                                 f"(control = '{control}'); use control = 'open'")
        start = config.get("start") or "vented"
        if start not in ("vented", "rest"):
            raise ParameterError(f"wpam_mj.muscle instance '{name}': start = {start!r} is "
                                 "not one of: vented, rest")
        load = check_range(f"wpam_mj.muscle instance '{name}': feedforward_load",
                           config.get("feedforward_load") or 0.0, *FEEDFORWARD_LOAD_RANGE_N,
                           "N")
        x0 = check_range(f"wpam_mj.muscle instance '{name}': contraction0",
                         config.get("contraction0") or 0.0, *CONTRACTION0_RANGE_M, "m")
        return cls(name, params, control, start == "rest", load, x0)


def instance_configs(spec: mujoco.MjSpec) -> dict[str, InstanceConfig]:
    """Every wpam_mj.muscle instance of `spec`, by name."""
    return {p.name: InstanceConfig.from_config(p.name, dict(p.config))
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
        self.muscle = MuscleModel.from_params(self.params)
        self.feedback = plugin.control_mode(config.control).feedback
        self.friction_row = 0  # where the tendon's friction row was last step
        self.reset()

    def reset(self) -> None:
        """Vented chambers, empty regulators, controller at its start (plugin reset)."""
        self.plant = Plant(self.muscle, RunConstants.make(self.params, self.dt, self.dt))
        self.controller: PoController = make_controller(self.config.control, self.params,
                                                        self.dt)
        self.rest_pending = self.config.start_at_rest
        self.pending: tuple | None = None  # what compute computed and advance keeps
        self.status = ""  # why the state left its range ("" while it has not)
        self.record = dict.fromkeys(REC_FIELDS[1:], 0.0)
        self.record["x_ref"] = math.nan

    def _inputs(self, ctrl: np.ndarray) -> tuple[float, float, float]:
        """(x_ref, Pi command, Po command or feedforward) from the input channels."""
        values = [float(ctrl[i]) for i in self.channels]
        if not self.feedback:
            return math.nan, values[0], values[1]
        x_ref = values[0]
        if len(values) > 1:
            pi_cmd = values[1]
        else:
            pi_cmd = float(pi_feedforward(self.muscle, self.params, x_ref,
                                          self.config.feedforward_load,
                                          self.params.controller.po_feedforward))
        return x_ref, pi_cmd, values[2] if len(values) > 2 else 0.0

    def compute(self, model: mujoco.MjModel, data: mujoco.MjData) -> None:
        """The step's force and friction level; nothing kept but what advance needs."""
        if self.pending is not None and data.time != self.pending[0]:
            self.advance()  # a loop that only calls mj_step: the last step ends here
        x = self.config.contraction0 + (self.length0 - float(data.ten_length[self.tendon]))
        v = -float(data.ten_velocity[self.tendon])
        x_ref, pi_cmd, po_in = self._inputs(data.ctrl)
        po_cmd, ctl_state = self.controller.evaluate(x, x_ref, po_in)
        if self.rest_pending:
            self.plant.rest(pi_cmd, po_cmd)
        tension, friction = self.plant.forces(x)
        if not -1.0 < x < 1.0 and not self.status:
            self.status = contraction_diverged(x)
        pi, po = self.plant.pressures
        self.record.update(x=x, velocity=v, x_ref=x_ref, pi=pi, po=po, pi_cmd=pi_cmd,
                           po_cmd=po_cmd, tension=tension, friction=friction)
        data.ctrl[self.force_actuator] = -tension  # along the tendon's length
        self.friction_row = set_friction_rows(data, self.tendon, friction, self.friction_row)
        self.pending = (float(data.time), x, v, pi_cmd, po_cmd, ctl_state)

    def advance(self) -> None:
        """Keep the controller's state, advance the regulators and chambers."""
        if self.pending is None:
            return
        _, x, v, pi_cmd, po_cmd, ctl_state = self.pending
        self.pending = None
        self.controller.commit(ctl_state)
        self.rest_pending = False
        try:
            self.plant.step(x, v, pi_cmd, po_cmd)
        except SimulationDiverged as err:
            self.status = self.status or str(err)
        self.record["pi_reg"], self.record["po_reg"] = self.plant.set_points


_FRICTION_TENDON = int(mujoco.mjtConstraint.mjCNSTR_FRICTION_TENDON)


def set_friction_rows(data: mujoco.MjData, tendon: int, friction: float,
                      row: int = 0) -> int:
    """Write this step's friction level [N] into the tendon's friction row (made by MuJoCo
    because the model's tendon_frictionloss is positive; the model stays untouched).
    `row`: where to look first (the row keeps its place while the set of equality and
    friction constraints before it does). Returns the row, -1 if there is none."""
    kinds, ids = data.efc_type, data.efc_id
    if not (row < data.nefc and kinds[row] == _FRICTION_TENDON and ids[row] == tendon):
        rows = np.flatnonzero((kinds[:data.nefc] == _FRICTION_TENDON)
                              & (ids[:data.nefc] == tendon))
        if not rows.size:
            return -1
        row = int(rows[0])
    data.efc_frictionloss[row] = friction
    return row


def python_model(spec: mujoco.MjSpec) -> tuple[mujoco.MjModel, list[PythonMuscle]]:
    """Compile `spec` with its wpam_mj.muscle actuators replaced for the Python engine.

    Each plugin actuator becomes a motor of gear 0 in place (same name, index and ctrl:
    an input channel), and each instance gets a force motor, named "<instance>_force", on
    its first actuator's tendon, appended after the model's actuators. Returns the model
    and the muscles, one per instance.
    """
    configs = instance_configs(spec)
    channel_names: dict[str, list[str]] = {name: [] for name in configs}
    tendons: dict[str, str] = {}
    for act in spec.actuators:
        if not act.plugin.active or act.plugin.name not in configs:
            continue
        instance = act.plugin.name
        if not channel_names[instance]:
            if act.trntype != mujoco.mjtTrn.mjTRN_TENDON:
                raise ParameterError(f"wpam_mj.muscle instance '{instance}': its first "
                                     "actuator must act on a tendon (the muscle)")
            tendons[instance] = act.target
        channel_names[instance].append(act.name)
        act.plugin.active = False
        act.plugin.name = ""
        act.plugin.plugin_name = ""
        act.gear[0] = 0.0  # an input channel only
        act.gaintype = mujoco.mjtGain.mjGAIN_FIXED
        act.biastype = mujoco.mjtBias.mjBIAS_NONE
    for p in [p for p in spec.plugins if p.name in configs]:
        spec.delete(p)
    for instance in configs:
        spec.add_actuator(name=f"{instance}_force", target=tendons[instance],
                          trntype=mujoco.mjtTrn.mjTRN_TENDON)
    model = spec.compile()
    muscles = []
    for instance, config in configs.items():
        control = plugin.control_mode(config.control)
        n = len(channel_names[instance])
        if not control.required <= n <= len(control.channels):
            raise ParameterError(f"wpam_mj.muscle instance '{instance}': control = "
                                 f"'{control.name}' takes {control.required} to "
                                 f"{len(control.channels)} actuators (input channels), "
                                 f"{n} name the instance")
        tendon = model.tendon(tendons[instance])
        if model.tendon_frictionloss[tendon.id] <= 0.0:
            raise ParameterError(f"wpam_mj.muscle instance '{instance}': tendon "
                                 f"'{tendon.name}' needs a positive frictionloss (any value;"
                                 " the plugin sets the level every step)")
        muscles.append(PythonMuscle(model, config,
                                    [model.actuator(a).id for a in channel_names[instance]],
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
