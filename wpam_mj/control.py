"""Controllers: Pi feedforward from the mechanical equilibrium model, PI/PID on Po.

Paper §3-4: Pi is set by the mechanical equilibrium model for the target x_r and load F
(eqs. 5-6 without friction), Po by feedback on the position error. Our feedforward
assumes a mid-range Po (`Controller.po_feedforward`), so with less Po the muscle is
over-contracted (the paper's "excessive contraction state", §4.1) and the feedback has
authority both ways within [p_min, po_cap].

Gain units (the paper does not state them; we read them in the paper's display units):
    e = x - x_r  [mm]   (over-contraction positive: more Po extends the muscle)
    Po = Kp e + Ki int(e dt) + Kd de/dt  [MPa],  t in s
so Kp = 0.1 MPa/mm, Ki = 0.008 MPa/(mm s), Kd = 0.004 MPa s/mm. The derivative acts on
the error through a first-order filter s / (T_f s + 1) (backward Euler), and the integral
stops while the output is saturated in the direction the error pushes it (conditional
integration anti-windup; Astrom & Hagglund, Advanced PID Control, 2006, §3.5).

Feedback runs start bumpless: the integral is preloaded so that Po = po_feedforward at
zero error, the rest state the Pi feedforward assumes, as if the loop had been holding
the first target before the record starts (an experiment starts with its controller
already running). Starting from an empty integral instead, Po would need ~5 mm s of
integrated error to reach po_feedforward: the muscle would over-contract and creep back
for tens of seconds, a start-up transient rather than the muscle's hysteresis.
"""

from __future__ import annotations

import numpy as np

from wpam_mj.muscle import MuscleModel
from wpam_mj.params import MM, MPA, Params, ParameterError

CONTROLS = ("open", "pi", "pid")


def check_control(control: str) -> str:
    """A control mode: one of CONTROLS."""
    if control not in CONTROLS:
        raise ParameterError(f"unknown control {control!r}; valid: {', '.join(CONTROLS)}")
    return control


def pi_feedforward(muscle: MuscleModel, params: Params, x_ref: np.ndarray, load: float,
                   po: float) -> np.ndarray:
    """Pi command [Pa] that holds each x_ref [m] under `load` [N] at Po = `po` [Pa].

    Frictionless mechanical equilibrium (paper eqs. 5-6 with mu = 0), clamped to the
    regulator range.
    """
    pn = params.pneumatics
    pi = muscle.equilibrium_pressure(np.asarray(x_ref, dtype=float), load, po)
    return np.clip(pi, pn.p_min, pn.p_max)


def initial_integral(output: float, ki: float) -> float:
    """Integral [mm s] whose Ki term alone outputs `output` [Pa]; 0 when ki = 0."""
    return output / MPA / ki if ki > 0.0 else 0.0


class PoFeedback:
    """PI/PID on the contraction error, output Po command [Pa]; call once per step."""

    def __init__(self, params: Params, dt: float, *, derivative: bool,
                 initial_output: float = 0.0) -> None:
        """initial_output: Po [Pa] at zero error before the first update, held by the
        integral (the loop at rest before the run: bumpless start); 0 without integral."""
        c = params.controller
        self.kp, self.ki = c.kp, c.ki
        self.kd = c.kd if derivative else 0.0
        self.tf = c.derivative_filter
        self.dt = dt
        self.lo, self.hi = params.pneumatics.p_min, c.po_cap
        self.integral = initial_integral(initial_output, self.ki)  # mm s
        self.derivative = 0.0  # mm/s
        self.e_prev = None

    def update(self, x: float, x_ref: float) -> float:
        """Advance one step with contraction x and target x_ref [m]; return Po [Pa]."""
        e = (x - x_ref) / MM
        e_prev = e if self.e_prev is None else self.e_prev
        self.derivative = (self.tf * self.derivative + (e - e_prev)) / (self.tf + self.dt)
        integral = self.integral + e * self.dt
        u = (self.kp * e + self.ki * integral + self.kd * self.derivative) * MPA
        if u > self.hi:
            u = self.hi
            if e < 0.0:
                self.integral = integral
        elif u < self.lo:
            u = self.lo
            if e > 0.0:
                self.integral = integral
        else:
            self.integral = integral
        self.e_prev = e
        return u
