"""Linear models of the Po position loop about an operating point (paper §3), with python-control.

Paper §3 (eqs. 8-14) treats the W-PAM as a double-acting cylinder, contraction x positive:

    m x'' = F + F_i - F_o - c x',   F_o = A_o P_o                          (eqs. 8, 12)

with F_A = F + F_i an input disturbance d. Po = C(s) (x - x_r)
(`wpam_mj.control.controllers`) closes the loop through L(s) = A_o C(s) / (m s^2 + c s);
for PI, C = (Kp s + Ki) / s:

    G_yr(s) = A_o (Kp s + Ki) / (m s^3 + c s^2 + A_o Kp s + A_o Ki)       (eq. 13)
    G_yd(s) = s / (m s^3 + c s^2 + A_o Kp s + A_o Ki)                      (eq. 14)

PID adds Kd s to C (the paper's ideal derivative). The operating point comes from the
nonlinear model, never typed in (`operating_point`): m and c from the compiled MuJoCo model,
A_o = -dT/dPo by central difference of `MuscleModel.tension` at the target x, the Pi
feedforward there and the nominal Po.

The extended model (`extended_model`) adds what §3 leaves out, each slope again taken
numerically from the package's own functions: the muscle's stiffness -dT/dx and the Pi
feedforward (Pi follows x_r, so the target also acts through Pi), each regulator's dead time
(Pade approximant) and first-order lag, both polytropic chambers linearised about zero flow
(the slope of `pneumatics.mass_flow`, the chamber volume, and the pneumatic stiffness of its
volume change dV/dx), and the derivative filter of the simulated PID. Dry friction has no
linearisation: on the shipped plant it is what makes the simulation lag the models at every
amplitude and holds the loop the extended model calls unstable; the flow limit of the
restriction adds to it at large amplitude (docs/linear_model.md).

SI throughout: x in m, pressures in Pa (gauge unless stated), gains Kp in Pa/m, Ki in
Pa/(m s), Kd in Pa s/m (the controller's gains per mm times `Controller.command_scale`
[MPa per controller unit], times 1e6 / 1e-3).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import control as ct
import mujoco
import numpy as np

from wpam_mj.physics import pneumatics as pn
from wpam_mj.control.controllers import pi_feedforward
from wpam_mj.physics.geometry import BraidGeometry
from wpam_mj.simulation.context import check_load
from wpam_mj.simulation.model import MuscleIndex, build_model
from wpam_mj.physics.muscle import MuscleModel
from wpam_mj.physics.params import Params
from wpam_mj.errors import ParameterError, check_range
from wpam_mj.units import MM, MPA

CONTROLLERS = ("pi", "pid")
MODELS = ("paper", "extended")
PADE_ORDER = 5  # our choice: phase within 1 deg of e^{-sL} up to wL ~ 6 rad
_REL_STEP = 1e-6  # central-difference step relative to the variable's scale


def check_linear_control(control: str) -> str:
    """A controller the linear models have: one of CONTROLLERS."""
    if control not in CONTROLLERS:
        raise ParameterError(f"unknown controller {control!r} for the linear model; "
                             f"valid: {', '.join(CONTROLLERS)}")
    return control


def _slope(f: Callable[[float], float], at: float, step: float) -> float:
    """Central difference df/dv at v = `at` with half-step `step`."""
    return float(f(at + step) - f(at - step)) / (2.0 * step)


# ------------------------------------------------------------------ operating point


@dataclass(frozen=True)
class Chamber:
    """One chamber linearised about zero flow (polytropic index n,
    `wpam_mj.physics.pneumatics`).

    V dp/dt = n (R T0 m_dot(p_set, p) - p (dV/dx) v)  gives, for small deviations,
    dp/dt = n (R T0 (g_set dp_set - g_p dp) - p0 (dV/dx) v) / V.
    """

    volume: float  # V [m^3]
    volume_slope: float  # dV/dx [m^2]
    pressure: float  # p0, absolute [Pa]
    set_slope: float  # g_set = d m_dot / d p_set [kg/(s Pa)]
    pressure_slope: float  # g_p = -d m_dot / d p [kg/(s Pa)]
    polytropic: float = 1.0  # n [1]

    @property
    def time_constant(self) -> float:
        """V / (n R T0 g_p) [s]: how fast the chamber follows its regulator."""
        return self.volume / (self.polytropic * pn.RT0 * self.pressure_slope)

    def system(self, name: str, set_input: str, output: str) -> ct.StateSpace:
        """State space: inputs (set pressure [Pa], load velocity v [m/s]), output p [Pa]."""
        n = self.polytropic
        a = -n * pn.RT0 * self.pressure_slope / self.volume
        b = [[n * pn.RT0 * self.set_slope / self.volume,
              -n * self.pressure * self.volume_slope / self.volume]]
        return ct.ss([[a]], b, [[1.0]], [[0.0, 0.0]], name=name,
                     inputs=[set_input, "v"], outputs=[output])


def inner_volume(params: Params, x: float) -> float:
    """Inner chamber volume V_i [m^3] at contraction x [m]."""
    return pn.chamber_volumes_of(params, x)[0]


def outer_volume(params: Params, x: float) -> float:
    """Outer chamber volume V_o [m^3] at contraction x [m]."""
    return pn.chamber_volumes_of(params, x)[1]


def _chamber(params: Params, x: float, gauge: float, conductance: float,
             volume: Callable[[Params, float], float]) -> Chamber:
    """Linearise one chamber at contraction x [m] and gauge pressure [Pa] at rest."""
    pnm = params.pneumatics
    p0 = gauge + pnm.atmosphere
    step = _REL_STEP * p0
    geom_scale = BraidGeometry.from_params(params.braid).max_contraction
    return Chamber(
        volume=volume(params, x),
        volume_slope=_slope(lambda xx: volume(params, xx), x, _REL_STEP * geom_scale),
        pressure=p0,
        set_slope=_slope(lambda ps: pn.mass_flow(ps, p0, conductance, pnm.critical_ratio),
                         p0, step),
        pressure_slope=-_slope(lambda p: pn.mass_flow(p0, p, conductance,
                                                      pnm.critical_ratio), p0, step),
        polytropic=pnm.polytropic_index)


@dataclass(frozen=True)
class OperatingPoint:
    """The loop at rest holding target x under a load, and the nonlinear model's slopes
    there (SI). Pi is the feedforward for x (`control.pi_feedforward`), Po the nominal Po
    it assumes (`Controller.po_feedforward`): with no friction the loop rests exactly there.
    """

    load: float  # N
    x: float  # contraction [m]
    pi: float  # gauge [Pa]
    po: float  # gauge [Pa]
    mass: float  # moving mass: MuJoCo inertia of the contraction dof [kg]
    damping: float  # MuJoCo slide damping c [N s/m]
    po_area: float  # A_o = -dT/dPo [m^2] (paper eq. 12)
    pi_area: float  # dT/dPi [m^2]
    stiffness: float  # k = -dT/dx at fixed pressures [N/m]
    pi_ff_slope: float  # dPi_ff/dx_r [Pa/m]
    inner: Chamber
    outer: Chamber

    def as_json(self) -> dict:
        """Display units: mm, MPa; slopes in SI."""
        return {"load_n": self.load, "x_mm": self.x / MM, "pi_mpa": self.pi / MPA,
                "po_mpa": self.po / MPA, "mass_kg": self.mass, "damping_n_s_per_m": self.damping,
                "a_o_m2": self.po_area, "a_i_m2": self.pi_area,
                "stiffness_n_per_m": self.stiffness,
                "pi_ff_slope_mpa_per_mm": self.pi_ff_slope / MPA * MM,
                "inner_time_constant_s": self.inner.time_constant,
                "outer_time_constant_s": self.outer.time_constant}


def moving_mass_and_damping(params: Params, load: float) -> tuple[float, float]:
    """Inertia [kg] and damping [N s/m] of the contraction dof in the compiled model."""
    model = build_model(params, load)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    inertia = np.zeros((model.nv, model.nv))
    mujoco.mj_fullM(model, data, inertia)
    dof = MuscleIndex.of(model).dof
    return float(inertia[dof, dof]), float(model.dof_damping[dof])


def operating_point(params: Params, load: float, x: float) -> OperatingPoint:
    """Linearise the nonlinear model at contraction x [m] under `load` [N]."""
    load = check_load(load)
    muscle = MuscleModel.from_params(params)
    x_max = muscle.geometry.max_contraction
    check_range("contraction", x / MM, 0.0, x_max / MM, "mm", lo_open=True)
    po = params.controller.po_feedforward

    def feedforward(xr: float) -> float:
        return float(pi_feedforward(muscle, params, xr, load, po))

    pi = feedforward(x)
    pnm = params.pneumatics
    if not pnm.p_min < pi < pnm.p_max:
        need = muscle.equilibrium_pressure(x, load, po, params.controller.feedforward_friction)
        raise ParameterError(f"contraction = {x / MM:g} mm under {load:g} N needs Pi = "
                             f"{need / MPA:.4g} MPa, outside the regulator's range "
                             f"[{pnm.p_min / MPA:g}, "
                             f"{pnm.p_max / MPA:g}] MPa: no linear operating point")
    mass, damping = moving_mass_and_damping(params, load)
    dp = _REL_STEP * (pi + pnm.atmosphere)
    dx = _REL_STEP * x_max
    return OperatingPoint(
        load=load, x=x, pi=pi, po=po, mass=mass, damping=damping,
        po_area=-_slope(lambda p: muscle.tension(x, pi, p), po, dp),
        pi_area=_slope(lambda p: muscle.tension(x, p, po), pi, dp),
        stiffness=-_slope(lambda xx: muscle.tension(xx, pi, po), x, dx),
        pi_ff_slope=_slope(feedforward, x, dx),
        inner=_chamber(params, x, pi, pnm.inner_conductance, inner_volume),
        outer=_chamber(params, x, po, pnm.outer_conductance, outer_volume))


# ------------------------------------------------------------------ controllers


def controller_gains(params: Params) -> tuple[float, float, float]:
    """(Kp [Pa/m], Ki [Pa/(m s)], Kd [Pa s/m]) from the gains of `Controller` (controller
    units per mm, turned into MPa by `Controller.command_scale`, as `control.PoFeedback`
    reads them)."""
    c = params.controller
    si = c.command_scale * MPA / MM
    return c.kp * si, c.ki * si, c.kd * si


def controller_tf(params: Params, control: str, *, derivative_filter: bool = False
                  ) -> ct.TransferFunction:
    """C(s) from the error x - x_r [m] to Po [Pa]: PI (Kp s + Ki) / s; PID adds Kd s,
    or Kd s / (T_f s + 1) with `derivative_filter` (as `control.PoFeedback` runs it)."""
    kp, ki, kd = controller_gains(params)
    c = ct.tf([kp, ki], [1.0, 0.0])
    if check_linear_control(control) == "pid":
        tf_ = params.controller.derivative_filter if derivative_filter else 0.0
        c = c + ct.tf([kd, 0.0], [tf_, 1.0])
    return ct.tf(c, name="C", inputs="e", outputs="po_cmd")


# ------------------------------------------------------------------ closed loops


@dataclass(frozen=True)
class LinearLoop:
    """One linear model of the closed loop, every system with named signals (SI):

    plant: P(s), Po command "po_cmd" [Pa] -> "x" [m] (negative: more Po extends);
    controller: C(s), "e" = x - x_r [m] -> "po_cmd" [Pa] (the paper's sign: Po = C e);
    loop: L(s) = -C(s) P(s), "e" -> "x", for unity negative feedback: `control.margin(loop)`
      gives the margins, and `control.feedback(loop)` is g_yr of the paper model (the
      extended g_yr adds x_r's path through the Pi feedforward, P_pi k / (1 + L));
    g_yr: target "x_r" [m] -> "x" [m]; g_yd: disturbance force "d" [N] -> "x" [m].
    """

    model: str
    control: str
    op: OperatingPoint
    plant: ct.LTI
    controller: ct.LTI
    loop: ct.LTI
    g_yr: ct.LTI
    g_yd: ct.LTI

    def poles(self) -> np.ndarray:
        """Closed-loop poles [rad/s], by increasing real part then imaginary part."""
        return np.sort_complex(np.asarray(self.g_yr.poles()))

    @property
    def stable(self) -> bool:
        return bool(np.all(self.poles().real < 0.0))

    def margins(self) -> dict[str, float]:
        """Gain margin [1], phase margin [deg] and their crossover frequencies [Hz] of L;
        inf where L never crosses (`control.stability_margins`)."""
        # the polynomial method evaluates the stability-margin polynomial far beyond the
        # Pade poles, where it overflows; gain and phase margins are not affected
        with np.errstate(over="ignore", invalid="ignore"):
            gm, pm, _, w_pc, w_gc, _ = ct.stability_margins(self.loop)
        return {"gain_margin": float(gm), "phase_margin_deg": float(pm),
                "phase_crossover_hz": float(w_pc) / (2 * math.pi),
                "gain_crossover_hz": float(w_gc) / (2 * math.pi)}

    def dc_gains(self) -> tuple[float, float]:
        """(G_yr(0) [1], G_yd(0) [m/N])."""
        return float(np.real(self.g_yr.dcgain())), float(np.real(self.g_yd.dcgain()))

    def frequency_response(self, freqs_hz) -> tuple[np.ndarray, np.ndarray]:
        """Gain [1] and phase lag [deg, positive = lag] of G_yr at `freqs_hz` [Hz]."""
        omega = 2 * math.pi * np.atleast_1d(np.asarray(freqs_hz, dtype=float))
        resp = ct.frequency_response(self.g_yr, omega)
        lag = -np.degrees(np.unwrap(np.atleast_1d(resp.phase.squeeze())))
        return np.atleast_1d(resp.magnitude.squeeze()), lag

    def step_info(self) -> dict[str, float]:
        """Rise time [s], settling time [s] and overshoot [%] of a step in x_r
        (`control.step_info`, which runs `control.step_response`)."""
        info = ct.step_info(self.g_yr)
        return {"rise_time_s": float(info["RiseTime"]),
                "settling_time_s": float(info["SettlingTime"]),
                "overshoot_pct": float(info["Overshoot"])}

    def as_json(self) -> dict:
        """Plain JSON types; inf margins become None."""
        g_yr0, g_yd0 = self.dc_gains()

        def num(v: float) -> float | None:
            return v if math.isfinite(v) else None
        return {"model": self.model, "controller": self.control, "stable": self.stable,
                "poles": [[float(p.real), float(p.imag)] for p in self.poles()],
                **{k: num(v) for k, v in self.margins().items()},
                "g_yr_dc": g_yr0, "g_yd_dc_m_per_n": g_yd0,
                **({k: num(v) for k, v in self.step_info().items()} if self.stable else {})}


def named(system: ct.LTI, name: str, inputs: str, outputs: str) -> ct.LTI:
    """`system` (SISO) with its name and signal names, of the same kind (tf or ss)."""
    kind = ct.tf if isinstance(system, ct.TransferFunction) else ct.ss
    return kind(system, name=name, inputs=inputs, outputs=outputs)


def _closed_loops(model: str, control: str, op: OperatingPoint, plant: ct.LTI,
                  controller: ct.LTI, g_yr: ct.LTI, g_yd: ct.LTI) -> LinearLoop:
    """A `LinearLoop` with every system named (`LinearLoop`'s docstring)."""
    return LinearLoop(model, control, op, plant, controller,
                      named(-controller * plant, "L", "e", "x"),
                      named(g_yr, "G_yr", "x_r", "x"), named(g_yd, "G_yd", "d", "x"))


def paper_plant(op: OperatingPoint) -> ct.TransferFunction:
    """§3's P(s) = -A_o / (m s^2 + c s): Po command [Pa] -> x [m] (eq. 12, Po = its command)."""
    return ct.tf([-op.po_area], [op.mass, op.damping, 0.0], name="P", inputs="po_cmd",
                 outputs="x")


def paper_model(params: Params, op: OperatingPoint, control: str) -> LinearLoop:
    """The paper's §3 loop (eqs. 12-14) at `op` with PI or PID (ideal derivative)."""
    force_to_x = ct.tf([1.0], [op.mass, op.damping, 0.0])  # 1 / (m s^2 + c s), eq. 12
    c = controller_tf(params, control)
    loop = c * op.po_area * force_to_x  # Po -> F_o = A_o Po
    return _closed_loops("paper", control, op, paper_plant(op), c, ct.feedback(loop, 1),
                         ct.feedback(force_to_x, c * op.po_area))


def _regulator(params: Params, name: str, cmd: str, out: str) -> ct.TransferFunction:
    """Dead time (Pade, order PADE_ORDER) and first-order lag of one regulator."""
    pnm = params.pneumatics
    reg = ct.tf([1.0], [pnm.time_constant, 1.0])
    if pnm.dead_time > 0.0:
        reg = reg * ct.tf(*ct.pade(pnm.dead_time, PADE_ORDER))
    return ct.tf(reg, name=name, inputs=cmd, outputs=out)


def extended_plant(params: Params, op: OperatingPoint) -> ct.StateSpace:
    """Pressure commands ("pi_cmd", "po_cmd" [Pa]) and a force "d" [N] -> "x" [m]: the
    load, both chambers and both regulators linearised at `op`. P(s) is its
    `plant[0, 1]` ("po_cmd" -> "x"), as `LinearLoop.plant` holds it."""
    m, c, k = op.mass, op.damping, op.stiffness
    mech = ct.ss([[0.0, 1.0], [-k / m, -c / m]],
                 [[0.0, 0.0, 0.0], [op.pi_area / m, -op.po_area / m, 1.0 / m]],
                 np.eye(2), np.zeros((2, 3)), name="load",
                 inputs=["pi", "po", "d"], outputs=["x", "v"])
    return ct.interconnect(
        [mech, op.inner.system("inner", "pi_set", "pi"),
         op.outer.system("outer", "po_set", "po"),
         _regulator(params, "reg_i", "pi_cmd", "pi_set"),
         _regulator(params, "reg_o", "po_cmd", "po_set")],
        inputs=["pi_cmd", "po_cmd", "d"], outputs=["x"], name="plant")


def extended_model(params: Params, op: OperatingPoint, control: str) -> LinearLoop:
    """§3 plus stiffness, Pi feedforward, regulators, chamber dynamics and the D filter."""
    plant = extended_plant(params, op)
    c = controller_tf(params, control, derivative_filter=True)
    feedforward = ct.tf([op.pi_ff_slope], [1.0], name="ff", inputs="x_r", outputs="pi_cmd")
    error = ct.summing_junction(inputs=["x", "-x_r"], output="e", name="error")
    closed = ct.interconnect([plant, c, feedforward, error], inputs=["x_r", "d"],
                             outputs=["x"], name="closed")
    p = named(plant[0, 1], "P", "po_cmd", "x")  # Po = C (x - x_r); more Po extends
    return _closed_loops("extended", control, op, p, c, closed[0, 0], closed[0, 1])


def linear_loop(params: Params, load: float, x: float, control: str,
                model: str = "paper") -> LinearLoop:
    """`paper_model` or `extended_model` at the operating point (load [N], x [m]).

        lp = linear_loop(wpam_mj.preset(), 100.0, 25e-3, "pi", "extended")
        control.margin(lp.loop); control.bode_plot(lp.plant)
        control.feedback(-lp.controller * lp.plant)   # x_r -> x without the Pi feedforward
    """
    if model not in MODELS:
        raise ParameterError(f"unknown linear model {model!r}; valid: {', '.join(MODELS)}")
    op = operating_point(params, load, x)
    build = paper_model if model == "paper" else extended_model
    return build(params, op, check_linear_control(control))
