"""Regulators and chambers: ITV2031-like pressure sources behind a flow restriction.

Each regulator (SMC ITV2031: 0.005-0.5 MPa) is modelled as
  1. its command clamped to [0, p_max] (0 = vented; the controllers never command
     below p_min while they drive a chamber),
  2. a dead time and a first-order lag on the command -> the regulator's set pressure p_set,
  3. an ideal pressure source p_set feeding the chamber through the valve + tubing,
     a restriction with ISO 6358 sonic conductance C and critical ratio b:

        m_dot = C rho_0 p_up psi(r),   r = p_down / p_up  (absolute pressures)
        psi = 1                                  for r <= b   (choked)
        psi = sqrt(1 - ((r - b) / (1 - b))^2)   for b < r     (subsonic)

     linearised for r > R_LAMINAR, where the subsonic law has an infinite slope (the
     usual laminar-region treatment, e.g. Beater, Pneumatic Drives, Springer 2007, §5).

The chamber air is isothermal at T_0 (slow, thin-walled bags):
        d(p V)/dt = R T_0 m_dot   =>   dp/dt = (R T_0 m_dot - p dV/dt) / V.
Inner chamber: V_i = V(x) + V_tube, dV_i/dt = S(x) v.
Outer chamber: V_o = V_bag - V(x) - A_ax x + V_tube, dV_o/dt = -(S(x) + A_ax) v.
Moving the muscle moves air, so the restriction limits its velocity: this is the paper's
"limit velocity" (§4.2), which makes the gain fall above about 0.5 Hz.
"""

from __future__ import annotations

import math

R_AIR = 287.05  # J/(kg K), specific gas constant of dry air
T_0 = 293.15  # K, ISO 8778 reference (ANR) temperature
RHO_0 = 1.185  # kg/m^3, ISO 8778 reference density (ANR)
R_LAMINAR = 0.99  # pressure ratio above which the flow law is linearised

RT0 = R_AIR * T_0


def iso6358_psi(r: float, b: float) -> float:
    """Flow function psi(r) of ISO 6358 for 0 <= r <= 1, laminar-linearised near r = 1."""
    if r <= b:
        return 1.0
    if r <= R_LAMINAR:
        q = (r - b) / (1.0 - b)
        return math.sqrt(1.0 - q * q)
    q = (R_LAMINAR - b) / (1.0 - b)
    return math.sqrt(1.0 - q * q) * (1.0 - r) / (1.0 - R_LAMINAR)


def mass_flow(p_source: float, p_chamber: float, conductance: float, b: float) -> float:
    """Mass flow [kg/s] from a source at `p_source` into a chamber at `p_chamber`.

    Absolute pressures [Pa]; negative when the chamber vents back through the valve.
    """
    if p_source >= p_chamber:
        return conductance * RHO_0 * p_source * iso6358_psi(p_chamber / p_source, b)
    return -conductance * RHO_0 * p_chamber * iso6358_psi(p_source / p_chamber, b)


def outer_bag_volume(length: float, diameter: float) -> float:
    """Volume enclosed by the outer bag [m^3] (a cylinder of the paper's §2.3 size)."""
    return math.pi * diameter * diameter * length / 4.0
