"""Physics tests of the core model: geometry, equilibria, stiction, hysteresis, feedback,
numerical convergence, determinism, input validation and the shipped MJCF.

Every simulated figure is compared with the closed-form model of `wpam_mj.muscle`
(tolerances in mm or relative, stated next to each assertion). Runs use the plain Python
loop (`engine="python"`, the reference), 1 ms steps unless stated; the whole file runs
in well under a minute.
"""

from __future__ import annotations

import io
import math
from functools import cache

import mujoco
import numpy as np
import pytest
from scipy.optimize import brentq

from wpam_mj.experiments.analysis import frequency_response, loop_area
from wpam_mj.control.controllers import (CONTROLS, PIControl, PIDControl, make_controller,
                                         pi_feedforward)
from wpam_mj.experiments.drives import SineSpec, sine_run, static_top_pressure
from wpam_mj.simulation.context import RunContext, check_dt, check_load
from wpam_mj.simulation.model import build_model
from wpam_mj.physics.muscle import MuscleModel
from wpam_mj.physics.params import Controller, Params, preset
from wpam_mj.errors import ParameterError, check_range
from wpam_mj.units import MM, MPA
from wpam_mj.paths import MODEL_XML, SCENE_XML
from wpam_mj.simulation import results
from wpam_mj.simulation.results import SimResult
from wpam_mj.simulation.simulate import Drive, simulate

ENGINE = "python"
DT = 1e-3  # s
LOADS = (50.0, 100.0, 150.0)  # N, paper §2.3

WPAM = preset("wpam")
FRICTIONLESS = WPAM.replace(muscle={"friction_coeff": 0.0, "friction_const": 0.0})


def open_loop(params: Params, load: float, pi_cmd: np.ndarray, *, dt: float = DT,
              record_dt: float = 0.01):
    """Open-loop run with Po vented (po_cmd = 0) and the given Pi command [Pa]."""
    n = len(pi_cmd)
    drive = Drive(pi_cmd, np.zeros(n), np.full(n, np.nan))
    return simulate(params, load, drive, dt=dt, record_dt=record_dt, engine=ENGINE)


def hold(value: float, duration: float, dt: float = DT) -> np.ndarray:
    return np.full(round(duration / dt), float(value))


def ramp_up_down(top: float, ramp_time: float, dt: float = DT) -> np.ndarray:
    """Pi command [Pa]: 0 -> top in ramp_time [s], then back to 0 in ramp_time."""
    up = np.linspace(0.0, top, round(ramp_time / dt) + 1)
    return np.concatenate([up, up[-2::-1]])


# ---------------------------------------------------------------------- geometry

GEOM = MuscleModel.from_params(WPAM).geometry
X_GRID = np.linspace(0.0, GEOM.max_contraction, 9)  # m


def test_effective_area_is_volume_derivative():
    h = 1e-7  # m
    for x in X_GRID[1:-1]:
        dv_dx = (GEOM.volume(x + h) - GEOM.volume(x - h)) / (2 * h)
        assert GEOM.area(x) == pytest.approx(dv_dx, rel=1e-6), f"S(x) at x = {x / MM:.1f} mm"


def test_bag_reaches_its_max_diameter_at_the_stop():
    assert GEOM.diameter(GEOM.max_contraction) == pytest.approx(WPAM.braid.max_diameter,
                                                                rel=1e-12)
    assert GEOM.diameter(0.0) == pytest.approx(WPAM.braid.natural_diameter, rel=1e-12)
    # the stop lies before the 54.7 deg locking angle: S > 0 all the way
    assert min(GEOM.area(x) for x in X_GRID) > 0.0


def test_length_and_diameter_follow_the_braid_angle():
    b, n = GEOM.thread_length, GEOM.turns
    assert math.acos(GEOM.length(0.0) / b) == pytest.approx(WPAM.braid.braid_angle, rel=1e-12)
    for x in X_GRID:
        theta = math.acos(GEOM.length(x) / b)  # L = b cos(theta)
        d = b * math.sin(theta) / (n * math.pi)  # D = b sin(theta) / (n pi)
        assert GEOM.diameter(x) == pytest.approx(d, rel=1e-12)
        assert GEOM.volume(x) == pytest.approx(math.pi * d * d * GEOM.length(x) / 4, rel=1e-12)
    # contraction swells the sleeve
    assert np.all(np.diff([GEOM.diameter(x) for x in X_GRID]) > 0.0)


@pytest.mark.parametrize("name", ["wpam", "mckibben"])
@pytest.mark.parametrize("direction", [-1, 0, 1])
def test_equilibrium_pressure_and_contraction_invert_each_other(name, direction):
    muscle = MuscleModel.from_params(preset(name))
    for load in LOADS:
        for po in (0.0, 0.04 * MPA):
            for x in (5 * MM, 20 * MM, 40 * MM, 60 * MM):
                pi = muscle.equilibrium_pressure(x, load, po, direction)
                back = muscle.equilibrium_contraction(pi, po, load, direction)
                assert back == pytest.approx(x, abs=1e-9), (
                    f"{name} load {load} N Po {po / MPA} MPa x {x / MM} mm dir {direction}")
                s = direction
                net = muscle.tension(x, pi, po) - s * muscle.friction(x, pi, po) - load
                assert net == pytest.approx(0.0, abs=1e-9 * load)


def test_equilibrium_contraction_is_clipped_to_the_stops():
    muscle = MuscleModel.from_params(WPAM)
    assert muscle.equilibrium_contraction(0.0, 0.0, 100.0) == 0.0
    assert muscle.equilibrium_contraction(0.5 * MPA, 0.0, 50.0) == GEOM.max_contraction


# ---------------------------------------------------------- static equilibrium

@pytest.mark.parametrize("load", LOADS)
@pytest.mark.parametrize("x_target_mm", [10.0, 25.0, 40.0])
def test_frictionless_rest_matches_the_closed_form_equilibrium(load, x_target_mm):
    muscle = MuscleModel.from_params(FRICTIONLESS)
    pi = muscle.equilibrium_pressure(x_target_mm * MM, load, 0.0)
    res = open_loop(FRICTIONLESS, load, hold(pi, 10.0))
    last = res.time >= 9.0
    assert np.abs(res.velocity[last]).max() < 5e-5, "load still moving [m/s] in the last 1 s"
    expected = muscle.equilibrium_contraction(res.pi[-1], res.po[-1], load)
    err_mm = (res.x[-1] - expected) / MM
    print(f"load {load:.0f} N, x {x_target_mm:.0f} mm: rest error {err_mm:+.2e} mm")
    assert abs(err_mm) < 0.1, "rest contraction minus closed-form equilibrium [mm]"


# ------------------------------------------------------------------- stiction

@cache
def resting_at_25mm(load: float):
    """Contract onto the contracting branch at 25 mm and come to rest (8 s)."""
    muscle = MuscleModel.from_params(WPAM)
    pi1 = muscle.equilibrium_pressure(25 * MM, load, 0.0, direction=+1)
    return pi1, open_loop(WPAM, load, hold(pi1, 8.0))


def pressure_for_net_force(load: float, x: float, po: float, net_over_friction: float):
    """Pi [Pa] such that T(x) - load = net_over_friction * Ff(x) at Po = po."""
    muscle = MuscleModel.from_params(WPAM)

    def residual(pi):
        return (muscle.tension(x, pi, po) - load
                - net_over_friction * muscle.friction(x, pi, po))
    return brentq(residual, po, WPAM.pneumatics.p_max)


@pytest.mark.parametrize("load", LOADS)
@pytest.mark.parametrize("sign", [-1, +1], ids=["extend", "contract"])
def test_stiction_holds_below_the_friction_level_and_slips_above(load, sign):
    pi1, rest = resting_at_25mm(load)
    x0, po0 = rest.x[-1], rest.po[-1]
    assert abs(rest.velocity[-1]) < 1e-4, "load at rest [m/s] before the hold"
    moved = {}
    for ratio in (2 / 3, 4 / 3):
        pi2 = pressure_for_net_force(load, x0, po0, sign * ratio)
        res = open_loop(WPAM, load, np.concatenate([hold(pi1, 8.0), hold(pi2, 10.0)]))
        after = res.time >= 8.0 - 1e-9
        moved[ratio] = np.abs(res.x[after] - x0).max() / MM
    print(f"load {load:.0f} N, {'contract' if sign > 0 else 'extend'}: creep "
          f"{moved[2 / 3]:.2e} mm at 2/3 of Ff, slip {moved[4 / 3]:.2f} mm at 4/3 of Ff")
    assert moved[2 / 3] < 0.01, "creep in 10 s under a net force of 2/3 the friction [mm]"
    assert moved[4 / 3] > 1.0, "slip in 10 s under a net force of 4/3 the friction [mm]"


# ---------------------------------------------------- open-loop Pi-x hysteresis

RAMP_TOP = 0.3 * MPA
RAMP_TIME = 20.0  # s each way
RAMP_VENT = 10.0  # s at 0 after the ramp


@cache
def ramp_run(load: float, top: float | None = None, dt: float = DT):
    """Ramp to `top` [Pa]; None: the Pi whose contracting branch reaches 50 mm."""
    top = static_top_pressure(WPAM, load) if top is None else top
    vent = np.zeros(round(RAMP_VENT / dt))  # the chamber empties through its line
    return open_loop(WPAM, load, np.concatenate([ramp_up_down(top, RAMP_TIME, dt), vent]),
                     dt=dt)


@pytest.mark.parametrize("load, top", [(50.0, RAMP_TOP), (50.0, None), (100.0, None),
                                       (150.0, None)])
def test_open_loop_release_waits_for_friction(load, top):
    """On release x stays put until Pi falls to the extending-branch pressure Pi_E
    (paper eq. 6), well below the frictionless pressure, then extends to x = 0.

    At 50 N and 0.3 MPa the muscle reaches its stop; with the 50 mm ramp top it does
    not, so there only friction holds it."""
    res = ramp_run(load, top)
    muscle = MuscleModel.from_params(WPAM)
    slow = 1e-5  # m/s: "at rest" / "moving" threshold (0.01 mm/s)
    turn = int(np.argmax(res.pi))  # measured Pi starts to fall
    stop = turn + int(np.argmax(res.velocity[turn:] <= slow))  # contraction has ended
    x_hold = res.x[stop]
    release = stop + int(np.argmax(res.velocity[stop:] < -slow))
    assert release > stop, "the load never extends"
    pi_release = res.pi[release]
    pi_e = muscle.equilibrium_pressure(x_hold, load, res.po[release], direction=-1)
    pi_0 = muscle.equilibrium_pressure(x_hold, load, res.po[release], direction=0)
    holding = np.arange(res.time.size) >= stop
    holding &= res.pi > 1.01 * pi_e
    creep_mm = np.abs(res.x[holding] - x_hold).max() / MM
    held_s = res.time[release] - res.time[turn]
    print(f"load {load:.0f} N, top {res.pi_cmd.max() / MPA:.2f} MPa: x {x_hold / MM:.2f} mm held "
          f"{held_s:.2f} s (moved {creep_mm:.3f} mm); release at Pi {pi_release / MPA:.4f} MPa,"
          f" Pi_E {pi_e / MPA:.4f}, frictionless {pi_0 / MPA:.4f} MPa")
    assert res.time[stop] - res.time[turn] < 1.0, "contraction ends soon after the turn [s]"
    assert creep_mm < 0.05, "x moves while Pi > 1.01 Pi_E on the way down [mm]"
    assert held_s > 2.0, "x stays put for a while after the turning point [s]"
    assert pi_release == pytest.approx(pi_e, rel=0.01), "release pressure vs Pi_E"
    assert pi_release < pi_0 - 0.5 * (pi_0 - pi_e), "release is held by friction"
    assert res.x[-1] < 0.1 * MM, "extended back to x = 0 at the end [m]"


def test_open_loop_loop_area_grows_with_load():
    areas = [loop_area(ramp_run(load).pi, ramp_run(load).x) for load in LOADS]
    print("open-loop loop areas [MPa mm] at 50/100/150 N:",
          ", ".join(f"{a / (MPA * MM):.3f}" for a in areas))
    # each ramp tops out where the contracting branch reaches 50 mm, so the loops span
    # the same stroke and are comparable
    for load in LOADS:
        assert ramp_run(load).x.max() == pytest.approx(50 * MM, abs=4 * MM)
    assert 0.0 < areas[0] < areas[1] < areas[2]


# --------------------------------------------------------------- feedback

STEP_LEVELS = np.array([0.0, 10.0, 20.0, 30.0]) * MM
STEP_TIME = 8.0  # s per plateau
SETTLED = 2.0  # s: the last part of each plateau that must hold the target


def step_target(dt: float = DT) -> np.ndarray:
    return np.repeat(STEP_LEVELS, round(STEP_TIME / dt))


@cache
def feedback_run(load: float = 100.0, control: str = "pi", params: Params = WPAM):
    x_ref = step_target()
    muscle = MuscleModel.from_params(params)
    pi_cmd = pi_feedforward(muscle, params, x_ref, load, params.controller.po_feedforward)
    drive = Drive(pi_cmd, np.zeros_like(x_ref), x_ref)
    return simulate(params, load, drive, dt=DT, control=control, engine=ENGINE)


def test_feedback_holds_each_plateau():
    res = feedback_run()
    errors_mm = []
    for i, level in enumerate(STEP_LEVELS):
        t1 = (i + 1) * STEP_TIME
        w = (res.time >= t1 - SETTLED - 1e-9) & (res.time < t1 - 1e-9)
        errors_mm.append(np.abs(res.x[w] - level).max() / MM)
    print("PI at 100 N, max |x - x_r| in the last 2 s of each plateau [mm]:",
          ", ".join(f"{e:.3f}" for e in errors_mm))
    # The paper's plateaus settle within 0.5 mm; the credible plant reaches 0.64 mm here
    # (docs/physics.md: the paper's integral time Kp/Ki = 12.5 s against 8-10 s plateaus,
    # through friction), so this holds the measured level, not the paper's.
    assert max(errors_mm) < 0.8, "plateau error after settling [mm]"


def test_feedback_run_starts_at_rest_at_the_first_target():
    """Bumpless start: the integral holds Po = po_feedforward, the Po the Pi feedforward
    assumes. With a frictionless feedforward the first plateau then shows no start-up
    transient (it showed 0.3 mm with an empty integral); with the shipped share of the
    friction band in the feedforward the muscle starts over-contracted, never under (the
    paper's "excessive contraction state", §4.1)."""
    frictionless = WPAM.replace(controller={"feedforward_friction": 0.0})
    first = step_target() < STEP_LEVELS[1]
    # -0.05 mm: the stop at x = 0 is a stiff constraint, not a rigid one
    for params, lo, hi in ((frictionless, -0.05, 0.05), (WPAM, -0.05, 1.0)):
        res = feedback_run(params=params)
        assert res.po_cmd[0] == pytest.approx(params.controller.po_feedforward, rel=1e-12)
        err = (res.x - res.x_ref)[first[::round(res.time[1] / DT)]] / MM
        print(f"feedforward_friction {params.controller.feedforward_friction:g}: first "
              f"plateau x - x_r in [{err.min():.3f}, {err.max():.3f}] mm")
        assert lo <= err.min() and err.max() <= hi, "first-plateau error [mm]"


def test_po_feedback_initial_output_is_held_by_the_integral():
    ff = WPAM.controller.po_feedforward
    ctl = PIControl(WPAM, DT, initial_output=ff)
    assert ctl.update(0.01, 0.01) == pytest.approx(ff, rel=1e-12)  # zero error
    # and it is ordinary integral state: a steady error moves it at Ki (PI: no D kick
    # to saturate the output and pause the integral)
    for _ in range(1000):
        u = ctl.update(0.0102, 0.01)  # e = 0.2 mm for 1 s
    c = WPAM.controller
    assert u == pytest.approx(ff + (c.kp * 0.2 + c.ki * 0.2 * 1.0) * c.command_scale * MPA,
                             rel=1e-6)
    no_integral = WPAM.replace(controller={"ki": 0.0})
    assert PIControl(no_integral, DT, initial_output=ff).integral == 0.0


def test_feedback_keeps_po_within_regulator_and_cap():
    res = feedback_run()
    p_min, cap = WPAM.pneumatics.p_min, WPAM.controller.po_cap
    assert res.po_cmd.min() >= p_min and res.po_cmd.max() <= cap, "Po command [Pa]"
    # The chamber starts vented at atmosphere and needs ~0.3 s to fill up to p_min;
    # after that it follows the clamped command through the valve. Only compression
    # by the moving muscle can push it past the command: allow 1 kPa.
    filled = res.time >= 0.5
    po = res.po[filled]
    print(f"PI at 100 N: Po in [{po.min() / MPA:.4f}, {po.max() / MPA:.4f}] MPa after 0.5 s")
    assert po.min() >= p_min - 1e3 and po.max() <= cap + 1e3, "chamber Po [Pa]"


@pytest.mark.parametrize("control", [PIControl, PIDControl], ids=["pi", "pid"])
def test_po_feedback_does_not_wind_up(control):
    ctl = control(WPAM, DT)
    cap, p_min = WPAM.controller.po_cap, WPAM.pneumatics.p_min
    for _ in range(20_000):  # 20 s over-contracted by 5 mm: Po pinned at the cap
        u = ctl.update(5.0 * MM, 0.0)
    assert u == cap
    # A wound-up integral (100 mm s -> 0.8 MPa) would hold the cap for minutes.
    leaves = [ctl.update(-0.5 * MM, 0.0) for _ in range(3)]
    assert min(leaves) < cap, "Po leaves the cap within 3 steps of the error reversing"
    c = WPAM.controller
    assert abs(c.ki * ctl.integral * c.command_scale) < 0.08, "integral term [MPa]"
    for _ in range(20_000):  # and the same at the lower limit
        u = ctl.update(-5.0 * MM, 0.0)
    assert u == p_min
    leaves = [ctl.update(0.5 * MM, 0.0) for _ in range(3)]
    assert max(leaves) > p_min, "Po leaves p_min within 3 steps of the error reversing"


def test_po_feedback_follows_the_pi_law_in_its_linear_range():
    """Po = command_scale (Kp e + Ki int(e) dt), e in mm (paper §4.1 gains), inside
    [p_min, po_cap]."""
    ctl = PIControl(WPAM, DT)
    c = WPAM.controller
    e_mm = 1.0
    for _ in range(10_000):
        u = ctl.update(e_mm * MM, 0.0)
    expected = (c.kp * e_mm + c.ki * e_mm * 10.0) * c.command_scale * MPA
    assert u == pytest.approx(expected, rel=1e-9)


# ------------------------------------------------------- numerical convergence

@pytest.mark.parametrize("control", ["pi", "pid"])
def test_sine_response_has_settled_after_the_settle_cycles(control):
    """The sweep analyses cycles 5-7 (`SineSpec.settle_cycles` = 4): they must be close
    to the periodic state. 150 N and 0.2 Hz settle slowest: the integral carries the
    loop's hysteretic memory through the friction band. On the shipped plant cycles 3-5
    were still 0.7-1.0 deg of lag from it (18.9 against 17.8 deg), as much as the lag
    differences between loads that the findings order; four more cycles than the sweep's
    change gain and lag by less than 1 % and 1 deg (measured PI 0.2 %, 0.4 deg; PID
    0.1 %, 0.4 deg)."""
    fr = []
    for settle in (4, 8):
        spec = SineSpec(0.2, settle_cycles=settle)
        r = sine_run(WPAM, 150.0, control, spec, engine=ENGINE)
        fr.append(frequency_response(r.time, r.x_ref, r.x, spec.freq, settle_cycles=settle,
                                     n_cycles=spec.cycles))
    print(f"{control} 150 N 0.2 Hz, settle 4 vs 8 cycles: gain {fr[0].gain:.4f} vs "
          f"{fr[1].gain:.4f}, lag {fr[0].phase_lag_deg:.3f} vs {fr[1].phase_lag_deg:.3f} deg")
    assert fr[0].gain == pytest.approx(fr[1].gain, rel=1e-2)
    assert fr[0].phase_lag_deg == pytest.approx(fr[1].phase_lag_deg, abs=1.0)


def test_halving_dt_keeps_the_rest_contraction():
    muscle = MuscleModel.from_params(WPAM)
    pi = muscle.equilibrium_pressure(25 * MM, 100.0, 0.0, direction=+1)
    x = [open_loop(WPAM, 100.0, hold(pi, 8.0, dt), dt=dt).x[-1] for dt in (DT, DT / 2)]
    delta_mm = abs(x[1] - x[0]) / MM
    print(f"constant Pi at 100 N: rest x {x[0] / MM:.5f} mm, dt/2 changes it by "
          f"{delta_mm:.2e} mm")
    assert delta_mm < 0.05, "rest contraction change on halving dt [mm]"


def test_halving_dt_keeps_the_loop_area():
    a1 = loop_area(ramp_run(100.0).pi, ramp_run(100.0).x)
    a2 = loop_area(ramp_run(100.0, dt=DT / 2).pi, ramp_run(100.0, dt=DT / 2).x)
    print(f"open-loop loop area at 100 N: {a1 / (MPA * MM):.4f} MPa mm, dt/2 changes it by "
          f"{100 * abs(a2 / a1 - 1):.3f} %")
    assert a2 == pytest.approx(a1, rel=0.02), "loop area on halving dt"


# ------------------------------------------------------------- determinism

def test_same_run_twice_is_bit_identical():
    x_ref = step_target()[:10_000]
    muscle = MuscleModel.from_params(WPAM)
    pi_cmd = pi_feedforward(muscle, WPAM, x_ref, 100.0, WPAM.controller.po_feedforward)
    drive = Drive(pi_cmd, np.zeros_like(x_ref), x_ref)
    a, b = (simulate(WPAM, 100.0, drive, control="pid", engine=ENGINE) for _ in range(2))
    for name, arr in a.arrays().items():
        assert np.array_equal(arr, b.arrays()[name], equal_nan=True), name


def test_csv_holds_every_sample_in_display_units(tmp_path):
    """Block-formatted CSV: same text as np.savetxt, values back in mm/MPa within %.6g."""
    n = 2 * 4096 + 7  # more than one formatting block
    t = np.arange(n) * 1e-3
    x_ref = np.where(t < 1.0, np.nan, 0.02)  # NaN target in open loop
    r = SimResult(time=t, x=0.03 * np.sin(t), velocity=np.cos(t), x_ref=x_ref,
                  pi=0.3e6 + t, po=0.04e6 - t, pi_cmd=0.3e6 + 0 * t, po_cmd=0 * t,
                  tension=100 + t, friction=5 + 0 * t, pi_reg=0.3e6 + 2 * t,
                  po_reg=0.04e6 + 0 * t, context=RunContext(WPAM, 1e-3, 100.0, "pi"))
    path = r.to_csv(tmp_path / "run.csv")
    lines = path.read_text().splitlines()
    table = np.genfromtxt(path, delimiter=",", names=True)  # plain: no comment lines
    assert len(table) == n
    assert np.allclose(table["x_mm"], r.x / MM, rtol=1e-5, atol=1e-9)
    assert np.allclose(table["pi_mpa"], r.pi / MPA, rtol=1e-5)
    assert np.array_equal(np.isnan(table["x_ref_mm"]), np.isnan(x_ref))
    ref = io.StringIO()
    np.savetxt(ref, np.column_stack([getattr(r, f) * k for f, _, k in results._COLUMNS]),
               fmt="%.6g", delimiter=",")
    assert lines[1:] == ref.getvalue().splitlines()


# ------------------------------------------------------------------ bad input

@pytest.mark.parametrize("load", [-10.0, 0.0, float("nan"), float("inf")])
def test_bad_load_is_rejected_naming_value_and_range(load):
    with pytest.raises(ParameterError, match=r"load = .* outside the allowed range \[1, 2000\]"):
        check_load(load)
    n = 10
    with pytest.raises(ParameterError, match="load"):
        simulate(WPAM, load, Drive(np.zeros(n), np.zeros(n), np.full(n, np.nan)),
                 engine=ENGINE)


@pytest.mark.parametrize("dt", [0.0, -1e-3, 0.01, float("nan")])
def test_bad_dt_is_rejected(dt):
    with pytest.raises(ParameterError, match=r"dt = .* outside the allowed range"):
        check_dt(dt)
    n = 10
    with pytest.raises(ParameterError, match="dt"):
        simulate(WPAM, 100.0, Drive(np.zeros(n), np.zeros(n), np.full(n, np.nan)), dt=dt,
                 engine=ENGINE)


def test_check_range_names_value_unit_and_bracket():
    with pytest.raises(ParameterError, match=r"pi = 0.7 MPa is outside the allowed range "
                                             r"\[0.005, 0.5\] MPa"):
        check_range("pi", 0.7, 0.005, 0.5, "MPa")
    with pytest.raises(ParameterError, match=r"\(0, 1\]"):
        check_range("x", 0.0, 0.0, 1.0, lo_open=True)
    with pytest.raises(ParameterError, match="not a number"):
        check_range("x", "abc", 0.0, 1.0)


def test_non_finite_commands_are_rejected():
    n = 10
    with pytest.raises(ParameterError, match="pi_cmd contains NaN"):
        Drive(np.full(n, np.nan), np.zeros(n), np.full(n, np.nan))
    with pytest.raises(ParameterError, match="po_cmd contains NaN or infinite"):
        Drive(np.zeros(n), np.full(n, np.inf), np.full(n, np.nan))
    with pytest.raises(ParameterError, match=r"drive.po_cmd has shape \(9,\)"):
        Drive(np.zeros(n), np.zeros(n - 1), np.full(n, np.nan))
    with pytest.raises(ParameterError, match="finite target"):
        simulate(WPAM, 100.0, Drive(np.zeros(n), np.zeros(n), np.full(n, np.nan)),
                 control="pi", engine=ENGINE)


def test_bad_parameters_are_rejected():
    with pytest.raises(ParameterError, match=r"controller.po_cap = 600000 Pa .*\[5000, 500000\]"):
        Params(controller=Controller(po_cap=0.6 * MPA))
    with pytest.raises(ParameterError, match="valid presets: wpam, rlam, mckibben"):
        preset("nope")
    with pytest.raises(ParameterError, match="unknown parameter muscle.mu; valid names"):
        WPAM.replace(muscle={"mu": 0.1})
    with pytest.raises(ParameterError, match="muscle.friction_coeff = -0.1"):
        WPAM.replace(muscle={"friction_coeff": -0.1})
    with pytest.raises(ParameterError, match="unknown control 'pd'; valid: open, pi, pid"):
        simulate(WPAM, 100.0, Drive(np.zeros(3), np.zeros(3), np.zeros(3)), control="pd",
                 engine=ENGINE)


def test_diverging_run_raises_instead_of_returning_nans(monkeypatch):
    """A chamber update too fast for dt is refused up front (test_plugin.py); with that
    check removed, the run must still stop with a message rather than return NaNs: the
    engine refuses the model by the rule table (wpam_mj.physics.rules)."""
    import wpam_mj.simulation.simulate  # noqa: PLC0415

    monkeypatch.setattr(wpam_mj.simulation.simulate, "check_chamber_step", lambda params, dt: None)
    bad = WPAM.replace(pneumatics={"inner_conductance": 1e-6, "outer_conductance": 1e-6})
    with pytest.raises(ParameterError, match=r"timestep = 0.005 s is outside the allowed "
                                             r"range \(0, 7.96474e-05\] s"):
        open_loop(bad, 100.0, hold(0.3 * MPA, 2.0, 0.005), dt=0.005)


# ------------------------------------------------------------------------ MJCF

@pytest.mark.parametrize("xml", [MODEL_XML, SCENE_XML], ids=["model", "scene"])
def test_mjcf_compiles_and_steps_without_warnings(xml):
    model = mujoco.MjModel.from_xml_path(str(xml))
    data = mujoco.MjData(model)
    mujoco.mj_step(model, data, nstep=round(1.0 / model.opt.timestep))
    warnings = {mujoco.mjtWarning(i).name: data.warning[i].number
                for i in range(len(data.warning)) if data.warning[i].number}
    assert not warnings, f"MuJoCo warnings: {warnings}"
    assert np.all(np.isfinite(data.qpos))
    obj = mujoco.mjtObj
    counts = {obj.mjOBJ_BODY: model.nbody, obj.mjOBJ_JOINT: model.njnt,
              obj.mjOBJ_GEOM: model.ngeom, obj.mjOBJ_SITE: model.nsite,
              obj.mjOBJ_TENDON: model.ntendon, obj.mjOBJ_ACTUATOR: model.nu}
    for kind, count in counts.items():
        start = 1 if kind == obj.mjOBJ_BODY else 0  # body 0 is the world
        for i in range(start, count):
            assert mujoco.mj_id2name(model, kind, i), f"unnamed {kind.name} {i} in {xml.name}"


@pytest.mark.parametrize("name", ["wpam", "rlam", "mckibben"])
def test_built_models_step_without_warnings(name):
    params = preset(name)
    for load in LOADS:
        model = build_model(params, load)
        data = mujoco.MjData(model)
        mujoco.mj_step(model, data, nstep=1000)
        assert all(w.number == 0 for w in data.warning), f"{name} at {load} N"
        assert model.body("load").mass[0] * 9.80665 == pytest.approx(load, rel=1e-12)


@pytest.mark.parametrize("name, value", [("pi_cmd", 0.6 * MPA), ("pi_cmd", -0.001 * MPA),
                                         ("po_cmd", -0.01 * MPA), ("po_cmd", 0.7 * MPA)])
def test_pressure_command_outside_regulator_range(name, value):
    n = 200
    cmds = {"pi_cmd": np.full(n, 0.1 * MPA), "po_cmd": np.zeros(n)}
    cmds[name][50] = value
    drive = Drive(**cmds, x_ref=np.full(n, np.nan))
    with pytest.raises(ParameterError, match=rf"drive\.{name} = .* MPa at t = 0\.05 s is "
                                             r"outside the regulator range \[0, 0\.5\] MPa"):
        simulate(WPAM, 100.0, drive, dt=DT)


@pytest.mark.parametrize("control", CONTROLS)
def test_controller_reset_restarts_the_run(control):
    """Every registered controller: after reset() the same inputs give the same outputs."""
    ctl = make_controller(control, WPAM, DT)
    assert ctl.name == control
    inputs = [(0.01 + 1e-4 * i, 0.012, 0.03 * MPA) for i in range(50)]
    first = [ctl.update(*u) for u in inputs]
    ctl.reset()
    assert [ctl.update(*u) for u in inputs] == first
    assert (first[0] == 0.03 * MPA) == (not ctl.feedback)


def test_with_values_sets_fields_by_dotted_name():
    p = WPAM.with_values({"muscle.damping": 30.0, "controller.kp": 0.2})
    assert (p.muscle.damping, p.controller.kp) == (30.0, 0.2)
    assert p.replace(muscle={"damping": 20.0}, controller={"kp": 0.1}) == WPAM
    assert WPAM.with_values({}) is WPAM
    with pytest.raises(ParameterError, match="unknown parameter muscle.nope"):
        WPAM.with_values({"muscle.nope": 1.0})
