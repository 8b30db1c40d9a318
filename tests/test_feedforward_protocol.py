"""Physics of the PI staircase: the rest start and the contracting-branch feedforward.

With true stiction the feedback's Po can hold the muscle anywhere inside the friction
band, 18-50 kPa of Po wide here (`docs/physics.md`), 2-5 mm of error at the paper's Kp.
Where a step leaves the muscle inside the band, the integral creeps it back with the
paper's Kp/Ki = 12.5 s; only a muscle that finishes every step on one branch of the band
settles within a 10 s plateau. These tests pin that mechanism on the shipped plant.
"""

from __future__ import annotations

import numpy as np
import pytest

from wpam_mj.experiments.drives import drive_for_targets, step_targets
from wpam_mj.physics.params import preset
from wpam_mj.errors import ParameterError
from wpam_mj.units import MM, MPA
from wpam_mj.simulation.simulate import simulate
from wpam_mj.experiments.paper_studies import step_study

WPAM = preset("wpam")
DT = 1e-3  # s
SETTLE_S = 5.0  # the last 5 s of each 10 s plateau
# Pi from the contracting branch of eq. 5 at the regulator's minimum Po, 1 % of the
# friction band beyond it: at Po = p_min the muscle would over-contract, Po holds it back.
CONTRACTING_BRANCH = WPAM.with_values({"controller.feedforward_friction": 1.01,
                                       "controller.po_feedforward": WPAM.pneumatics.p_min})
# The earlier reading: Pi short of the contracting branch (0.83 of the band) at a nominal
# Po of 0.0108 MPa.
SHORT_OF_BRANCH = WPAM.with_values({"controller.feedforward_friction": 0.83,
                                    "controller.po_feedforward": 0.0108 * MPA})


def first_plateau(params, load: float, *, start_at_rest: bool):
    """PI on the staircase's first 10 s plateau (target 0 mm: the muscle at its stop)."""
    t = np.arange(10_000) * DT
    drive = drive_for_targets(params, load, step_targets(t), "pi", DT)
    if not start_at_rest:
        drive = type(drive)(drive.pi_cmd, drive.po_cmd, drive.x_ref)  # chambers vented at t = 0
    return simulate(params, load, drive, dt=DT, control="pi", record_dt=0.01)


@pytest.mark.parametrize("params", [CONTRACTING_BRANCH, SHORT_OF_BRANCH],
                         ids=["branch", "short"])
def test_rig_at_rest_stays_at_its_stop_where_a_vented_start_over_contracts(params):
    """A rig already holding the first commands starts with its chambers at them and its
    muscle at the stop; from vented chambers the small inner bag fills faster than the
    outer bag's litre and dP overshoots (by how much depends on the two lines: 0.1-2 mm of
    contraction for the readings here)."""
    at_rest = first_plateau(params, 50.0, start_at_rest=True)
    vented = first_plateau(params, 50.0, start_at_rest=False)
    assert at_rest.pi[0] == pytest.approx(at_rest.pi_cmd[0], rel=1e-12), "Pi chamber at t = 0"
    assert at_rest.po[0] == pytest.approx(at_rest.po_cmd[0], rel=1e-12), "Po chamber at t = 0"
    assert vented.pi[0] == vented.po[0] == 0.0, "vented chambers at t = 0 [Pa gauge]"
    rest_mm, vented_mm = at_rest.x.max() / MM, vented.x.max() / MM
    print(f"50 N, first plateau: max x {rest_mm:.3f} mm at rest, {vented_mm:.3f} mm vented")
    assert rest_mm < 0.2, "muscle at rest near its stop [mm]"


@pytest.fixture(scope="module")
def staircase():
    runs = [(load, "pi") for load in (50.0, 100.0, 150.0)]
    return {name: step_study(params, runs, dt=DT)
            for name, params in (("branch", CONTRACTING_BRANCH), ("short", SHORT_OF_BRANCH))}


def test_contracting_branch_feedforward_settles_every_plateau(staircase):
    """Contraction steps drop Po to p_min and the muscle climbs its contracting branch to
    the target; extension steps push it down past the target, and back at p_min it climbs
    the same branch to it. Every plateau ends on that branch, whatever the integral holds."""
    for s in staircase["branch"]:
        err, pp = s.worst_error(SETTLE_S) / MM, s.worst_peak_to_peak(SETTLE_S) / MM
        print(f"{s.load:g} N: worst plateau error {err:.3f} mm, x peak-to-peak {pp:.3f} mm")
        # 0.87 mm: the split Table 2's feedback-row limit allowed at 150 N on the plant
        # this reading was first measured on (findings.plateau_error_limit; 0.72 mm on
        # the shipped plant, whose own feedforward reading its golden test judges)
        assert err < 0.87 and pp < 0.2, f"{s.load:g} N plateau error / peak-to-peak [mm]"


def test_po_rises_with_load_on_the_contracting_branch(staircase):
    """The over-contraction Po holds back is a share of the friction band, which grows
    with the load; a feedforward short of the contracting branch (0.83 of it) lets Po
    sink towards p_min at the heavy load instead."""
    po = {name: [float(np.mean(s.po_mean)) for s in runs] for name, runs in staircase.items()}
    print("plateau-mean Po [MPa] at 50/100/150 N:",
          {k: [round(v / MPA, 4) for v in vs] for k, vs in po.items()})
    assert po["branch"][0] < po["branch"][1] < po["branch"][2], "Po rises with load"
    assert po["short"][0] > po["short"][2], "short of the branch: Po falls with load"


def test_feedforward_friction_beyond_the_branch_is_bounded():
    assert CONTRACTING_BRANCH.controller.feedforward_friction == 1.01
    with pytest.raises(ParameterError, match=r"feedforward_friction = 1.3 .*\[0, 1.2\]"):
        WPAM.with_values({"controller.feedforward_friction": 1.3})


def quasi_static_pi(pre_sliding: float, seconds: float = 10.0, dt: float = 0.01):
    """|e(t)| [m] of a quasi-static Maxwell-slip muscle under the paper's PI (0-5 V reading):
    ten elastoplastic elements of 1-10 N that slip after `pre_sliding` [m] of stretch, a
    10 N/m spring, Po on 1e-3 m^2 extending it; the integral updated implicitly."""
    kp, ki, area = 0.01 * MPA / MM, 0.0008 * MPA / MM, 1e-3  # Pa/m, Pa/(m s), m^2
    limit = np.arange(1.0, 11.0)  # N, each element's slip force
    k, z = limit / pre_sliding, np.zeros(10)  # N/m; slider positions [m]
    drive, integral, errors = 60.0, 0.0, []  # N (Pi's pull beyond the load), Pa

    def balance(x, integral):  # contraction force left over at x [N], rising with x
        return (np.sum(np.clip(k * (x - z), -limit, limit)) + 10.0 * x
                + area * (kp * x + integral) - drive)

    for _ in range(int(seconds / dt)):
        lo, hi = -1.0, 1.0
        for _ in range(80):  # bisection: the balance rises with x
            mid = 0.5 * (lo + hi)
            lo, hi = (lo, mid) if balance(mid, integral + ki * mid * dt) > 0 else (mid, hi)
        x = 0.5 * (lo + hi)
        integral += ki * x * dt
        z = np.clip(z, x - limit / k, x + limit / k)  # elements past their limit slip
        errors.append(abs(x))
    return np.array(errors), ki / kp


@pytest.mark.parametrize("pre_sliding", [1e-6, 1e-4, 1e-2, 1.0])
def test_no_friction_law_settles_faster_than_the_pi_zero(pre_sliding):
    """Landed, a quasi-static muscle's error falls no faster than exp(-t Ki/Kp)
    (`StepRun.landing_floor`): true for stiction (1 um of pre-sliding) and for pre-sliding
    up to a metre, and approached as the muscle grows compliant."""
    e, rate = quasi_static_pi(pre_sliding)
    t = np.arange(1, len(e)) * 0.01
    achieved = e[1:] / e[0]
    assert np.all(achieved >= np.exp(-rate * t) * (1 - 1e-9)), "faster than the PI's zero"
    if pre_sliding >= 1.0:
        assert achieved[-1] < 1.1 * np.exp(-rate * t[-1]), "a compliant plant nears the bound"


def test_plateaus_settle_no_lower_than_their_landing_floor(staircase):
    """In the simulator too, from the landing on nothing beats the PI's zero: every landed
    plateau's steady-state error (the mean over the last 5 s) is at least its landing
    floor (a floor above the error would mean the landing is misread: the chambers or the
    muscle still moving)."""
    for runs in staircase.values():
        for s in runs:
            r, floor = s.result, s.landing_floor(SETTLE_S)
            late = (r.time % 10.0) >= 10.0 - SETTLE_S
            plateau = (r.time // 10.0).astype(int)
            worst = np.array([abs(np.mean((r.x - r.x_ref)[late & (plateau == k)]))
                              for k in range(len(floor))])
            landed = np.isfinite(floor)
            assert landed.sum() >= len(floor) - 2, f"{s.load:g} N: most plateaus land"
            assert np.all(worst[landed] >= 0.98 * floor[landed]), f"{s.load:g} N"


def test_a_plateaus_error_is_its_steady_state_mean_and_its_stillness_the_peak_to_peak():
    """worst_error is Fig. 16's steady-state average: a muscle swinging +-0.5 mm about
    0.1 mm past its target over a plateau's last 5 s has a 0.1 mm error and a 1 mm
    peak-to-peak (the largest instantaneous error, 0.6 mm, is neither)."""
    import dataclasses

    from wpam_mj.experiments.responses import StepRun
    from wpam_mj.simulation.context import RunContext
    from wpam_mj.simulation.results import SimResult

    t = np.arange(20_000) * DT  # two 10 s plateaus
    x_ref = np.where(t < 10.0, 0.0, 10.0 * MM)
    series = {f.name: np.zeros(len(t)) for f in dataclasses.fields(SimResult)
              if f.name != "context"}
    series.update(time=t, x_ref=x_ref,
                  x=x_ref + 0.1 * MM + 0.5 * MM * np.sin(2 * np.pi * t))
    run = StepRun(SETTLE_S, np.array([0.0, 10.0 * MM]), np.zeros(2), np.zeros(2),
                  np.zeros(2), SimResult(**series, context=RunContext(WPAM, DT, 100.0, "pi")))
    assert run.worst_error(SETTLE_S) == pytest.approx(0.1 * MM, abs=1e-6)
    assert run.worst_peak_to_peak(SETTLE_S) == pytest.approx(1.0 * MM, rel=1e-3)
