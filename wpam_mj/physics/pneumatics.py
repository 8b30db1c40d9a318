"""Regulators and chambers: ITV2031-like regulators feeding the chambers through their lines.

Per physics step the muscle advances each regulator (command -> set pressure,
`Regulator` here) and each chamber (the regulator's flow -> chamber pressure). Their
equations are `wpam_mj.physics.kernel`'s, which every engine runs (the compiled plugin as
generated C); this module binds them for the analysis code.

Each regulator (SMC ITV2031: 0.005-0.5 MPa) is modelled as
  1. its command clamped to [0, p_max] (0 = vented; the controllers never command
     below p_min while they drive a chamber),
  2. a dead time and a first-order lag on the command -> the regulator's set pressure p_set,
  3. a device that holds its own outlet, where its pressure sensor is, at p_set by
     throttling a supply valve (from the supply, `supply_pressure`) or an exhaust valve (to
     the atmosphere); the line (tube, fittings) joins the outlet to the chamber. Each
     restriction follows ISO 6358 with sonic conductance C and critical ratio b:

        m_dot = C rho_0 p_up psi(r),   r = p_down / p_up  (absolute pressures)
        psi = 1                                  for r <= b   (choked)
        psi = sqrt(1 - ((r - b) / (1 - b))^2)   for b < r     (subsonic)

     linearised for r > R_LAMINAR, where the subsonic law has an infinite slope (the
     usual laminar-region treatment, e.g. Beater, Pneumatic Drives, Springer 2007, §5).
     While the valve can hold the outlet at p_set the chamber fills through the line from
     p_set; wide open, through valve and line in series (1/C^2 = 1/C_valve^2 +
     1/C_line^2, ISO 6358-3) from the supply or to the atmosphere: the flow is the
     smaller of the two (`kernel.regulator_flow`). The ITV2031's valve (1500 L/min) is
     several times the lines', so on the paper's rig the lines set the flow.

The chamber air is polytropic with index n, isothermal at T_0 by default (n = 1: slow,
thin-walled bags); n = 1.4 is adiabatic with the air entering at T_0 (Richer & Hurmuzlu,
ASME J. Dyn. Syst. Meas. Control 122(3), 2000):
        dp/dt = n (R T_0 m_dot - p dV/dt) / V   (n = 1: d(p V)/dt = R T_0 m_dot).
with dV/dt = (dV/dx) v:
Inner chamber: V_i = V(x) + V_tube, dV_i/dx = S(x).
Outer chamber: V_o = V_bag - V(x) - A_ax x + V_tube, dV_o/dx = -(S(x) + A_ax).
Outside the stroke 0 <= x <= x_max the geometry is that of its nearest end
(`wpam_mj.physics.geometry`): the volumes are held there and dV/dx = S keeps that end's
value, the same S the tension uses, so the work the air does and the work the force does
still agree (virtual work) for a muscle pushed a little past an end by a soft limit.
Moving the muscle moves air, so the restriction limits its velocity: this is the paper's
"limit velocity" (§4.2), which makes the gain fall above about 0.5 Hz.
"""

from __future__ import annotations

import numpy as np

from wpam_mj.physics import kernel
from wpam_mj.physics.geometry import BraidGeometry
from wpam_mj.physics.kernel_codegen import array_kernel
from wpam_mj.physics.params import Params

R_AIR, T_0, RHO_0, R_LAMINAR, RT0 = (kernel.R_AIR, kernel.T_0, kernel.RHO_0, kernel.R_LAMINAR,
                                     kernel.RT0)
iso6358_psi = kernel.iso6358_psi  # psi(r, b), 0 <= r <= 1
mass_flow = kernel.mass_flow  # (p_source, p_chamber, C, b) -> kg/s, absolute pressures
max_flow_slope = kernel.max_flow_slope  # (C, b) -> the largest |d m_dot / d p| [kg/(s Pa)]
outer_bag_volume = kernel.outer_bag_volume  # (length, diameter) -> m^3


def mass_flow_array(p_source: np.ndarray, p_chamber: np.ndarray, conductance: float,
                    b: float) -> np.ndarray:
    """`mass_flow` elementwise on arrays (for feedforward design, not the step loop)."""
    return array_kernel().mass_flow(p_source, p_chamber, conductance, b)


def source_pressure(m_dot: np.ndarray, p_chamber: np.ndarray, conductance: float,
                    b: float, p_limit: float) -> np.ndarray:
    """Source pressure [Pa abs] that drives `m_dot` [kg/s] into a chamber at `p_chamber`
    [Pa abs] through the restriction: the inverse of `mass_flow`, which is monotone in the
    source pressure; found by bisection on [0, p_limit] (saturating at the ends)."""
    m_dot, p_chamber = np.broadcast_arrays(np.asarray(m_dot, float), np.asarray(p_chamber, float))
    lo, hi = np.zeros_like(m_dot), np.full_like(m_dot, p_limit)
    for _ in range(60):  # 2^-60 of the bracket: below the float spacing of Pa values
        mid = 0.5 * (lo + hi)
        short = mass_flow_array(mid, p_chamber, conductance, b) < m_dot
        lo, hi = np.where(short, mid, lo), np.where(short, hi, mid)
    return 0.5 * (lo + hi)


def chamber_volumes(bag_inner: float, x: float, axial_area: float, bag_volume: float,
                    tube_volume: float) -> tuple[float, float]:
    """(V_i, V_o) [m^3]: the inner bag's volume `bag_inner` plus its tube, and the outer
    bag's enclosed `bag_volume` less the inner bag and A_ax x, plus its tube (module doc).
    Floats or arrays."""
    return (kernel.inner_volume(bag_inner, tube_volume),
            kernel.outer_volume(bag_inner, x, axial_area, bag_volume, tube_volume))


def chamber_volumes_of(params: Params, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """`chamber_volumes` [m^3] of one parameter set at contraction x [m] (float or array)."""
    b = params.braid
    geometry = BraidGeometry.from_params(b)
    x = geometry.in_stroke(x)
    return chamber_volumes(geometry.volume(x), x, params.muscle.axial_area,
                           outer_bag_volume(b.outer_bag_length, b.outer_bag_diameter),
                           params.pneumatics.tube_volume)


def stable_timesteps(geometry: BraidGeometry, axial_area: float, bag_length: float,
                     bag_diameter: float, tube_volume: float, conductance_i: float,
                     conductance_o: float, b: float, polytropic: float
                     ) -> tuple[float, float]:
    """The largest time steps [s] at which `kernel.chamber_step` (explicit Euler) is stable and
    does not oscillate, (inner chamber, outer chamber).

    Near equilibrium dp/dt = n R T_0 m_dot(p) / V is linear with rate
    lambda = n R T_0 max_flow_slope / V; explicit Euler decays monotonically for
    dt lambda <= 1. V is each chamber's smallest volume over the stroke: the inner one at
    x = 0, the outer one at the full contraction. The plugin's rule table
    (`wpam_mj.physics.rules`) bounds the model's time step by both.
    """
    x_max = geometry.max_contraction
    bag = outer_bag_volume(bag_length, bag_diameter)
    v_i, _ = chamber_volumes(geometry.volume(0.0), 0.0, axial_area, bag, tube_volume)
    _, v_o = chamber_volumes(geometry.volume(x_max), x_max, axial_area, bag, tube_volume)
    return (kernel.stable_timestep(v_i, conductance_i, b, polytropic),
            kernel.stable_timestep(v_o, conductance_o, b, polytropic))


def largest_stable_dt(params: Params) -> tuple[float, str]:
    """The largest stable time step [s] of this parameter set (`stable_timesteps`) and the
    conductance that sets it."""
    pn, b = params.pneumatics, params.braid
    limits = stable_timesteps(BraidGeometry.from_params(b), params.muscle.axial_area,
                              b.outer_bag_length, b.outer_bag_diameter, pn.tube_volume,
                              pn.inner_conductance, pn.outer_conductance, pn.critical_ratio,
                              pn.polytropic_index)
    return min(zip(limits, ("pneumatics.inner_conductance", "pneumatics.outer_conductance")))


class Regulator:
    """One ITV2031-like regulator: command [Pa gauge] -> set pressure `set_point` [Pa gauge].

    Per step: the command enters a dead time of `delay_steps` steps (a ring buffer of the
    commands in flight, all 0 at the start), is clamped to [0, p_max], and the set point
    follows it through a first-order lag discretised exactly for a held input,
    p_set += alpha (p_cmd - p_set) with alpha = 1 - exp(-dt / tau) (`lag_alpha`).
    """

    def __init__(self, lag_alpha: float, delay_steps: int, p_max: float) -> None:
        self.lag_alpha, self.p_max = lag_alpha, p_max
        self.set_point = 0.0
        self._queue = [0.0] * delay_steps
        self._head = 0

    def rest(self, command: float) -> None:
        """Settle at a held `command` [Pa]: every command in flight and the set point equal
        to it (the regulator has been holding it since before the run)."""
        self._queue = [command] * len(self._queue)
        self.set_point = kernel.regulator_clamp(command, self.p_max)

    def update(self, command: float) -> float:
        """Take this step's command [Pa]; return the new set point [Pa]."""
        if self._queue:
            h = self._head
            command, self._queue[h] = self._queue[h], command
            self._head = (h + 1) % len(self._queue)
        self.set_point = kernel.regulator_set_point(self.set_point, command, self.p_max,
                                                    self.lag_alpha)
        return self.set_point
