"""The Python engine: the muscle's physics run from Python on a plain MuJoCo model.

Any model that declares ``wpam_mj.muscle`` actuators (docs/plugin.md) runs either on the
compiled plugin (`wpam_mj.simulation.plugin`, the product) or here, where `python_model` replaces
each instance's actuators by plain motors that carry no force (their ctrl stays the input
channels) plus one force motor on the muscle's tendon, and `PythonMuscle` computes the
muscle from Python with the same physics, `wpam_mj.physics.kernel`, which the plugin runs
as generated C; this module is the glue the plugin's callbacks are in C:

  compute (between ``mj_step1``, which makes the constraint rows, and ``mj_step2``, which
    runs actuation and the solve: where MuJoCo calls a plugin's compute): x, v from the
    tendon; the commands; the Po feedback's output, evaluated but not committed; the
    tendon force from the chamber pressures -> the force motor; the friction level -> this
    simulation's friction row of the tendon (`d.efc_frictionloss`).
  advance (after ``mj_step2``, once per step): the feedback's state committed, the
    regulators and chambers advanced.

`step` is one such step. Each muscle's state lives in the MjData, in ``userdata`` (which
`python_model` sizes), laid out as the plugin's ``plugin_state``: `mj_resetData`, copies,
pickles, several MjData of one model and threads behave as on the plugin, and no MuJoCo
callback is installed, so other models compile meanwhile.

Configurations are checked against the rule table `wpam_mj.physics.rules`, with the same
line as the compiled plugin (`InstanceConfig.from_config`, `python_model`).
tests/test_plugin.py checks that the plugin is bit-identical to this.
"""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass

import mujoco
import numpy as np

from wpam_mj.simulation import plugin
from wpam_mj.control.controllers import CONTROLLERS, make_controller
from wpam_mj.simulation.loop_contract import RunConstants
from wpam_mj.simulation.plugin import FIELD
from wpam_mj.physics import kernel, rules
from wpam_mj.physics.muscle import MuscleModel
from wpam_mj.physics.params import Params, parameter_fields, preset
from wpam_mj.errors import ParameterError

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
    """One muscle instance computed in Python on a model made by `python_model`: what its
    model determines (the plugin's Instance). Its state lives in each MjData's userdata,
    laid out as the plugin's `plugin_state` (`plugin.STATE_FIELDS`, then the two dead-time
    queues) after this engine's own fields (`HEADER`), from `address` on."""

    def __init__(self, model: mujoco.MjModel, config: InstanceConfig, channels: list[int],
                 force_actuator: int, address: int) -> None:
        self.config = config
        self.params = params = config.params
        self.channels = channels
        self.force_actuator = force_actuator
        self.address = address
        self.tendon = int(model.actuator_trnid[force_actuator, 0])
        self.length0 = float(model.tendon_length0[self.tendon])
        self.dt = float(model.opt.timestep)
        self.integrator = int(model.opt.integrator)
        self.feedback = plugin.control_mode(config.control).feedback
        self.outer_chamber = params.outer_chamber  # False: Po stays the atmosphere
        # each channel's ctrlrange where it is limited (read_commands clamps to it)
        self.ctrl_limits = [tuple(map(float, model.actuator_ctrlrange[a]))
                            if model.actuator_ctrllimited[a] else None for a in channels]
        self.geometry = g = MuscleModel.from_params(params).geometry
        # the kernel's braid arguments of V and S, and of D
        self.braid = (params.braid.natural_length, g.thread_sq, g.volume_denom,
                      g.max_contraction)
        self.braid_d = (params.braid.natural_length, g.thread_sq, g.diameter_denom,
                        g.max_contraction)
        self.x_max = g.max_contraction
        # (channel index, actuator, its ctrlrange where it is limited) of each channel
        self.inputs = tuple((i, a, limits)
                            for i, (a, limits) in enumerate(zip(channels, self.ctrl_limits)))
        self.k = RunConstants.make(params, self.dt, self.dt)
        controller = make_controller(config.control, params, self.dt)
        # the Po feedback's constants (PoFeedback's), and its integral at the start
        self.gains = (controller.kp, controller.ki, controller.kd, controller.tf,
                      controller.pa_per_unit, controller.lo, controller.hi) \
            if self.feedback else ()
        self.integral0 = controller.integral if self.feedback else 0.0
        self.size = state_size(config, self.dt)

    def state(self, data: mujoco.MjData) -> np.ndarray:
        """This muscle's state in `data` (a view, laid out as the plugin's plugin_state),
        set to the start first where it is not yet (a new or reset MjData)."""
        block = data.userdata[self.address:self.address + self.size]
        if block[_STARTED] == 0.0:
            block[:] = self._initial()
        return block[_S:]

    def _initial(self) -> list[float]:
        """Vented chambers, empty regulators, controller at its bumpless start (the
        plugin's state_reset), after the header of a started muscle."""
        h = [0.0] * self.size
        h[_STARTED] = 1.0
        h[_X_REF] = math.nan
        h[_P_I] = h[_P_O] = self.k.atmosphere
        h[_INTEGRAL] = self.integral0
        h[_REST_PENDING] = float(self.config.start_at_rest)
        return h

    def status(self, data: mujoco.MjData) -> str:
        """Why the muscle's state in `data` left its range, in one line ("" while it has
        not)."""
        s = self.state(data)
        return plugin.status_message(*(float(s[FIELD[n]]) for n in ("status", "x", "p_i",
                                                                     "p_o")))

    def _options_changed(self, model: mujoco.MjModel, h: list[float]) -> bool:
        """The plugin's refusal of a timestep or integrator changed after compile, or of a
        model left without the muscle's friction row (`no_friction_row`): status, and one
        warning line (once per data until changed back)."""
        opt = model.opt
        if opt.timestep == self.dt and opt.integrator == self.integrator:
            why = no_friction_row(model, self.config.name, self.tendon, after=True)
            if why is None:
                h[_REFUSED] = 0.0
                return False
        else:
            what = "timestep" if model.opt.timestep != self.dt else "integrator"
            why = (f"wpam_mj.muscle instance '{self.config.name}': the {what} changed after "
                   f"the model compiled (timestep {model.opt.timestep:.6g} s, integrator "
                   f"{plugin.INTEGRATORS[int(model.opt.integrator)]}); the muscle stops "
                   "until it is changed back or the model recompiled")
        if not h[_REFUSED]:
            print(f"WARNING: {why}", file=sys.stderr)
        h[_REFUSED] = 1.0
        _set_status(h, plugin.STATUS_MODEL)
        return True

    def _commands(self, ctrl: np.ndarray, h: list[float]) -> list[float]:
        """The commands of this step (the plugin's read_commands): each channel's ctrl
        clamped to its ctrlrange where limited, a non-finite one replaced by the channel's
        last finite value (0 at the start), x_ref held to the stroke under feedback."""
        command = [0.0] * plugin.MAX_CHANNELS
        for i, a, limits in self.inputs:
            c = float(ctrl[a])
            if limits is not None:
                c = min(max(c, limits[0]), limits[1])
            if math.isfinite(c):
                h[_INPUTS[i]] = c
            command[i] = h[_INPUTS[i]]
        if self.feedback:
            command[0] = kernel.in_stroke(command[0], self.x_max)
        return command

    def compute(self, model: mujoco.MjModel, data: mujoco.MjData) -> None:
        """The step's force and friction level (the plugin's compute): after the constraint
        rows are made, before actuation and the solve; the controller's output is kept
        in the state for `advance` to commit."""
        block = data.userdata[self.address:self.address + self.size]
        h = block.tolist() if block[_STARTED] else self._initial()
        if self._options_changed(model, h) or _stopped(h):
            block[:] = h
            data.ctrl[self.force_actuator] = 0.0
            return
        k, m = self.k, self.params.muscle
        x = self.config.contraction0 + (self.length0 - float(data.ten_length[self.tendon]))
        v = -float(data.ten_velocity[self.tendon])
        command = self._commands(data.ctrl, h)
        nchannel = len(self.channels)
        x_ref = math.nan
        if self.feedback:
            x_ref = command[0]
            pi_cmd = command[1] if nchannel > 1 else self._pi_feedforward(x_ref)
            po_cmd, h[_NEXT_INTEGRAL], h[_NEXT_DERIVATIVE], h[_NEXT_E] = kernel.po_feedback(
                x, x_ref, command[2] if nchannel > 2 else 0.0, h[_INTEGRAL], h[_DERIVATIVE],
                h[_E_PREV], h[_HAS_PREV] != 0.0, *self.gains, self.dt)
        else:
            pi_cmd, po_cmd = command[0], command[1]
        if h[_REST_PENDING] != 0.0:
            self._rest(h, pi_cmd, po_cmd)
        pi = h[_P_I] - k.atmosphere
        po = h[_P_O] - k.atmosphere
        area = kernel.area(x, *self.braid)
        force = kernel.tendon_force(pi, po, area, self._rubber(x), m.output_coeff,
                                    m.axial_area, self.config.guided)
        friction = kernel.friction_level(pi, po, area, m.friction_coeff, m.friction_const)
        tolerance = plugin.STROKE_TOLERANCE
        if not -tolerance <= x <= self.x_max + tolerance:
            self._left_stroke(h, x)
        if not math.isfinite(x):  # MuJoCo's state is already bad: add nothing to it
            force, friction = 0.0, m.friction_const
        h[_X:_FRICTION + 1] = x, v, x_ref, pi, po, pi_cmd, po_cmd, force, friction
        data.ctrl[self.force_actuator] = -force  # along the tendon's length
        h[_FRICTION_ROW] = set_friction_level(data, self.tendon, friction,
                                              int(h[_FRICTION_ROW]))
        block[:] = h

    def _left_stroke(self, h: list[float], x: float) -> None:
        """The plugin's left_stroke: STATUS_STROKE, and the first time since the reset one
        warning line naming the tendon range that holds the muscle in its stroke."""
        if not int(h[_STATUS]) & plugin.STATUS_STROKE:
            x_max = self.x_max
            natural = self.length0 + self.config.contraction0  # the tendon's length at x = 0
            print(f"WARNING: wpam_mj.muscle instance '{self.config.name}': contraction x = "
                  f"{x:.6g} m left the stroke [0, {x_max:.6g}] m by more than "
                  f"{plugin.STROKE_TOLERANCE:.6g} m (status {plugin.STATUS_STROKE}); limit "
                  "its tendon from the full bag to the natural length: "
                  f'range="{natural - x_max:.6g} {natural:.6g}" (plugin.tendon_range)',
                  file=sys.stderr)
        _set_status(h, plugin.STATUS_STROKE)

    def _rubber(self, x: float) -> float:
        return kernel.rubber_force(kernel.diameter(x, *self.braid_d),
                                   self.params.muscle.rubber_stiffness,
                                   self.params.braid.natural_diameter)

    def _pi_feedforward(self, x_ref: float) -> float:
        """The in-plugin Pi feedforward [Pa gauge] (control.pi_feedforward)."""
        p, m = self.params, self.params.muscle
        pi = kernel.equilibrium_pressure(
            p.controller.po_feedforward, self.config.feedforward_load,
            p.controller.feedforward_friction, kernel.area(x_ref, *self.braid),
            self._rubber(x_ref), m.output_coeff, m.friction_coeff, m.friction_const,
            m.axial_area)
        return kernel.clip(pi, p.pneumatics.p_min, p.pneumatics.p_max)

    def _rest(self, h: list[float], pi_cmd: float, po_cmd: float) -> None:
        """The plugin's plant_rest: regulators settled on the commands, chambers at their
        set points."""
        k, n = self.k, self.k.delay_steps
        h[_QUEUES:_QUEUES + n] = [pi_cmd] * n
        h[_QUEUES + n:_QUEUES + 2 * n] = [po_cmd] * n
        h[_PI_REG] = kernel.regulator_clamp(pi_cmd, k.p_max)
        h[_PO_REG] = kernel.regulator_clamp(po_cmd, k.p_max)
        h[_P_I] = h[_PI_REG] + k.atmosphere
        h[_P_O] = h[_PO_REG] + k.atmosphere

    def advance(self, model: mujoco.MjModel, data: mujoco.MjData) -> None:
        """After the step (the plugin's advance): the controller's state committed, the
        regulators and chambers advanced from the values compute used."""
        block = data.userdata[self.address:self.address + self.size]
        h = block.tolist()
        if not h[_STARTED] or h[_REFUSED] or _stopped(h):
            return
        k, axial = self.k, self.params.muscle.axial_area
        if self.feedback:  # PoFeedback's commit
            h[_INTEGRAL], h[_DERIVATIVE], h[_E_PREV] = h[_NEXT_INTEGRAL:_NEXT_E + 1]
            h[_HAS_PREV] = 1.0
        h[_REST_PENDING] = 0.0
        pi_cmd, po_cmd = h[_PI_CMD], h[_PO_CMD]
        n = k.delay_steps
        if n:  # the dead time: this step's commands in, those n steps old out
            head = int(h[_HEAD])
            i, o = _QUEUES + head, _QUEUES + n + head
            pi_cmd, h[i], po_cmd, h[o] = h[i], pi_cmd, h[o], po_cmd
            h[_HEAD] = (head + 1) % n
        set_i = h[_PI_REG] = kernel.regulator_set_point(h[_PI_REG], pi_cmd, k.p_max,
                                                         k.lag_alpha)
        set_o = h[_PO_REG] = kernel.regulator_set_point(h[_PO_REG], po_cmd, k.p_max,
                                                         k.lag_alpha)
        v = h[_VELOCITY]
        x = kernel.in_stroke(h[_X], self.x_max)
        area = kernel.area(x, *self.braid)
        vol = kernel.volume(x, *self.braid)
        m_i = kernel.regulator_flow(set_i + k.atmosphere, h[_P_I], k.supply_abs, k.atmosphere,
                                    k.conductance_i, k.supply_valve, k.exhaust_valve,
                                    k.critical_ratio)
        m_o = kernel.regulator_flow(set_o + k.atmosphere, h[_P_O], k.supply_abs, k.atmosphere,
                                    k.conductance_o, k.supply_valve, k.exhaust_valve,
                                    k.critical_ratio)
        p_i = h[_P_I] = kernel.chamber_step(h[_P_I], m_i,
                                            kernel.inner_volume(vol, k.tube_volume), area, v,
                                            k.polytropic, k.dt)
        p_o = h[_P_O] = kernel.outer_chamber_step(self.outer_chamber, h[_P_O], m_o, vol, x,
                                                  area, axial, k.bag_volume, k.tube_volume, v,
                                                  k.polytropic, k.dt, k.atmosphere)
        if not (p_i > 0.0 and p_o > 0.0 and math.isfinite(p_i) and math.isfinite(p_o)):
            _set_status(h, plugin.STATUS_PRESSURE)
        block[:] = h


# The Python engine's own fields of a muscle's block of userdata, before the plugin's
# state layout: whether the state was set to its start (0 in a new or reset MjData),
# where the tendon's friction row was last step, whether the model's options were refused.
HEADER = ("started", "friction_row", "refused")
_STARTED, _FRICTION_ROW, _REFUSED = range(len(HEADER))
_S = len(HEADER)  # where the plugin's layout starts in a block


def _at(*names: str) -> tuple[int, ...]:
    """Where the plugin's state fields `names` lie in a muscle's block."""
    return tuple(_S + FIELD[name] for name in names)


(_X, _VELOCITY, _X_REF, _PI_CMD, _PO_CMD, _FRICTION, _PI_REG, _PO_REG, _P_I, _P_O, _INTEGRAL,
 _DERIVATIVE, _E_PREV, _HAS_PREV, _NEXT_INTEGRAL, _NEXT_DERIVATIVE, _NEXT_E, _REST_PENDING,
 _STATUS, _HEAD) = _at(
    "x", "velocity", "x_ref", "pi_cmd", "po_cmd", "friction", "pi_reg", "po_reg", "p_i", "p_o",
    "integral", "derivative", "e_prev", "has_prev", "next_integral", "next_derivative",
    "next_e", "rest_pending", "status", "head")
_INPUTS = _at(*(f"input{i}" for i in range(plugin.MAX_CHANNELS)))
_QUEUES = _S + len(plugin.STATE_FIELDS)  # the dead-time queues: Pi's, then Po's
# compute writes x .. friction in one slice, advance reads the next_* in one: in this order
assert _at("x", "velocity", "x_ref", "pi", "po", "pi_cmd", "po_cmd", "tension", "friction") \
    == tuple(range(_X, _FRICTION + 1))
assert _at("next_integral", "next_derivative", "next_e") == tuple(range(_NEXT_INTEGRAL,
                                                                        _NEXT_E + 1))


def _stopped(h: list[float]) -> bool:
    """A muscle whose state left its range, or whose model changed, steps no more."""
    return bool(int(h[_STATUS]) & (plugin.STATUS_PRESSURE | plugin.STATUS_MODEL))


def _set_status(h: list[float], bit: int) -> None:
    h[_STATUS] = float(int(h[_STATUS]) | bit)


def step(model: mujoco.MjModel, data: mujoco.MjData, muscles: list[PythonMuscle],
         nstep: int = 1) -> None:
    """`nstep` physics steps of a model made by `python_model`, as ``mj_step`` steps the
    plugin's: ``mj_step1`` (positions, velocities, constraint rows), the muscles' compute,
    ``mj_step2`` (actuation, the solve, integration), their advance. No MuJoCo callback
    is installed, so other models compile and other threads step meanwhile."""
    for _ in range(nstep):
        mujoco.mj_step1(model, data)
        for muscle in muscles:
            muscle.compute(model, data)
        mujoco.mj_step2(model, data)
        for muscle in muscles:
            muscle.advance(model, data)


_FRICTION_TENDON = int(mujoco.mjtConstraint.mjCNSTR_FRICTION_TENDON)
_NO_FRICTION_ROW = {"constraint": int(mujoco.mjtDisableBit.mjDSBL_CONSTRAINT),
                    "frictionloss": int(mujoco.mjtDisableBit.mjDSBL_FRICTIONLOSS)}
_NO_ROW_FLAGS = _NO_FRICTION_ROW["constraint"] | _NO_FRICTION_ROW["frictionloss"]


def no_friction_row(model: mujoco.MjModel, instance: str, tendon: int, *,
                    after: bool) -> str | None:
    """The plugin's no_friction_row: the line saying why MuJoCo makes no friction row for
    the muscle's tendon (its frictionloss not positive, or MuJoCo's constraint or
    frictionloss flag disabled), at compile or `after` it; None while it makes one."""
    loss = float(model.tendon_frictionloss[tendon])
    if loss > 0.0 and not model.opt.disableflags & _NO_ROW_FLAGS:
        return None  # the usual case, every step: nothing to say
    prefix = f"wpam_mj.muscle instance '{instance}': "
    stop = "; the muscle stops until it is changed back and the data reset"
    name = model.tendon(tendon).name
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
    actuators; each muscle's state gets a block of ``userdata`` after the spec's own.
    Returns the model and the muscles, one per instance. Raises ParameterError with the
    compiled plugin's line for a configuration it refuses.
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
    addresses, size = {}, spec.nuserdata
    for instance, config in configs.items():
        addresses[instance] = size
        size += state_size(config, spec.option.timestep)
    spec.nuserdata = size
    model = spec.compile()
    muscles = []
    for instance, config in configs.items():
        why = no_friction_row(model, instance, model.tendon(first_tendons[instance]).id,
                              after=False)
        if why is not None:
            raise ParameterError(why)
        muscles.append(PythonMuscle(model, config,
                                    [model.actuator(a.name).id for a in acts[instance]],
                                    model.actuator(f"{instance}_force").id,
                                    addresses[instance]))
    return model, muscles


def state_size(config: InstanceConfig, timestep: float) -> int:
    """The userdata one muscle takes: `HEADER`, the plugin's named fields and its two
    dead-time queues at this time step [s]."""
    delay_steps = RunConstants.make(config.params, timestep, timestep).delay_steps
    return len(HEADER) + len(plugin.STATE_FIELDS) + 2 * delay_steps
