"""Controllers: Pi feedforward from the mechanical equilibrium model; Po from a
`PoController` (open loop, PI, PID; the registry `CONTROLLERS`).

Paper §3-4: Pi is set by the mechanical equilibrium model for the target x_r and load F
(eqs. 5-6), Po by feedback on the position error. The feedforward is the equilibrium
at a nominal Po (`Controller.po_feedforward`) on a branch from the frictionless one (0)
to the contracting one of eq. 5 (1) and a little beyond (`Controller.feedforward_friction`
up to 1.2): beyond the branch the muscle would over-contract (the paper's "excessive
contraction state", §4.1) by a share of the friction band, which grows with the load, so
the Po that holds it back rises with the load (paper Fig. 15). docs/physics.md measures
the readings.

Gain units. The paper gives Kp = 0.1, Ki = 0.008, Kd = 0.004 without units. We keep its
numbers, with the error in mm and time in s, and read the controller's output u in a
unit that `Controller.command_scale` [MPa per u] turns into the Po command:
    e = x - x_r  [mm]   (over-contraction positive: more Po extends the muscle)
    u = Kp e + Ki int(e dt) + Kd de/dt,   Po = command_scale u  [MPa]
command_scale = 1 reads the gains as MPa/mm; 0.1 as volts on the ITV2031's 0-5 V input
(0.5 MPa / 5 V); 0.05 on its 0-10 V input (docs/physics.md compares them). The derivative acts on
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

from typing import ClassVar

import numpy as np

from wpam_mj.physics import kernel, pneumatics
from wpam_mj.physics.kernel_codegen import array_kernel
from wpam_mj.physics.muscle import MuscleModel
from wpam_mj.physics.params import Params
from wpam_mj.errors import ParameterError
from wpam_mj.units import MPA

def pi_feedforward(muscle: MuscleModel, params: Params, x_ref: np.ndarray, load: float,
                   po: float) -> np.ndarray:
    """Pi command [Pa] that holds each x_ref [m] under `load` [N] at Po = `po` [Pa].

    The mechanical equilibrium model (paper eqs. 5-6) on the branch weighted by
    `Controller.feedforward_friction` (0: frictionless; 1: contracting, eq. 5; above 1
    beyond it), clamped to the regulator range.
    """
    pn = params.pneumatics
    pi = muscle.equilibrium_pressure(np.asarray(x_ref, dtype=float), load, po,
                                     params.controller.feedforward_friction)
    return array_kernel().clip(pi, pn.p_min, pn.p_max)


initial_integral = kernel.initial_integral  # (output [Pa], ki, Pa per unit) -> [mm s]


class PoController:
    """The Po command of one run, decided once per physics step.

    Interface: `name` (the registry key), `feedback` (True when the controller needs a
    finite target x_ref at every step; the Pi feedforward then assumes Po =
    po_feedforward, else Po = 0), `for_run(params, dt)` (the controller as `simulate`
    runs it), `reset()` (back to the state at the start of a run) and
    `update(x, x_ref, po_cmd)` -> Po command [Pa]. A new controller is one subclass here
    plus its entry in `CONTROLLERS`; the plugin runs the names of
    `wpam_mj.simulation.plugin.CONTROLS`, any other runs on the Python engine
    (`wpam_mj.simulation.engine`). `needs_target_ahead` says whether it can run where the
    target comes as it goes (`check_live`).
    """

    name: ClassVar[str]
    feedback: ClassVar[bool]
    adds_drive_po: ClassVar[bool] = False  # add the drive's Po command to the feedback's
    # Its feedforward leads the regulators' dead time, so it needs the target ahead of
    # time: users that learn the target only as it comes (the live viewer) cannot run it.
    needs_target_ahead: ClassVar[bool] = False

    @classmethod
    def for_run(cls, params: Params, dt: float) -> "PoController":
        raise NotImplementedError

    @classmethod
    def feedforward(cls, params: Params, load: float, x_ref: np.ndarray,
                    dt: float) -> tuple[np.ndarray, np.ndarray]:
        """(Pi command, drive Po command) [Pa] for the target x_ref [m] sampled every dt
        [s]: the equilibrium-model Pi at the Po this controller assumes (po_feedforward
        under feedback, 0 in open loop) and no Po schedule."""
        po = params.controller.po_feedforward if cls.feedback else 0.0
        pi = pi_feedforward(MuscleModel.from_params(params), params, x_ref, load, po)
        return pi, np.zeros(len(x_ref))

    def reset(self) -> None:
        raise NotImplementedError

    def update(self, x: float, x_ref: float, po_cmd: float = 0.0) -> float:
        """Advance one step at contraction x and target x_ref [m]; po_cmd is the drive's
        open-loop Po command [Pa]. Returns the Po command [Pa]."""
        raise NotImplementedError


class OpenLoop(PoController):
    """Po from the drive's schedule, unchanged (paper Figs. 8-9, 12)."""

    name = "open"
    feedback = False

    @classmethod
    def for_run(cls, params: Params, dt: float) -> "OpenLoop":
        return cls()

    def reset(self) -> None:
        """Nothing to reset: an open loop has no state."""

    def update(self, x: float, x_ref: float, po_cmd: float = 0.0) -> float:
        return po_cmd

    def evaluate(self, x: float, x_ref: float, po_cmd: float = 0.0) -> tuple[float, None]:
        return po_cmd, None

    def commit(self, state: None) -> None:
        """Nothing to keep."""


class PoFeedback(PoController):
    """PI or PID on the contraction error, output Po command [Pa] (see the module doc)."""

    feedback = True
    derivative_term: ClassVar[bool]

    def __init__(self, params: Params, dt: float, *, initial_output: float = 0.0) -> None:
        """initial_output: Po [Pa] at zero error before the first update, held by the
        integral (the loop at rest before the run: bumpless start); 0 without integral."""
        c = params.controller
        self.kp, self.ki = c.kp, c.ki
        self.kd = c.kd if self.derivative_term else 0.0
        self.tf = c.derivative_filter
        self.pa_per_unit = c.command_scale * MPA  # Po command [Pa] per controller unit
        self.dt = dt
        self.lo, self.hi = params.pneumatics.p_min, c.po_cap
        self.initial_output = initial_output
        self.reset()

    @classmethod
    def for_run(cls, params: Params, dt: float) -> "PoFeedback":
        """Started bumpless at Po = po_feedforward, the Po the Pi feedforward assumes."""
        return cls(params, dt, initial_output=params.controller.po_feedforward)

    def reset(self) -> None:
        self.integral = initial_integral(self.initial_output, self.ki, self.pa_per_unit)
        self.derivative = 0.0  # mm/s
        self.e_prev = None

    def update(self, x: float, x_ref: float, po_cmd: float = 0.0) -> float:
        """Advance one step with contraction x and target x_ref [m]; return Po [Pa]."""
        u, state = self.evaluate(x, x_ref, po_cmd)
        self.commit(state)
        return u

    def evaluate(self, x: float, x_ref: float,
                 po_cmd: float = 0.0) -> tuple[float, tuple[float, float, float]]:
        """This step's Po command [Pa] and the state `commit` would keep, without keeping
        it: an engine may evaluate a step more than once (`wpam_mj.simulation.engine`)."""
        u, integral, derivative, e = kernel.po_feedback(
            x, x_ref, po_cmd if self.adds_drive_po else 0.0, self.integral, self.derivative,
            0.0 if self.e_prev is None else self.e_prev, self.e_prev is not None, self.kp,
            self.ki, self.kd, self.tf, self.pa_per_unit, self.lo, self.hi, self.dt)
        return u, (integral, derivative, e)

    def commit(self, state: tuple[float, float, float]) -> None:
        """Keep the (integral, derivative, error) of an `evaluate`."""
        self.integral, self.derivative, self.e_prev = state


class PIControl(PoFeedback):
    """PI on Po (paper §4.1)."""

    name = "pi"
    derivative_term = False


class PIDControl(PoFeedback):
    """PID on Po (paper §4.2), the derivative through the first-order filter."""

    name = "pid"
    derivative_term = True


class PIFlowFeedforward(PIControl):
    """The paper's PI on Po plus a feedforward of the air the target's motion moves.

    Beyond the paper (§4.2 leaves the limit velocity to the regulators and the PI): the
    air that moving the muscle along x_r(t) pushes in and out of each chamber is known in
    advance, d(p V)/dt / (R T_0) with p the feedforward's pressure and V(x_r) the chamber
    volume (`wpam_mj.physics.pneumatics`), so each regulator is commanded the source pressure that
    drives that flow through its line (the restriction's flow law inverted), led by the
    regulator's dead time and its first-order lag inverted (p + tau dp/dt). Pi gets the
    whole command; Po gets the PI law plus the difference from po_feedforward, so at rest
    it is the paper's PI. Designed on the plant model, not tuned per load; both pressures
    stay inside [p_min, po_cap] and [0, p_max].
    """

    name = "pi_ff"
    adds_drive_po = True
    needs_target_ahead = True

    @classmethod
    def feedforward(cls, params: Params, load: float, x_ref: np.ndarray,
                    dt: float) -> tuple[np.ndarray, np.ndarray]:
        pn_, c = params.pneumatics, params.controller
        muscle = MuscleModel.from_params(params)
        x_ref = np.asarray(x_ref, dtype=float)
        pa = pn_.atmosphere
        p_i = pi_feedforward(muscle, params, x_ref, load, c.po_feedforward) + pa  # abs
        p_o = np.full_like(x_ref, c.po_feedforward + pa)
        v_i, v_o = pneumatics.chamber_volumes_of(params, x_ref)
        commands = []
        for p, v, conductance in ((p_i, v_i, pn_.inner_conductance),
                                  (p_o, v_o, pn_.outer_conductance)):
            # R T0 m_dot = V dp/dt / n + p dV/dt = d(pV)/dt - (1 - 1/n) V dp/dt
            m_dot = (np.gradient(p * v, dt) - (1.0 - 1.0 / pn_.polytropic_index) * v
                     * np.gradient(p, dt)) / pneumatics.RT0
            source = pneumatics.source_pressure(m_dot, p, conductance, pn_.critical_ratio,
                                                pa + pn_.p_max) - pa
            commands.append(_regulator_inverse(source, dt, pn_.dead_time, pn_.time_constant))
        pi_cmd, po_cmd = commands
        return (np.clip(pi_cmd, 0.0, pn_.p_max),
                np.clip(po_cmd, pn_.p_min, c.po_cap) - c.po_feedforward)


def _regulator_inverse(set_point: np.ndarray, dt: float, dead_time: float,
                       time_constant: float) -> np.ndarray:
    """Command [Pa] whose regulator output (dead time, first-order lag) is `set_point`:
    the set point `dead_time` ahead (held at the end) plus tau times its slope."""
    lead = round(dead_time / dt)
    ahead = np.concatenate([set_point[lead:], np.full(lead, set_point[-1])])
    return ahead + time_constant * np.gradient(ahead, dt)


# The registry: control mode name -> controller class.
CONTROLLERS: dict[str, type[PoController]] = {
    c.name: c for c in (OpenLoop, PIControl, PIDControl, PIFlowFeedforward)}
CONTROLS = tuple(CONTROLLERS)


def check_control(control: str) -> str:
    """A control mode: one of CONTROLS."""
    if control not in CONTROLLERS:
        raise ParameterError(f"unknown control {control!r}; valid: {', '.join(CONTROLS)}")
    return control


def check_live(control: str) -> str:
    """A control mode for a user that learns the target only as it comes (the live
    viewer): refuses, saying why, a controller that needs the target ahead of time."""
    if CONTROLLERS[check_control(control)].needs_target_ahead:
        raise ParameterError(f"control {control!r} needs the target ahead of time, which "
                             f"the live viewer does not have; valid: {', '.join(LIVE_CONTROLS)}")
    return control


# The controllers that decide from x and x_r as they come.
LIVE_CONTROLS = tuple(name for name, c in CONTROLLERS.items() if not c.needs_target_ahead)


def make_controller(control: str, params: Params, dt: float) -> PoController:
    """The controller `control` for one run of step `dt` [s]."""
    return CONTROLLERS[check_control(control)].for_run(params, dt)
