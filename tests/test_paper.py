"""The paper's findings as signed margins, on hand-made sweeps: PASS/FAIL, the places a
finding fails (by load, frequency and controller) and the calibration residuals all
come from the same margins."""

import pytest

from wpam_mj import paper
from wpam_mj.reproduction import findings
from wpam_mj.physics.params import preset
from wpam_mj.simulation.context import StudyContext
from wpam_mj.units import MPA
from wpam_mj.experiments.responses import SweepPoint, SweepResult
from wpam_mj.reproduction.findings import checks_text

CAP = paper.PO_CAP_MPA * MPA
CONTEXT = StudyContext(preset("wpam"), 1e-3)  # what the sweeps were made with: this cap


def _heavy_fast_cap(load, f, c):
    """The paper's Po picture: the cap at the heavy load from 0.5 Hz, less elsewhere."""
    return CAP if (load, f >= 0.5) == (150.0, True) else 0.06 * MPA


def _sweep(gain, lag, po_max=_heavy_fast_cap):
    """A sweep whose gain/lag/Po max are functions of (load, freq, controller)."""
    po = po_max if callable(po_max) else (lambda load, f, c: po_max)
    points = tuple(SweepPoint(load, f, c, gain(load, f, c), lag(load, f, c), po(load, f, c))
                   for load in paper.LOADS_N for c in paper.SWEEP_CONTROLLERS
                   for f in paper.SWEEP_FREQS_HZ)
    return SweepResult(points=points, context=CONTEXT)


def by_name(sw):
    return {c.name: c for c in findings.sweep_checks(sw)}


def _papers_picture():
    return _sweep(gain=lambda load, f, c: 1.0 / (1.0 + f),
                  lag=lambda load, f, c: 40 * f + (load / 20 if f < 0.5 else 0)
                  - (2.0 if c == "pid" else 0.0))


def test_sweep_checks_pass_on_the_papers_picture():
    checks = findings.sweep_checks(_papers_picture())
    assert all(c.passed is True for c in checks), checks_text(checks)
    assert all(m.margin >= 0.0 for c in checks for m in c.margins)


def test_sweep_checks_fail_where_the_paper_does_not_hold():
    sw = _sweep(gain=lambda load, f, c: ((1.0 + f) * (1.0 + load / 1000)  # rises, load-
                                         * (1.1 if c == "pid" else 1.0)),  # and PID-dependent
                lag=lambda load, f, c: 40 * f - load / 10 + (2.0 if c == "pid" else 0.0),
                po_max=lambda load, f, c: CAP if load < 150.0 else 0.05 * MPA)
    checks = findings.sweep_checks(sw)
    assert all(c.passed is False for c in checks), checks_text(checks)


def test_sweep_checks_need_their_data():
    sw = SweepResult(points=(SweepPoint(100.0, 0.5, "pi", 0.9, 30.0, 0.07 * MPA),),
                     context=CONTEXT)
    assert all(c.passed is None for c in findings.sweep_checks(sw))


def test_a_failing_margin_names_its_load_and_frequency():
    """Only the 100 N PI lag at 0.2 Hz breaks 'lag smaller at lower load': exactly that
    margin is negative, and the check's text names it."""
    def lag(load, f, c):
        base = 40 * f + (load / 20 if f < 0.5 else 0) - (2.0 if c == "pid" else 0.0)
        return base + (5.0 if (load, f, c) == (100.0, 0.2, "pi") else 0.0)

    sw = _sweep(gain=lambda load, f, c: 1.0 / (1.0 + f), lag=lag)
    checks = by_name(sw)
    for name in ("lag_order_low_freq", "lag_order_low_freq_strict"):
        lag_load = checks[name]
        bad = [(m.load, m.freq, m.controller) for m in lag_load.margins if m.margin < 0.0]
        assert bad == [(150.0, 0.2, "pi")], name  # 150 N now 2.5 deg below the 100 N lag
        assert lag_load.passed is False and "0.2 Hz: 10.5/18.0/15.5" in lag_load.detail
    assert "out of order at 0.2 Hz" in checks["lag_order_low_freq_strict"].detail


def test_a_lag_order_seen_at_the_figures_resolution_holds_and_a_flat_one_fails():
    """'in the slower frequency band, the phase lag tends to be smaller at lower loads'
    read on Fig. 17, at the 1 deg it resolves (as every other lag comparison): a light
    load 0.4 deg behind the next heavier at 0.1 Hz, with the heaviest 2 deg behind the
    lightest at 0.25 Hz, holds it (the strict reading, an extra, does not); lags all
    within 1 deg of each other show no order and fail it; a reversal of 1.5 deg fails."""
    def checks(low_lag):
        return by_name(_sweep(gain=lambda load, f, c: 1.0 / (1.0 + f),
                              lag=lambda load, f, c: 40 * f + (low_lag(load, f) if f < 0.5
                                                               else 0.0)))

    sub_degree = checks(lambda load, f: {50.0: 0.4, 100.0: 0.0, 150.0: 0.6}[load]
                        + (load / 50 - 1 if f == 0.25 else 0.0))
    assert sub_degree["lag_order_low_freq"].passed is True
    assert sub_degree["lag_order_low_freq_strict"].passed is False
    assert not sub_degree["lag_order_low_freq_strict"].counted
    flat = checks(lambda load, f: load / 200)  # the heaviest 0.5 deg behind the lightest
    assert flat["lag_order_low_freq"].passed is False
    reversed_ = checks(lambda load, f: load / 20 - (4.0 if load == 150.0 else 0.0))  # 1.5 below
    assert reversed_["lag_order_low_freq"].passed is False


def test_the_papers_load_findings_are_checked_on_its_controllers_only():
    """§4.2 states its load findings for PI and compares PID with PI: a sweep that adds
    another controller (pi_ff) whose gains differ across loads is not held to them."""
    base = _papers_picture()
    extra = tuple(SweepPoint(p.load, p.freq, "pi_ff", p.gain * (1 + p.load / 100), p.phase_lag_deg
                             + p.load, p.po_max) for p in base.points if p.controller == "pi")
    checks = findings.sweep_checks(SweepResult(points=base.points + extra, context=CONTEXT))
    assert all(c.passed is True for c in checks), checks_text(checks)
    assert not any(m.controller == "pi_ff" for c in checks for m in c.margins)


def test_high_frequency_lags_and_pid_against_pi_are_checked_as_the_paper_says():
    """'The phase lag is almost the same above 0.5 Hz' (PI, loads within LAG_SAME_DEG);
    at 150 N PID's gain equals PI's and its lag is visibly smaller (>= PID_LEAD_MIN_DEG)."""
    spread = _sweep(gain=lambda load, f, c: 1.0 / (1.0 + f),
                    lag=lambda load, f, c: 40 * f + load / 10 - (2.0 if c == "pid" else 0.0))
    assert by_name(spread)["lag_same_high_freq"].passed is False  # 10 deg apart at 0.5 Hz+
    small_lead = _sweep(gain=lambda load, f, c: 1.0 / (1.0 + f),
                        lag=lambda load, f, c: 40 * f - (0.5 if c == "pid" else 0.0))
    assert by_name(small_lead)["pid_leads_pi"].passed is False  # 0.5 deg: not visible
    pid_gain = _sweep(gain=lambda load, f, c: (1.08 if c == "pid" else 1.0) / (1.0 + f),
                      lag=lambda load, f, c: 40 * f - (2.0 if c == "pid" else 0.0))
    checks = by_name(pid_gain)
    assert checks["pid_gain_equals_pi"].passed is False
    assert checks["gain_spread"].passed is True  # PI alone: equal across loads


def test_a_pid_lead_seen_only_where_it_is_resolved_holds_and_a_visible_lag_fails():
    """'the phase delay is smaller when the PID controller is used' (the abstract: 'tended
    to improve'): PID's lag nowhere visibly above PI's and visibly below it somewhere.
    A lead of 0.2 deg at low frequency and 5 deg above 0.5 Hz holds it (the reading at
    every frequency, an extra, does not); a PID 2 deg behind at 0.1 Hz fails it."""
    def checks(lead):
        sw = _sweep(gain=lambda load, f, c: 1.0 / (1.0 + f),
                    lag=lambda load, f, c: 40 * f - (lead(f) if c == "pid" else 0.0))
        return {c.name: c for c in findings.sweep_checks(sw)}

    high_only = checks(lambda f: 5.0 if f >= 0.5 else 0.2)
    assert high_only["pid_leads_pi"].passed is True
    assert high_only["pid_leads_pi_everywhere"].passed is False
    assert not high_only["pid_leads_pi_everywhere"].counted
    behind = checks(lambda f: -2.0 if f == 0.1 else 5.0)
    assert behind["pid_leads_pi"].passed is False
    assert "0.1 Hz -2.00" in behind["pid_leads_pi"].detail


def test_a_load_that_does_not_follow_fails_equal_gains_by_a_number_and_is_named():
    """At 1 Hz the 150 N load sticks in the analysed cycles (a gain of ~0, as slow lines
    give): the spread counts its gain as the least the analysis resolves, a 0.5 mm span
    of the 25 mm sine (0.01), so the check fails by a finite, readable amount and says
    which load did not move, instead of dividing by ~0."""
    base = _papers_picture()
    stuck = (150.0, 1.0, "pi")
    points = tuple(SweepPoint(p.load, p.freq, p.controller, 3e-17, 0.6, p.po_max,
                              load_moved=False) if (p.load, p.freq, p.controller) == stuck
                   else p for p in base.points)
    (spread,) = [c for c in findings.sweep_checks(SweepResult(points, CONTEXT))
                 if c.name == "gain_spread"]
    worst = min(spread.margins, key=lambda m: m.margin)
    assert (worst.freq, worst.controller) == (1.0, "pi")
    assert worst.value == pytest.approx(0.5 / 0.01 - 1.0)  # gain 1/(1+1) over 0.01
    assert spread.passed is False
    assert "150 N did not move in the analysed cycles" in spread.detail, spread.detail
    assert "4900.0%" in spread.detail


def test_calibration_residuals_are_the_margins():
    """Zero where every finding holds with headroom; the Po-cap residual grows as the
    regulator's Po falls short of the cap, in units of a tenth of the cap."""
    assert not findings.residuals(findings.sweep_checks(_papers_picture())).any()
    short = _sweep(gain=lambda load, f, c: 1.0 / (1.0 + f),
                   lag=lambda load, f, c: 40 * f + (load / 20 if f < 0.5 else 0)
                   - (2.0 if c == "pid" else 0.0), po_max=0.5 * CAP)
    (cap,) = [c for c in findings.sweep_checks(short) if "reaches" in c.finding]
    limit = (1.0 - paper.PO_CAP_RTOL) * CAP
    assert findings.residuals([cap]) == pytest.approx(
        [paper.CALIBRATION_HEADROOM + (limit - 0.5 * CAP) / (0.1 * CAP)])


def test_parameter_defaults_are_the_papers_numbers():
    c = preset("wpam").controller
    assert (c.kp, c.ki, c.kd) == (paper.KP, paper.KI, paper.KD)
    assert c.po_cap == paper.PO_CAP_MPA * MPA


def test_feedback_row_is_each_cell_within_a_factor_of_two_of_the_papers():
    """Table 2's feedback row as a fidelity target: 0.0170 at 150 N holds from 0.0085 to
    0.034, and only the cell outside its factor fails."""
    from types import SimpleNamespace  # noqa: PLC0415

    finding = findings.FINDINGS["table2_feedback_row"]
    for f150, holds in ((0.0090, True), (0.030, True), (0.0079, False), (0.040, False)):
        t2 = SimpleNamespace(loads=paper.LOADS_N, feedback={50.0: 0.001, 100.0: 0.002,
                                                            150.0: f150},
                             paper=lambda: paper.TABLE2)
        margins = finding.margins(t2)
        assert all(m.margin >= 0 for m in margins) is holds, f150
        assert [m.load for m in margins if m.margin < 0] == ([] if holds else [150.0])


def test_extras_are_reported_and_not_counted():
    """Readings of ours that no sentence states (PID ahead at every frequency, the cap
    only in the heavy, fast case) are printed as extras and left out of the score."""
    checks = findings.sweep_checks(_papers_picture())
    extra = [c for c in checks if not c.counted]
    assert [c.name for c in extra] == ["lag_order_low_freq_strict", "pid_leads_pi_everywhere",
                                       "po_cap_light_slow"]
    assert "(extra)" in checks_text(extra)
    assert findings.score(checks) == (len(checks) - 3, len(checks) - 3)
