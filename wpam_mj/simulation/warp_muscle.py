"""The muscle on MuJoCo Warp: the kernel's functions compiled by NVIDIA Warp, per world.

MuJoCo Warp runs no engine plugins, so the muscle runs as two Warp kernels around its
step, each world's muscle in one thread:
  compute (installed as the model's `control` callback, which MuJoCo Warp calls after the
    constraint rows are made and before actuation and the solve, where MuJoCo calls a
    plugin's compute): x, v from the tendon; the input channels; the Po feedback,
    evaluated but not kept; the tendon force from the chamber pressures into the force
    motor's ctrl (the Python engine's model, `engine.python_model`); the friction level
    into this world's friction row of the tendon (`efc.frictionloss`), which the solver
    and the no-slip solver then hold, stiction included, as on the plugin.
  advance (launched after each `mujoco_warp.step`): the feedback's state kept, the
    regulators and chambers advanced.
The physics is `wpam_mj.physics.kernel`, its functions turned into `warp.func`s as they
are (`kernel_funcs`): no copy. What is here is the plugin's glue (muscle_plugin.c's
wpam_compute and wpam_advance), with the state in the plugin's own layout
(`plugin.STATE_FIELDS`, then the two dead-time queues), one row per world, and every
parameter per world (`WorldParams`), so one batch holds many plants. Warp computes in
float32 (MuJoCo Warp's precision); the plugin in float64: docs/warp.md says how far apart.
"""

import functools
import importlib
import types

import numpy as np

from wpam_mj.physics import kernel as physics_kernel
from wpam_mj.errors import ParameterError
from wpam_mj.simulation import plugin

GPU_EXTRA = "pip install 'wpam-mj[gpu]'"


@functools.cache
def require_warp() -> tuple[types.ModuleType, types.ModuleType]:
    """(warp, mujoco_warp), or one ParameterError line naming the extra that installs them."""
    try:
        wp = importlib.import_module("warp")
        mjw = importlib.import_module("mujoco_warp")
    except ImportError as err:
        raise ParameterError(f"backend = 'warp' needs NVIDIA Warp and MuJoCo Warp, not "
                             f"installed here ({err.name} missing): {GPU_EXTRA}") from None
    wp.config.quiet = True
    return wp, mjw


def warp_available() -> bool:
    """True when Warp and MuJoCo Warp import."""
    try:
        require_warp()
    except ParameterError:
        return False
    return True


@functools.cache
def kernel_funcs() -> types.SimpleNamespace:
    """Every function of `wpam_mj.physics.kernel` as a `warp.func`, compiled from its own
    source: each is rebound to a namespace in which the kernel functions it calls are their
    `warp.func`s, so Warp compiles the one definition (annotated `float` is float32 there;
    `min`/`max`, `math.sqrt` and `a if c else b` are Warp's)."""
    wp, _ = require_warp()
    namespace = dict(vars(physics_kernel))
    out = {}
    for name, f in vars(physics_kernel).items():
        if isinstance(f, types.FunctionType) and f.__module__ == physics_kernel.__name__:
            g = types.FunctionType(f.__code__, namespace, name, f.__defaults__, f.__closure__)
            g.__annotations__, g.__qualname__, g.__doc__ = dict(f.__annotations__), name, f.__doc__
            g.__module__ = f"{__name__}.kernel"  # Warp's module: apart from the kernels here
            out[name] = namespace[name] = wp.func(g)
    return types.SimpleNamespace(**out)


# What each world's muscle reads, derived on the host in float64 from its Params, run and
# model (as muscle_config.c's derive_for_model does), then stored in float32.
WORLD_FIELDS = (
    "natural_length", "thread_sq", "volume_denom", "diameter_denom", "max_contraction",
    "natural_diameter", "rubber_stiffness", "output_coeff", "axial_area", "friction_coeff",
    "friction_const", "guided", "atmosphere", "p_min", "p_max", "lag_alpha",
    "delay_steps", "critical_ratio", "inner_conductance", "outer_conductance",
    "supply_abs", "supply_valve", "exhaust_valve", "tube_volume", "polytropic", "bag_volume",
    "outer_chamber", "kp", "ki", "kd", "derivative_filter",
    "pa_per_unit", "po_cap", "integral0", "feedforward_friction", "po_feedforward",
    "feedforward_load", "contraction0", "length0", "feedback", "nchannel", "start_at_rest",
    "dt", "stroke_tolerance")


def world_values(config, length0: float, dt: float, nchannel: int) -> dict[str, float]:
    """The `WORLD_FIELDS` of one muscle: its `engine.InstanceConfig`, the tendon length at
    which x = contraction0 [m], the time step [s] and its number of input channels."""
    k = physics_kernel
    p = config.params
    br, mu, pn, c = p.braid, p.muscle, p.pneumatics, p.controller
    b = k.thread_length(br.natural_length, br.braid_angle)
    n = k.turns(br.natural_length, br.braid_angle, br.natural_diameter)
    feedback = plugin.control_mode(config.control).feedback
    pa_per_unit = c.command_scale * plugin.MPA
    return {
        "natural_length": br.natural_length, "thread_sq": b ** 2.0,
        "volume_denom": k.volume_denominator(n), "diameter_denom": k.diameter_denominator(n),
        "max_contraction": k.max_contraction(br.natural_length, br.braid_angle,
                                             br.natural_diameter, br.max_diameter),
        "natural_diameter": br.natural_diameter, "rubber_stiffness": mu.rubber_stiffness,
        "output_coeff": mu.output_coeff, "axial_area": mu.axial_area,
        "friction_coeff": mu.friction_coeff, "friction_const": mu.friction_const,
        "guided": float(config.guided), "atmosphere": pn.atmosphere, "p_min": pn.p_min,
        "p_max": pn.p_max, "lag_alpha": k.lag_alpha(dt, pn.time_constant),
        "delay_steps": float(round(pn.dead_time / dt)), "critical_ratio": pn.critical_ratio,
        "inner_conductance": pn.inner_conductance, "outer_conductance": pn.outer_conductance,
        "supply_abs": pn.supply_pressure + pn.atmosphere,
        "supply_valve": pn.supply_valve_conductance,
        "exhaust_valve": pn.exhaust_valve_conductance, "tube_volume": pn.tube_volume,
        "polytropic": pn.polytropic_index,
        "bag_volume": k.outer_bag_volume(br.outer_bag_length, br.outer_bag_diameter),
        "outer_chamber": float(p.outer_chamber),
        "kp": c.kp, "ki": c.ki, "kd": c.kd if config.control == "pid" else 0.0,
        "derivative_filter": c.derivative_filter, "pa_per_unit": pa_per_unit,
        "po_cap": c.po_cap,
        "integral0": k.initial_integral(c.po_feedforward, c.ki, pa_per_unit) if feedback
        else 0.0,
        "feedforward_friction": c.feedforward_friction, "po_feedforward": c.po_feedforward,
        "feedforward_load": config.feedforward_load, "contraction0": config.contraction0,
        "length0": length0, "feedback": float(feedback), "nchannel": float(nchannel),
        "start_at_rest": float(config.start_at_rest), "dt": dt,
        "stroke_tolerance": plugin.STROKE_TOLERANCE}


@functools.cache
def kernels() -> types.SimpleNamespace:
    """The Warp struct and kernels of the muscle (built once, when Warp is first used)."""
    wp, _ = require_warp()
    kf = kernel_funcs()
    F = plugin.FIELD
    S_X, S_VELOCITY, S_X_REF, S_PI, S_PO = (wp.constant(F[n]) for n in
                                           ("x", "velocity", "x_ref", "pi", "po"))
    S_PI_CMD, S_PO_CMD, S_TENSION, S_FRICTION = (wp.constant(F[n]) for n in
                                                 ("pi_cmd", "po_cmd", "tension", "friction"))
    S_PI_REG, S_PO_REG, S_P_I, S_P_O = (wp.constant(F[n]) for n in
                                        ("pi_reg", "po_reg", "p_i", "p_o"))
    S_INTEGRAL, S_DERIVATIVE, S_E_PREV, S_HAS_PREV = (
        wp.constant(F[n]) for n in ("integral", "derivative", "e_prev", "has_prev"))
    S_NEXT_INTEGRAL, S_NEXT_DERIVATIVE, S_NEXT_E = (
        wp.constant(F[n]) for n in ("next_integral", "next_derivative", "next_e"))
    S_REST_PENDING, S_STATUS, S_HEAD, S_INPUT0 = (
        wp.constant(F[n]) for n in ("rest_pending", "status", "head", "input0"))
    S_COUNT = wp.constant(len(plugin.STATE_FIELDS))
    STROKE, PRESSURE, MODEL = (wp.constant(b) for b in (
        plugin.STATUS_STROKE, plugin.STATUS_PRESSURE, plugin.STATUS_MODEL))
    FRICTION_TENDON = wp.constant(2)  # mujoco_warp's ConstraintType.FRICTION_TENDON

    World = wp.struct(type("World", (), {"__annotations__": {
        name: wp.array(dtype=float) for name in WORLD_FIELDS}}))

    @wp.func
    def stopped(status: float) -> bool:
        return (int(status) & (PRESSURE | MODEL)) != 0

    @wp.func
    def set_status(s: wp.array2d(dtype=float), w: int, bit: int):
        s[w, S_STATUS] = float(int(s[w, S_STATUS]) | bit)

    @wp.func
    def area_at(p: World, w: int, x: float) -> float:
        return kf.area(x, p.natural_length[w], p.thread_sq[w], p.volume_denom[w],
                       p.max_contraction[w])

    @wp.func
    def rubber_at(p: World, w: int, x: float) -> float:
        d = kf.diameter(x, p.natural_length[w], p.thread_sq[w], p.diameter_denom[w],
                        p.max_contraction[w])
        return kf.rubber_force(d, p.rubber_stiffness[w], p.natural_diameter[w])

    @wp.func
    def pi_feedforward(p: World, w: int, x_ref: float) -> float:
        """muscle_plugin.c's pi_feedforward: eq. 5 at x_ref, clipped to the regulator."""
        pi = kf.equilibrium_pressure(p.po_feedforward[w], p.feedforward_load[w],
                                     p.feedforward_friction[w], area_at(p, w, x_ref),
                                     rubber_at(p, w, x_ref), p.output_coeff[w],
                                     p.friction_coeff[w], p.friction_const[w],
                                     p.axial_area[w])
        return kf.clip(pi, p.p_min[w], p.p_max[w])

    @wp.func
    def regulator_rest(s: wp.array2d(dtype=float), w: int, reg: int, queue: int,
                       delay: int, command: float, p_max: float):
        for i in range(delay):
            s[w, queue + i] = command
        s[w, reg] = kf.regulator_clamp(command, p_max)

    @wp.func
    def regulator_update(s: wp.array2d(dtype=float), w: int, reg: int, queue: int,
                         delay: int, head: int, command: float, p: World) -> float:
        """Regulator.update: the command through the dead time (a ring at `queue` with a
        shared head), clamped, then the lag."""
        held = command
        if delay > 0:
            held = s[w, queue + head]
            s[w, queue + head] = command
        s[w, reg] = kf.regulator_set_point(s[w, reg], held, p.p_max[w], p.lag_alpha[w])
        return s[w, reg]

    @wp.kernel
    def compute(p: World, s: wp.array2d(dtype=float), ten_length: wp.array2d(dtype=float),
                ten_velocity: wp.array2d(dtype=float), ctrl: wp.array2d(dtype=float),
                nefc: wp.array(dtype=int), efc_type: wp.array2d(dtype=int),
                efc_id: wp.array2d(dtype=int), efc_frictionloss: wp.array2d(dtype=float),
                channels: wp.array(dtype=int), lo: wp.array(dtype=float),
                hi: wp.array(dtype=float), tendon: int, force_actuator: int):
        """wpam_compute of muscle_plugin.c, world w."""
        w = wp.tid()
        if stopped(s[w, S_STATUS]):
            ctrl[w, force_actuator] = 0.0
            return
        atmosphere = p.atmosphere[w]
        x = p.contraction0[w] + (p.length0[w] - ten_length[w, tendon])
        v = -ten_velocity[w, tendon]
        n = int(p.nchannel[w])
        for i in range(n):  # read_commands: clamped where limited, the last finite kept
            c = wp.min(wp.max(ctrl[w, channels[i]], lo[i]), hi[i])
            if wp.isfinite(c):
                s[w, S_INPUT0 + i] = c
        x_ref = wp.nan
        pi_cmd = s[w, S_INPUT0]
        po_cmd = s[w, S_INPUT0 + 1]
        if p.feedback[w] != 0.0:
            x_ref = kf.in_stroke(s[w, S_INPUT0], p.max_contraction[w])
            po_ff = float(0.0)
            if n > 2:
                po_ff = s[w, S_INPUT0 + 2]
            if n > 1:
                pi_cmd = s[w, S_INPUT0 + 1]
            else:
                pi_cmd = pi_feedforward(p, w, x_ref)
            u, integral_next, derivative_next, e = kf.po_feedback(
                x, x_ref, po_ff, s[w, S_INTEGRAL], s[w, S_DERIVATIVE], s[w, S_E_PREV],
                s[w, S_HAS_PREV] != 0.0, p.kp[w], p.ki[w], p.kd[w], p.derivative_filter[w],
                p.pa_per_unit[w], p.p_min[w], p.po_cap[w], p.dt[w])
            po_cmd = u
            s[w, S_NEXT_INTEGRAL] = integral_next
            s[w, S_NEXT_DERIVATIVE] = derivative_next
            s[w, S_NEXT_E] = e
        if s[w, S_REST_PENDING] != 0.0:  # Plant.rest
            delay = int(p.delay_steps[w])
            regulator_rest(s, w, S_PI_REG, S_COUNT, delay, pi_cmd, p.p_max[w])
            regulator_rest(s, w, S_PO_REG, S_COUNT + delay, delay, po_cmd, p.p_max[w])
            s[w, S_P_I] = s[w, S_PI_REG] + atmosphere
            s[w, S_P_O] = s[w, S_PO_REG] + atmosphere
        pi = s[w, S_P_I] - atmosphere
        po = s[w, S_P_O] - atmosphere
        area = area_at(p, w, x)
        force = kf.tendon_force(pi, po, area, rubber_at(p, w, x), p.output_coeff[w],
                                p.axial_area[w], p.guided[w] != 0.0)
        friction = kf.friction_level(pi, po, area, p.friction_coeff[w], p.friction_const[w])
        tolerance = p.stroke_tolerance[w]
        if not (-tolerance <= x and x <= p.max_contraction[w] + tolerance):
            set_status(s, w, STROKE)
        if not wp.isfinite(x):  # MuJoCo's state is already bad: add nothing to it
            force = 0.0
            friction = p.friction_const[w]
        s[w, S_X] = x
        s[w, S_VELOCITY] = v
        s[w, S_X_REF] = x_ref
        s[w, S_PI] = pi
        s[w, S_PO] = po
        s[w, S_PI_CMD] = pi_cmd
        s[w, S_PO_CMD] = po_cmd
        s[w, S_TENSION] = force
        s[w, S_FRICTION] = friction
        ctrl[w, force_actuator] = -force  # along the tendon's length
        for row in range(nefc[w]):  # set_friction_level: this world's friction row
            if efc_type[w, row] == FRICTION_TENDON and efc_id[w, row] == tendon:
                efc_frictionloss[w, row] = friction

    @wp.kernel
    def advance(p: World, s: wp.array2d(dtype=float)):
        """wpam_advance of muscle_plugin.c, world w (after the step)."""
        w = wp.tid()
        if stopped(s[w, S_STATUS]):
            return
        atmosphere = p.atmosphere[w]
        delay = int(p.delay_steps[w])
        head = int(s[w, S_HEAD])
        if p.feedback[w] != 0.0:  # the Po feedback's commit
            s[w, S_INTEGRAL] = s[w, S_NEXT_INTEGRAL]
            s[w, S_DERIVATIVE] = s[w, S_NEXT_DERIVATIVE]
            s[w, S_E_PREV] = s[w, S_NEXT_E]
            s[w, S_HAS_PREV] = 1.0
        s[w, S_REST_PENDING] = 0.0
        set_i = regulator_update(s, w, S_PI_REG, S_COUNT, delay, head, s[w, S_PI_CMD], p)
        set_o = regulator_update(s, w, S_PO_REG, S_COUNT + delay, delay, head,
                                 s[w, S_PO_CMD], p)
        if delay > 0:
            s[w, S_HEAD] = float((head + 1) % delay)
        v = s[w, S_VELOCITY]
        x = kf.in_stroke(s[w, S_X], p.max_contraction[w])
        area = area_at(p, w, x)
        vol = kf.volume(x, p.natural_length[w], p.thread_sq[w], p.volume_denom[w],
                        p.max_contraction[w])
        m_i = kf.regulator_flow(set_i + atmosphere, s[w, S_P_I], p.supply_abs[w], atmosphere,
                                p.inner_conductance[w], p.supply_valve[w], p.exhaust_valve[w],
                                p.critical_ratio[w])
        m_o = kf.regulator_flow(set_o + atmosphere, s[w, S_P_O], p.supply_abs[w], atmosphere,
                                p.outer_conductance[w], p.supply_valve[w], p.exhaust_valve[w],
                                p.critical_ratio[w])
        p_i = kf.chamber_step(s[w, S_P_I], m_i, kf.inner_volume(vol, p.tube_volume[w]), area,
                              v, p.polytropic[w], p.dt[w])
        p_o = kf.outer_chamber_step(p.outer_chamber[w] != 0.0, s[w, S_P_O], m_o, vol, x, area,
                                    p.axial_area[w], p.bag_volume[w], p.tube_volume[w], v,
                                    p.polytropic[w], p.dt[w], atmosphere)
        s[w, S_P_I] = p_i
        s[w, S_P_O] = p_o
        if not (p_i > 0.0 and p_o > 0.0 and wp.isfinite(p_i) and wp.isfinite(p_o)):
            set_status(s, w, PRESSURE)

    return types.SimpleNamespace(World=World, compute=compute, advance=advance)


def world_struct(values: list[dict[str, float]], device):
    """The `World` struct of per-world float32 arrays from each world's `world_values`."""
    wp, _ = require_warp()
    world = kernels().World()
    for name in WORLD_FIELDS:
        column = np.array([v[name] for v in values], dtype=np.float32)
        setattr(world, name, wp.array(column, dtype=float, device=device))
    return world
