"""§4.2's findings, the frequency response (on a
`wpam_mj.experiments.responses.SweepResult`, whose context gives the Po cap): each a
`margins.Finding` with the paper's words. The paper states its load findings for the PI
controller and compares PID with PI at 150 N only; each finding is checked where the
paper states it, on the paper's controllers (a sweep of other controllers is not held to
them)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from wpam_mj.paper import (FIG18_FREQ_HZ, FIG18_LOAD_N, GAIN_LOAD_RTOL, GAIN_RISE_TOL,
                           LAG_FALL_TOL_DEG, LAG_ORDER_TOL_DEG, LAG_SAME_DEG,
                           PID_LEAD_MIN_DEG, PO_CAP_RTOL,
                           PO_SLOW_LIGHT_MAX_FRAC, SWEEP_CONTROLLERS)
from wpam_mj.experiments.feasibility import MOVE_MIN_MM
from wpam_mj.reproduction.margins import Finding, Margin
from wpam_mj.units import MM, MPA


def _paper_controllers(sw) -> list[str]:
    return [c for c in sw.controllers if c in SWEEP_CONTROLLERS]


def _falls_and_grows(sw):
    if len(sw.freqs) < 2:
        return None
    out = []
    for load in sw.loads:
        for c in _paper_controllers(sw):
            pts = sw.curve(load, c)
            if len(pts) < 2:
                continue
            g = np.array([p.gain for p in pts])
            lag = np.array([p.phase_lag_deg for p in pts])
            where = dict(load=load, controller=c)
            for i, (dg, dl) in enumerate(zip(np.diff(g), np.diff(lag))):
                out.append(Margin(dg, GAIN_RISE_TOL, -1, 0.1, freq=pts[i].freq, **where))
                out.append(Margin(dl, -LAG_FALL_TOL_DEG, +1, 10.0, freq=pts[i].freq, **where))
            out.append(Margin(g[-1] - g[0], 0.0, -1, 0.1, **where))
            out.append(Margin(lag[-1] - lag[0], 0.0, +1, 10.0, **where))
    return out or None


def _falls_and_grows_detail(sw, margins):
    def worst(limit: float, sign: float) -> tuple[float, str]:
        """The first largest rise (sign +1) or drop (-1) between neighbours, if any."""
        best, where = 0.0, ""
        for m in margins:
            if m.limit == limit and m.freq is not None and sign * m.value > best:
                nxt = sw.curve(m.load, m.controller)
                f1 = nxt[[p.freq for p in nxt].index(m.freq) + 1].freq
                best = sign * m.value
                where = f"{m.load:g} N {m.controller.upper()} {m.freq:g}->{f1:g} Hz"
        return best, where

    (rise, rise_at), (drop, drop_at) = worst(GAIN_RISE_TOL, 1.0), worst(-LAG_FALL_TOL_DEG, -1.0)
    return (f"largest gain rise {rise:+.3f} ({rise_at or '-'}), largest lag drop "
            f"{drop:.1f} deg ({drop_at or '-'}); tolerated: {GAIN_RISE_TOL} and "
            f"{LAG_FALL_TOL_DEG:g} deg between neighbouring frequencies")


def _resolved_gain(sw) -> float:
    """The least gain the analysis resolves as motion: a sine whose output spans
    `MOVE_MIN_MM` (a load that moves less did not move, `feasibility.load_moved`), so a
    stuck load's gain of ~0 gives a spread that is large but a number, not 1e16."""
    return MOVE_MIN_MM * MM / (2.0 * sw.amplitude)


def _spread(gains, sw) -> float:
    return max(gains) / max(min(gains), _resolved_gain(sw)) - 1.0


def _gain_spread(sw):
    if len(sw.loads) < 2 or "pi" not in sw.controllers:
        return None
    out = []
    for f in sw.freqs:
        g = [p.gain for p in sw.points if p.controller == "pi" and p.freq == f]
        if len(g) >= 2:
            out.append(Margin(_spread(g, sw), GAIN_LOAD_RTOL, -1, 0.1, freq=f, controller="pi"))
    return out


def _gain_spread_detail(sw, margins):
    worst, at = 0.0, None  # all NaN: no spread to place
    for m in margins:  # the last of the largest, as a reader scanning the table finds it
        if m.value >= worst:
            worst, at = m.value, m
    if at is None:
        return "largest spread max/min - 1 = 0.0% (no finite gain to compare)"
    still = [f"{p.load:g} N" for p in sw.points if p.freq == at.freq
             and p.controller == at.controller and not p.load_moved]
    note = (f"; {', '.join(still)} did not move in the analysed cycles (gain counted as "
            f"{_resolved_gain(sw):.3f}, the least resolved)") if still else ""
    return (f"largest spread max/min - 1 = {worst:.1%} ({at.controller.upper()} "
            f"{at.freq:g} Hz{note}); by frequency " + ", ".join(
                f"{m.freq:g} Hz {m.value:.1%}" for m in margins))


def _lags(sw, f, c):
    return [sw.point(load, f, c).phase_lag_deg for load in sw.loads]


def _low_freqs(sw) -> list[float] | None:
    low = [f for f in sw.freqs if f < FIG18_FREQ_HZ]
    return low if len(sw.loads) >= 2 and low and "pi" in sw.controllers else None


def _lag_rises_with_load(sw):
    """Each heavier load's PI lag minus the next lighter one's [deg], below 0.5 Hz (>= 0
    holds): the strict reading."""
    low = _low_freqs(sw)
    if low is None:
        return None
    out = []
    for f in low:
        lags = _lags(sw, f, "pi")
        for load, a, b in zip(sw.loads[1:], lags, lags[1:]):
            out.append(Margin(b - a, 0.0, +1, 10.0, load=load, freq=f, controller="pi"))
    return out


def _seen(differences: list[Margin], spans: list[Margin], tol: float) -> list[Margin]:
    """A lag order as a reader of Fig. 17 sees it, at its `tol` [deg] resolution: none of
    the `differences` visibly negative (each >= -tol) and the largest of the `spans`
    visibly positive (>= tol)."""
    return [*(replace(m, limit=-tol) for m in differences),
            replace(max(spans, key=lambda m: m.value), limit=tol)]


def _lag_tends_to_rise(sw):
    """No neighbouring pair of loads visibly out of order (each heavier lag >= the
    lighter's - 1 deg) and the heaviest load visibly behind the lightest (>= 1 deg) at one
    frequency at least (`_seen`)."""
    pairs = _lag_rises_with_load(sw)
    if pairs is None:
        return None
    spans = []
    for f in _low_freqs(sw):
        lags = _lags(sw, f, "pi")
        spans.append(Margin(lags[-1] - lags[0], 0.0, +1, 10.0, load=sw.loads[-1], freq=f,
                            controller="pi"))
    return _seen(pairs, spans, LAG_ORDER_TOL_DEG)


def _lag_order_text(sw, freqs) -> str:
    return "; ".join(f"{f:g} Hz: " + "/".join(f"{v:.1f}" for v in _lags(sw, f, "pi"))
                     for f in freqs)


def _lag_rises_with_load_detail(sw, margins):
    freqs = list(dict.fromkeys(m.freq for m in margins))
    bad = list(dict.fromkeys(m.freq for m in margins if m.margin < 0.0))
    return (("out of order" if bad else "PI lags [deg] by increasing load") + " at "
            + _lag_order_text(sw, bad or freqs))


def _lag_tends_to_rise_detail(sw, margins):
    return ("PI lags [deg] by increasing load at " + _lag_order_text(sw, _low_freqs(sw))
            + f" (pass: no lighter load more than {LAG_ORDER_TOL_DEG:g} deg above the next "
            f"heavier, the heaviest at least {LAG_ORDER_TOL_DEG:g} deg above the lightest at "
            f"one frequency; {LAG_ORDER_TOL_DEG:g} deg: what Fig. 17 resolves)")


def _lag_same_high(sw):
    high = [f for f in sw.freqs if f >= FIG18_FREQ_HZ]
    if len(sw.loads) < 2 or not high or "pi" not in sw.controllers:
        return None
    return [Margin(float(np.ptp(_lags(sw, f, "pi"))), LAG_SAME_DEG, -1, 10.0, freq=f,
                   controller="pi") for f in high]


def _lag_same_high_detail(sw, margins):
    return "; ".join(f"{m.freq:g} Hz: PI lags " + "/".join(
        f"{v:.1f}" for v in _lags(sw, m.freq, "pi")) + f" deg (spread {m.value:.1f})"
        for m in margins) + f" (pass: spread <= {LAG_SAME_DEG:g} deg)"


def _at_150(sw):
    if FIG18_LOAD_N not in sw.loads or not {"pi", "pid"} <= set(sw.controllers):
        return None
    return list(zip(sw.curve(FIG18_LOAD_N, "pi"), sw.curve(FIG18_LOAD_N, "pid")))


def _pid_gain_equal(sw):
    pairs = _at_150(sw)
    return None if pairs is None else [
        Margin(_spread([a.gain, b.gain], sw), GAIN_LOAD_RTOL, -1, 0.1, load=FIG18_LOAD_N,
               freq=a.freq) for a, b in pairs]


def _pid_gain_equal_detail(sw, margins):
    return ", ".join(f"{a.freq:g} Hz {a.gain:.3f}/{b.gain:.3f}" for a, b in _at_150(sw)) + (
        f" (PI/PID; worst {max(m.value for m in margins):.1%}, pass: <= {GAIN_LOAD_RTOL:.0%})")


def _pid_leads(sw) -> list[Margin] | None:
    """PI lag - PID lag [deg] at 150 N, one margin per frequency (>= PID_LEAD_MIN_DEG
    holds)."""
    pairs = _at_150(sw)
    return None if pairs is None else [
        Margin(a.phase_lag_deg - b.phase_lag_deg, PID_LEAD_MIN_DEG, +1, 10.0,
               load=FIG18_LOAD_N, freq=a.freq) for a, b in pairs]


def _pid_leads_pi(sw):
    """PID's lag nowhere visibly above PI's (the lead >= -1 deg at every frequency) and
    visibly below it (>= 1 deg) at one frequency at least (`_seen`)."""
    leads = _pid_leads(sw)
    return None if leads is None else _seen(leads, leads, PID_LEAD_MIN_DEG)


def _lead_text(leads) -> str:
    return "PI - PID lag " + ", ".join(f"{m.freq:g} Hz {m.value:+.2f}" for m in leads)


def _pid_leads_pi_detail(sw, margins):
    return _lead_text(_pid_leads(sw)) + (
        f" deg (pass: >= -{PID_LEAD_MIN_DEG:g} deg at every frequency and >= "
        f"{PID_LEAD_MIN_DEG:g} deg at one; {PID_LEAD_MIN_DEG:g} deg: what Fig. 17 resolves)")


def _pid_leads_everywhere_detail(sw, margins):
    return _lead_text(margins) + f" deg (pass: >= {PID_LEAD_MIN_DEG:g} deg at every frequency)"


def _po_reaches_cap(sw):
    p = sw.point(FIG18_LOAD_N, FIG18_FREQ_HZ, "pi")
    if p is None:
        return None
    po_cap = sw.context.po_cap
    return [Margin(p.po_max, (1.0 - PO_CAP_RTOL) * po_cap, +1, 0.1 * po_cap,
                   load=FIG18_LOAD_N, freq=FIG18_FREQ_HZ, controller="pi")]


def _po_reaches_cap_detail(sw, margins):
    p = sw.point(FIG18_LOAD_N, FIG18_FREQ_HZ, "pi")
    return (f"regulator-gauge Po max {p.po_max / MPA:.4f} MPa "
            f"(pass: >= {margins[0].limit / MPA:.4f} MPa); "
            f"chamber Po max {p.po_chamber_max / MPA:.4f} MPa")


def _po_cap_heavy_fast_only(sw):
    f = min(sw.freqs)
    light = [load for load in sw.loads if load < FIG18_LOAD_N]
    points = [(load, sw.point(load, f, "pi")) for load in light]
    if f >= FIG18_FREQ_HZ or not points or any(p is None for _, p in points):
        return None
    po_cap = sw.context.po_cap
    return [Margin(p.po_max, PO_SLOW_LIGHT_MAX_FRAC * po_cap, -1, 0.1 * po_cap, load=load,
                   freq=f, controller="pi") for load, p in points]


def _po_cap_heavy_fast_only_detail(sw, margins):
    return ", ".join(f"{m.load:g} N at {m.freq:g} Hz: Po max {m.value / MPA:.4f} MPa"
                     for m in margins) + f" (pass: < {margins[0].limit / MPA:.4f} MPa)"


SWEEP_FINDINGS = (
    Finding("gain_falls_lag_grows", "gain falls, lag grows with frequency",
            "'the output gain decreased, and the phase lag increased as the target frequency "
            "increased' (abstract; Fig. 17)",
            "gain falls and phase lag grows with frequency (every load, PI and PID)",
            _falls_and_grows, _falls_and_grows_detail, "needs >= 2 frequencies"),
    Finding("gain_spread", "PI gains of the loads within 5 %",
            "'Comparing the responses for each load, no change in amplitude gain is "
            "observed' (§4.2, PI)",
            f"PI gains of the loads within {GAIN_LOAD_RTOL:.0%} at each frequency",
            _gain_spread, _gain_spread_detail, "needs >= 2 loads and PI"),
    Finding("lag_order_low_freq", "PI lag visibly smaller at lower load below 0.5 Hz",
            "'in the slower frequency band, the phase lag tends to be smaller at lower "
            "loads' (§4.2, PI)",
            f"below {FIG18_FREQ_HZ:g} Hz no lighter load's PI lag more than "
            f"{LAG_ORDER_TOL_DEG:g} deg above the next heavier one's, and the heaviest at least "
            f"{LAG_ORDER_TOL_DEG:g} deg behind the lightest at some frequency",
            _lag_tends_to_rise, _lag_tends_to_rise_detail,
            f"needs >= 2 loads and a frequency below {FIG18_FREQ_HZ:g} Hz"),
    Finding("lag_order_low_freq_strict", "PI lag smaller at lower load, every pair",
            "(no sentence states it for every pair at every frequency; the earlier "
            "reading of §4.2's 'tends to be smaller')",
            f"below {FIG18_FREQ_HZ:g} Hz the PI phase lag is smaller at lower load, every "
            "pair of loads at every frequency", _lag_rises_with_load,
            _lag_rises_with_load_detail,
            f"needs >= 2 loads and a frequency below {FIG18_FREQ_HZ:g} Hz", counted=False),
    Finding("lag_same_high_freq", "PI lags of the loads within 5 deg from 0.5 Hz",
            "'The phase lag is almost the same in the frequency band above 0.5 Hz' (§4.2, "
            "PI, across loads)",
            f"from {FIG18_FREQ_HZ:g} Hz the PI lags of the loads within {LAG_SAME_DEG:g} deg",
            _lag_same_high, _lag_same_high_detail,
            f"needs >= 2 loads and a frequency from {FIG18_FREQ_HZ:g} Hz"),
    Finding("pid_gain_equals_pi", "PI and PID gains equal at 150 N",
            "'No difference in amplitude gain is observed' (§4.2, PI against PID at 150 N)",
            f"at {FIG18_LOAD_N:g} N the PI and PID gains within {GAIN_LOAD_RTOL:.0%} at each "
            "frequency", _pid_gain_equal, _pid_gain_equal_detail,
            f"needs {FIG18_LOAD_N:g} N and both PI and PID"),
    Finding("pid_leads_pi", "PID lags visibly less than PI at 150 N",
            "'the phase delay is smaller when the PID controller is used' (§4.2, 150 N); "
            "'The phase lag tended to improve with the PID controller' (abstract)",
            f"at {FIG18_LOAD_N:g} N the PID lag nowhere more than {PID_LEAD_MIN_DEG:g} deg "
            f"above PI's, and at least {PID_LEAD_MIN_DEG:g} deg below it at some frequency",
            _pid_leads_pi, _pid_leads_pi_detail,
            f"needs {FIG18_LOAD_N:g} N and both PI and PID"),
    Finding("pid_leads_pi_everywhere", "PID lags >= 1 deg less than PI at every frequency",
            "(no sentence states it at every frequency; the earlier reading of §4.2's PID "
            "sentence)",
            f"at {FIG18_LOAD_N:g} N the PID lag at least {PID_LEAD_MIN_DEG:g} deg below PI's "
            "at every frequency", _pid_leads, _pid_leads_everywhere_detail,
            f"needs {FIG18_LOAD_N:g} N and both PI and PID", counted=False),
    Finding("po_reaches_cap", "Po reaches its cap at 150 N, 0.5 Hz",
            "'the external pressure reaches 0.08 MPa, the highest value set' (§4.2, "
            "Figs. 18-19, 150 N, 0.5 Hz)",
            "Po reaches the {po_cap_mpa:g} MPa cap at "
            f"{FIG18_LOAD_N:g} N, {FIG18_FREQ_HZ:g} Hz (PI)",
            _po_reaches_cap, _po_reaches_cap_detail,
            f"needs the {FIG18_LOAD_N:g} N, {FIG18_FREQ_HZ:g} Hz PI run"),
    Finding("po_cap_light_slow", "Po < 0.07 MPa at 0.1 Hz, 50/100 N",
            "(§4.2 shows the cap only at 150 N, 0.5 Hz)",
            "at the lowest frequency the lighter loads keep Po below "
            f"{PO_SLOW_LIGHT_MAX_FRAC:.3g} of the cap (PI)",
            _po_cap_heavy_fast_only, _po_cap_heavy_fast_only_detail,
            f"needs a frequency below {FIG18_FREQ_HZ:g} Hz and a load below "
            f"{FIG18_LOAD_N:g} N", counted=False),
)
