"""The beyond-the-paper controller `pi_ff` (PI plus a feedforward of the air the target's
motion moves): its model inversions are exact, it is the paper's PI at rest, and at the
paper's heavy, fast point it lags far less than the paper's PID inside the same bounds."""

import math

import numpy as np
import pytest

from wpam_mj.physics import pneumatics as pn
from wpam_mj import preset
from wpam_mj.experiments.analysis import frequency_response
from wpam_mj.control.controllers import CONTROLLERS, PIFlowFeedforward, _regulator_inverse
from wpam_mj.experiments.drives import SineSpec, drive_for_targets, sine_run
from wpam_mj.units import MM, MPA

WPAM = preset("wpam")
DT = 1e-3


def test_source_pressure_inverts_the_flow_law():
    """Filling (choked and subsonic) and venting flows are driven exactly."""
    p_chamber = np.array([1.2e5, 1.5e5, 2.0e5, 1.3e5])  # Pa abs
    m_dot = np.array([2e-4, 1e-5, 0.0, -5e-5])  # kg/s
    c, b = WPAM.pneumatics.outer_conductance, WPAM.pneumatics.critical_ratio
    source = pn.source_pressure(m_dot, p_chamber, c, b, 1e6)
    back = pn.mass_flow_array(source, p_chamber, c, b)
    np.testing.assert_allclose(back, m_dot, rtol=1e-9, atol=1e-12)
    assert all(back[i] == pytest.approx(pn.mass_flow(source[i], p_chamber[i], c, b), rel=1e-12)
               for i in range(len(m_dot)))


def test_regulator_inverse_makes_the_regulator_follow_the_set_point():
    """A command from `_regulator_inverse` through the dead time and the first-order lag
    gives back the wanted set point (to the discretisation of its slope)."""
    pnm = WPAM.pneumatics
    t = np.arange(0.0, 4.0, DT)
    wanted = 0.1 * MPA + 0.05 * MPA * np.sin(2 * math.pi * 0.5 * t)
    cmd = _regulator_inverse(wanted, DT, pnm.dead_time, pnm.time_constant)
    reg = pn.Regulator(-math.expm1(-DT / pnm.time_constant), round(pnm.dead_time / DT),
                       pnm.p_max)  # starts vented, with vented commands in flight
    out = np.array([reg.update(u) for u in cmd])
    settled = slice(round(1.0 / DT), len(out) - round(0.2 / DT))  # after the start
    err = np.abs(out - wanted)[settled].max()
    print(f"regulator inverse: worst set-point error {err:.1f} Pa of a 50 kPa swing")
    assert err < 5e-3 * 0.05 * MPA, "set-point error [Pa]"


def test_pi_ff_is_the_papers_pi_at_rest():
    """A constant target moves no air: the feedforward is the paper's Pi and no extra Po."""
    x_ref = np.full(2000, 20 * MM)
    pi_ff, po_ff = PIFlowFeedforward.feedforward(WPAM, 100.0, x_ref, DT)
    pi_pi, po_pi = CONTROLLERS["pi"].feedforward(WPAM, 100.0, x_ref, DT)
    np.testing.assert_allclose(pi_ff, pi_pi, rtol=1e-9)
    np.testing.assert_allclose(po_ff, 0.0, atol=1e-6)
    assert np.all(po_pi == 0.0)


def _response(control: str, load: float, freq: float):
    spec = SineSpec(freq)
    r = sine_run(WPAM, load, control, spec)
    return r, frequency_response(r.time, r.x_ref, r.x, freq, settle_cycles=spec.settle_cycles,
                                 n_cycles=spec.cycles)


def test_pi_ff_beats_the_papers_pid_at_the_heavy_fast_point():
    """The target at 150 N, 0.5 Hz, 25 mm: lag <= 0.7x PID's, gain >= PID's, Po within
    [p_min, po_cap] and Pi within the regulator range."""
    pid = _response("pid", 150.0, 0.5)[1]
    r, ff = _response("pi_ff", 150.0, 0.5)
    print(f"150 N 0.5 Hz: PID gain {pid.gain:.3f} lag {pid.phase_lag_deg:.1f} deg; "
          f"pi_ff gain {ff.gain:.3f} lag {ff.phase_lag_deg:.1f} deg")
    assert ff.phase_lag_deg <= 0.7 * pid.phase_lag_deg
    assert ff.gain >= pid.gain
    c, pnm = WPAM.controller, WPAM.pneumatics
    assert pnm.p_min <= r.po_cmd.min() and r.po_cmd.max() <= c.po_cap
    assert 0.0 <= r.pi_cmd.min() and r.pi_cmd.max() <= pnm.p_max


def test_pi_ff_drive_is_built_by_its_controller():
    x_ref = SineSpec(0.5).target(np.arange(0.0, 2.0, DT))
    drive = drive_for_targets(WPAM, 150.0, x_ref, "pi_ff", DT)
    assert np.any(drive.po_cmd != 0.0)  # the Po feedforward travels in the drive
    assert drive.pi_cmd.max() > CONTROLLERS["pi"].feedforward(WPAM, 150.0, x_ref, DT)[0].max()
