"""The muscle's physics, written once: pure scalar functions that every engine runs.

The compiled plugin runs them as C that `wpam_mj.physics.kernel_codegen.c_source` writes
from this file's syntax tree into the header it compiles against (so a change here
rebuilds the plugin); the Python engine calls them as they are; array code (feedforward
design, the vector environment's PI) runs `kernel_codegen.array_kernel()`, the same
functions written for numpy arrays. One edit here changes every engine.

So that one text can be all three (and a later `warp.func`), the functions keep to a
small subset of Python, which `kernel_codegen` checks: `def` with every argument and the
return annotated (float, bool, or a tuple of floats), assignments, `if`/`elif`/`else`
whose branches only assign, one `return` at the end, arithmetic, comparisons, `and`,
`or`, `not`, `a if c else b`, `min`/`max` (Python's: the first argument wins ties, NaN
as Python's), `math.sqrt`, `math.cos`, `math.sin`, `math.asin`, `math.expm1`, `**`
(C's pow, as CPython's float power), `math.pi`, `math.inf`, the module's float constants
and calls to the other functions here. Every expression is evaluated in Python's order
in each target (no fused multiply-adds in the C), so the engines agree bit for bit.

Units: SI (m, m^2, m^3, s, Pa, N, kg/s); pressures `*_gauge` or `pi`, `po` above the
atmosphere, `*_abs` or chamber/source pressures absolute. Sources: the braid's geometry
Chou & Hannaford, IEEE Trans. Robot. Autom. 12(1), 1996, eqs. 1-5
(`wpam_mj.physics.geometry`); the force and friction laws and the equilibrium of the
paper's eqs. 1-7 (`wpam_mj.physics.muscle`); the flow law ISO 6358 and the polytropic
chambers (`wpam_mj.physics.pneumatics`); the Po feedback of the paper's §4 with
conditional-integration anti-windup (`wpam_mj.control.controllers`).
"""

from __future__ import annotations

import math

from wpam_mj.units import MM

R_AIR = 287.05  # J/(kg K), specific gas constant of dry air
T_0 = 293.15  # K, ISO 8778 reference (ANR) temperature
RHO_0 = 1.185  # kg/m^3, ISO 8778 reference density (ANR)
R_LAMINAR = 0.99  # pressure ratio above which the flow law is linearised
RT0 = R_AIR * T_0  # J/kg


# ---- the braid (Chou & Hannaford 1996): constants derived once per parameter set ----

def thread_length(natural_length: float, braid_angle: float) -> float:
    """b = L0 / cos(theta0) [m] (eq. 1)."""
    return natural_length / math.cos(braid_angle)


def turns(natural_length: float, braid_angle: float, natural_diameter: float) -> float:
    """n = b sin(theta0) / (pi D0) [1] (eq. 2)."""
    return thread_length(natural_length, braid_angle) * math.sin(braid_angle) \
        / (math.pi * natural_diameter)


def max_contraction(natural_length: float, braid_angle: float, natural_diameter: float,
                    max_diameter: float) -> float:
    """x at D = D_max [m]: b^2 - L^2 = (n pi D_max)^2; the rules guarantee the bag fills
    before the locking angle, so this length is real."""
    b = thread_length(natural_length, braid_angle)
    radial = turns(natural_length, braid_angle, natural_diameter) * math.pi * max_diameter
    return natural_length - math.sqrt(b * b - radial * radial)


def thread_square(natural_length: float, braid_angle: float) -> float:
    """b^2 [m^2]."""
    return thread_length(natural_length, braid_angle) ** 2


def locking_angle(natural_diameter: float, max_diameter: float) -> float:
    """The braid angle [rad] at which the threads lock (54.7 deg) just as the bag fills:
    D = b sin(theta) / (n pi) grows with sin(theta), so the bag reaches max_diameter before
    locking while sin(theta) max_diameter / natural_diameter < sqrt(2/3)."""
    return math.asin(min(1.0, math.sqrt(2.0 / 3.0) * natural_diameter / max_diameter))


def volume_denominator(turns: float) -> float:
    """4 pi n^2 [1], of V and S (eqs. 4-5)."""
    return 4.0 * math.pi * turns ** 2


def diameter_denominator(turns: float) -> float:
    """n pi [1], of D (eq. 2)."""
    return turns * math.pi


# ---- the braid per step: x [m] held to the stroke [0, x_max] (geometry's docstring) ----

def in_stroke(x: float, max_contraction: float) -> float:
    """x [m] held to the stroke [0, max_contraction]."""
    return min(max(x, 0.0), max_contraction)


def diameter(x: float, natural_length: float, thread_sq: float, diameter_denom: float,
             max_contraction: float) -> float:
    """D(x) = sqrt(b^2 - L^2) / (n pi) [m] (eq. 2), thread_sq = b^2."""
    L = natural_length - in_stroke(x, max_contraction)
    return math.sqrt(thread_sq - L * L) / diameter_denom


def volume(x: float, natural_length: float, thread_sq: float, volume_denom: float,
           max_contraction: float) -> float:
    """Inner-bag volume V(x) = L (b^2 - L^2) / (4 pi n^2) [m^3]."""
    L = natural_length - in_stroke(x, max_contraction)
    return L * (thread_sq - L * L) / volume_denom


def area(x: float, natural_length: float, thread_sq: float, volume_denom: float,
         max_contraction: float) -> float:
    """Effective area S(x) = dV/dx = (3 L^2 - b^2) / (4 pi n^2) [m^2] (eq. 5)."""
    L = natural_length - in_stroke(x, max_contraction)
    return (3.0 * L * L - thread_sq) / volume_denom


# ---- the muscle (paper eqs. 1-7); pi, po gauge [Pa], area S [m^2], rubber Fco [N] ----

def rubber_force(diameter: float, rubber_stiffness: float, natural_diameter: float) -> float:
    """Fco = pi K_R (D - D0) [N] (eq. 7 with r = D/2)."""
    return math.pi * rubber_stiffness * (diameter - natural_diameter)


def pressure_difference(pi: float, po: float) -> float:
    """max(Pi - Po, 0) [Pa]: a bag squeezed flat pulls nothing (eq. 3, Pa -> Po)."""
    return pi - po if pi > po else 0.0


def tension(pi: float, po: float, area: float, rubber: float, output_coeff: float,
            axial_area: float) -> float:
    """T = Kf (dP S - Fco) - A_ax Po [N] on the load, frictionless (eqs. 1-3)."""
    return output_coeff * (pressure_difference(pi, po) * area - rubber) - axial_area * po


def tendon_force(pi: float, po: float, area: float, rubber: float, output_coeff: float,
                 axial_area: float, guided: bool) -> float:
    """The force [N] the muscle pulls its tendon with: max(T, 0) on free end fittings;
    on guided ones the braid's pull less Po's push on them (muscle's docstring)."""
    if guided:
        force = max(output_coeff * (pressure_difference(pi, po) * area - rubber), 0.0) \
            - axial_area * po
    else:
        force = max(tension(pi, po, area, rubber, output_coeff, axial_area), 0.0)
    return force


def friction_level(pi: float, po: float, area: float, friction_coeff: float,
                   friction_const: float) -> float:
    """Dry-friction level Ff = mu dP S + F_f0 [N] (eq. 4 plus a constant part)."""
    return friction_coeff * pressure_difference(pi, po) * area + friction_const


def equilibrium_pressure(po: float, load: float, direction: float, area: float,
                         rubber: float, output_coeff: float, friction_coeff: float,
                         friction_const: float, axial_area: float) -> float:
    """Pi [Pa] that holds the muscle at rest under `load` [N] at Po = `po` on the branch
    `direction` (+1 contracting, eq. 5; -1 extending, eq. 6; 0 frictionless):
    Pi = Po + (F + Kf Fco + A_ax Po + s F_f0) / ((Kf - s mu) S); inf where the braid
    cannot hold it."""
    gain = (output_coeff - direction * friction_coeff) * area
    rhs = max(load + axial_area * po + output_coeff * rubber + direction * friction_const,
              0.0)
    return po + rhs / gain if gain > 0.0 else math.inf


def clip(value: float, lo: float, hi: float) -> float:
    """np.clip's min(max(value, lo), hi)."""
    return min(max(value, lo), hi)


# ---- the pneumatics (ISO 6358 flow, polytropic chambers); absolute pressures ----

def subsonic_psi(r: float, critical_ratio: float) -> float:
    """sqrt(1 - ((r - b) / (1 - b))^2), ISO 6358's subsonic flow function."""
    q = (r - critical_ratio) / (1.0 - critical_ratio)
    return math.sqrt(1.0 - q * q)


def iso6358_psi(r: float, critical_ratio: float) -> float:
    """Flow function psi(r) of ISO 6358 for 0 <= r <= 1: 1 when choked (r <= b),
    subsonic up to R_LAMINAR, linearised to 0 at r = 1 above it."""
    if r <= critical_ratio:
        psi = 1.0
    elif r <= R_LAMINAR:
        psi = subsonic_psi(r, critical_ratio)
    else:
        psi = subsonic_psi(R_LAMINAR, critical_ratio) * (1.0 - r) / (1.0 - R_LAMINAR)
    return psi


def mass_flow(source_abs: float, chamber_abs: float, conductance: float,
              critical_ratio: float) -> float:
    """Mass flow [kg/s] from a source into a chamber through a restriction of sonic
    conductance C [m^3/(s Pa)]: C rho_0 p_up psi(p_down / p_up), negative when the
    chamber vents back."""
    if source_abs >= chamber_abs:
        m = conductance * RHO_0 * source_abs \
            * iso6358_psi(chamber_abs / source_abs, critical_ratio)
    else:
        m = -conductance * RHO_0 * chamber_abs \
            * iso6358_psi(source_abs / chamber_abs, critical_ratio)
    return m


def series_conductance(valve: float, line: float) -> float:
    """Sonic conductance [m^3/(s Pa)] of two restrictions in series, the regulator's valve
    and the line after it: 1/C^2 = 1/C_valve^2 + 1/C_line^2 (ISO 6358-3:2014, components
    in series, for restrictions of similar critical ratio)."""
    return 1.0 / math.sqrt(1.0 / (valve * valve) + 1.0 / (line * line))


def regulator_flow(set_abs: float, chamber_abs: float, supply_abs: float,
                   exhaust_abs: float, line: float, supply_valve: float,
                   exhaust_valve: float, critical_ratio: float) -> float:
    """Mass flow [kg/s] into a chamber from an ITV-class regulator, a device: its internal
    loop throttles a supply valve (from the supply) or an exhaust valve (to the
    atmosphere) to hold its own outlet, where its pressure sensor is, at the set point;
    the line (tube and fittings, conductance `line`) joins that outlet to the chamber.

    Quasi-static in the outlet's small volume: while the valve can hold the outlet at the
    set point, the line's flow from the set point is what flows; once the valve is wide
    open it cannot, and the flow is that of valve and line in series from the supply (or
    to the exhaust). Both flows rise monotonically with the pressure drop, so the flow is
    the smaller in magnitude of the two. With valves far larger than the line this is the
    line's flow from the set point (an ideal source behind the line)."""
    held = mass_flow(set_abs, chamber_abs, line, critical_ratio)
    if set_abs >= chamber_abs:
        m = min(held, mass_flow(supply_abs, chamber_abs,
                                series_conductance(supply_valve, line), critical_ratio))
    else:
        m = max(held, mass_flow(exhaust_abs, chamber_abs,
                                series_conductance(exhaust_valve, line), critical_ratio))
    return m


def chamber_step(chamber_abs: float, mass_flow_in: float, volume: float, dvdx: float,
                 v: float, polytropic: float, dt: float) -> float:
    """One explicit Euler step of dp/dt = n (R T0 m_dot - p dV/dx v) / V: the chamber's
    new pressure [Pa abs] at inflow m_dot [kg/s], volume V [m^3], dV/dx [m^2], velocity
    v [m/s] and polytropic index n [1] (1: isothermal; 1.4: adiabatic, air entering at
    T0): the chamber model of Richer & Hurmuzlu, ASME J. Dyn. Syst. Meas. Control 122(3),
    2000, with one index for charging, venting and the volume's change."""
    return chamber_abs + dt * polytropic * (RT0 * mass_flow_in - chamber_abs * dvdx * v) \
        / volume


def inner_volume(bag_volume_inner: float, tube_volume: float) -> float:
    """V_i = V(x) + V_tube [m^3]; dV_i/dx = S."""
    return bag_volume_inner + tube_volume


def outer_volume(bag_volume_inner: float, x: float, axial_area: float,
                 outer_bag_volume: float, tube_volume: float) -> float:
    """V_o = V_bag + V_tube - V(x) - A_ax x [m^3]; dV_o/dx = -(S + A_ax)."""
    return outer_bag_volume + tube_volume - bag_volume_inner - axial_area * x


def outer_dvdx(area: float, axial_area: float) -> float:
    """dV_o/dx = -(S + A_ax) [m^2]."""
    return -(area + axial_area)


def outer_chamber_step(outer_chamber: bool, chamber_abs: float, mass_flow_in: float,
                       bag_volume_inner: float, x: float, area: float, axial_area: float,
                       outer_bag_volume: float, tube_volume: float, v: float,
                       polytropic: float, dt: float, atmosphere: float) -> float:
    """The outer chamber's new pressure [Pa abs]: `chamber_step` at V_o and dV_o/dx, or,
    for a muscle type without an outer bag (MuscleType.outer_chamber false: rlam,
    mckibben), the atmosphere exactly: the inner bag swells into the open air, so Po is
    0 gauge always and leaves the tension (eqs. 1-3) and the friction level alone."""
    if outer_chamber:
        p = chamber_step(chamber_abs, mass_flow_in,
                         outer_volume(bag_volume_inner, x, axial_area, outer_bag_volume,
                                      tube_volume),
                         outer_dvdx(area, axial_area), v, polytropic, dt)
    else:
        p = atmosphere
    return p


def bag_section(diameter: float) -> float:
    """The outer bag's cross-section pi D_bag^2 / 4 [m^2]: the most area its pressure can
    push the end fittings apart on."""
    return math.pi * (diameter * diameter) / 4.0


def outer_bag_volume(length: float, diameter: float) -> float:
    """Volume enclosed by the outer bag, a cylinder [m^3]."""
    return math.pi * diameter * diameter * length / 4.0


def max_flow_slope(conductance: float, critical_ratio: float) -> float:
    """Largest |d m_dot / d p_chamber| [kg/(s Pa)] of `mass_flow` at a fixed source: the
    slope of its laminar-linearised region."""
    return conductance * RHO_0 * iso6358_psi(R_LAMINAR, critical_ratio) / (1.0 - R_LAMINAR)


def stable_timestep(volume: float, conductance: float, critical_ratio: float,
                    polytropic: float) -> float:
    """The largest step [s] at which `chamber_step` decays without oscillating near
    equilibrium at the chamber's smallest volume [m^3]: V / (n R T0 max_flow_slope)."""
    return volume / (polytropic * RT0 * max_flow_slope(conductance, critical_ratio))


# ---- the regulators (command -> set point, gauge [Pa]); the dead time is a queue ----

def lag_alpha(dt: float, time_constant: float) -> float:
    """1 - exp(-dt / tau): the first-order lag discretised exactly for a held input."""
    return 1.0 if time_constant == 0.0 else -math.expm1(-dt / time_constant)


def regulator_clamp(command: float, p_max: float) -> float:
    """The command [Pa] clamped to the regulator's range [0, p_max]."""
    return min(max(command, 0.0), p_max)


def regulator_set_point(set_point: float, command: float, p_max: float,
                        lag_alpha: float) -> float:
    """The set point after one step of the lag toward the clamped command [Pa]."""
    return set_point + lag_alpha * (regulator_clamp(command, p_max) - set_point)


# ---- the Po feedback: PI or PID on the contraction error [mm] (paper §4) ----

def initial_integral(output: float, ki: float, pa_per_unit: float) -> float:
    """Integral [mm s] whose Ki term alone outputs `output` [Pa]; 0 when ki = 0."""
    return output / pa_per_unit / ki if ki > 0.0 else 0.0


def po_feedback(x: float, x_ref: float, po_ff: float, integral: float, derivative: float,
                e_prev: float, has_prev: bool, kp: float, ki: float, kd: float,
                derivative_filter: float, pa_per_unit: float, lo: float, hi: float,
                dt: float) -> tuple[float, float, float, float]:
    """One step of the Po feedback, evaluated, not kept: (Po command [Pa], the integral,
    the filtered derivative and the error [mm] to keep once the step is taken).

    e = (x - x_ref) / mm; the derivative through s / (T_f s + 1) (backward Euler); the
    integral stops while the output is clamped to [lo, hi] in the direction the error
    pushes it (conditional integration; Astrom & Hagglund 2006, §3.5)."""
    e = (x - x_ref) / MM
    e_before = e_prev if has_prev else e
    derivative_next = (derivative_filter * derivative + (e - e_before)) \
        / (derivative_filter + dt)
    integral_now = integral + e * dt
    u = (kp * e + ki * integral_now + kd * derivative_next) * pa_per_unit + po_ff
    integral_next = integral_now
    if u > hi:
        u = hi
        if not e < 0.0:
            integral_next = integral
    elif u < lo:
        u = lo
        if not e > 0.0:
            integral_next = integral
    return u, integral_next, derivative_next, e
