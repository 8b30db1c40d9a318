"""The paper's findings, each written once as signed margins, and their checks.

Each finding is a function from a study's result to `Margin`s: one signed distance per
place it can be checked (a load, a frequency, a controller), >= 0 where it holds.
`wpam reproduce` prints PASS/FAIL from them (`Check`), calibration uses the same margins
as its residuals (`residuals`) and the global search as its map's coordinates, so none of
them can disagree about what the paper says or how closely we must match it. Findings are
looked up by name (`FINDINGS`), never by position.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable, Sequence

import numpy as np

from wpam_mj.paper import (CALIBRATION_HEADROOM, FEEDBACK_150_OVER_100_MIN, FEEDBACK_MAX,
                           FIG18_FREQ_HZ, FIG18_LOAD_N, GAIN_LOAD_RTOL, GAIN_RISE_TOL,
                           LAG_FALL_TOL_DEG, PO_CAP_RTOL, PO_DOWN_STATIC_MPA,
                           PO_SLOW_LIGHT_MAX_FRAC, TABLE2_PO_RTOL)
from wpam_mj.experiments.feasibility import MOVE_MIN_MM
from wpam_mj.units import MM, MPA

# ---- margins and checks


@dataclass(frozen=True)
class Margin:
    """One place a finding is checked: `value` against `limit` in the same unit.

    sense = +1: holds when value >= limit; -1: when value <= limit. `margin` is the
    signed distance (>= 0 holds); `scale` is the size of a clear miss in that unit (the
    calibration residual's unit). load [N], freq [Hz], controller: where it was checked.
    """

    value: float
    limit: float
    sense: int
    scale: float
    load: float | None = None
    freq: float | None = None
    controller: str | None = None

    @property
    def margin(self) -> float:
        return self.sense * (self.value - self.limit)


@dataclass(frozen=True)
class Finding:
    """A finding of the paper: its `name` (how code and files refer to it), `text`
    (formatted with the simulated po_cap_mpa) and `short` label, its
    `margins(result, po_cap)` (None when the result lacks the data, said by `needs`),
    and `detail(result, po_cap, margins)`, the numbers a reader checks it by."""

    name: str
    short: str
    text: str
    margins: Callable[[Any, float], list[Margin] | None]
    detail: Callable[[Any, float, list[Margin]], str]
    needs: str


@dataclass(frozen=True)
class Check:
    """A finding checked on a result: passed is None when the data are missing.
    `name` is the finding's, `finding` its text."""

    name: str
    finding: str
    passed: bool | None
    detail: str
    margins: tuple[Margin, ...] = ()

    @property
    def verdict(self) -> str:
        return {True: "PASS", False: "FAIL", None: "n/a"}[self.passed]

    @property
    def worst_margin(self) -> float:
        """The smallest margin in units of its scale (>= 0 holds; nan: not checked)."""
        return min((m.margin / m.scale for m in self.margins), default=math.nan)


def check(finding: Finding, result, po_cap: float) -> Check:
    """Evaluate one finding on a study result (po_cap: the simulated Po cap [Pa])."""
    text = finding.text.format(po_cap_mpa=po_cap / MPA)
    margins = finding.margins(result, po_cap)
    if margins is None:
        return Check(finding.name, text, None, finding.needs)
    return Check(finding.name, text, all(m.margin >= 0.0 for m in margins),
                 finding.detail(result, po_cap, margins), tuple(margins))


def check_all(findings: Sequence[Finding], result, po_cap: float) -> list[Check]:
    return [check(f, result, po_cap) for f in findings]


def residuals(checks: Sequence[Check]) -> np.ndarray:
    """Calibration residuals of checked findings: one per margin, 0 where it holds with
    CALIBRATION_HEADROOM to spare, else the shortfall in units of the margin's scale."""
    return np.array([max(0.0, CALIBRATION_HEADROOM - m.margin / m.scale)
                     for c in checks for m in c.margins])


# ---- §4.2, the frequency response (on a `wpam_mj.experiments.responses.SweepResult`)


def _falls_and_grows(sw, po_cap):
    if len(sw.freqs) < 2:
        return None
    out = []
    for load in sw.loads:
        for c in sw.controllers:
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
    return out


def _falls_and_grows_detail(sw, po_cap, margins):
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


def _gain_spread(sw, po_cap):
    if len(sw.loads) < 2:
        return None
    out = []
    for c in sw.controllers:
        for f in sw.freqs:
            g = [p.gain for p in sw.points if p.controller == c and p.freq == f]
            if len(g) >= 2:
                out.append(Margin(max(g) / max(min(g), _resolved_gain(sw)) - 1.0,
                                  GAIN_LOAD_RTOL, -1, 0.1, freq=f, controller=c))
    return out


def _gain_spread_detail(sw, po_cap, margins):
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
            f"{at.freq:g} Hz{note})")


def _low_lags(sw, f, c):
    return [sw.point(load, f, c).phase_lag_deg for load in sw.loads]


def _lag_rises_with_load(sw, po_cap):
    low = [f for f in sw.freqs if f < FIG18_FREQ_HZ]
    if len(sw.loads) < 2 or not low:
        return None
    out = []
    for c in sw.controllers:
        for f in low:
            lags = _low_lags(sw, f, c)
            for load, a, b in zip(sw.loads[1:], lags, lags[1:]):
                out.append(Margin(b - a, 0.0, +1, 10.0, load=load, freq=f, controller=c))
    return out


def _lag_rises_with_load_detail(sw, po_cap, margins):
    bad = list(dict.fromkeys((m.controller, m.freq) for m in margins if m.margin < 0.0))
    if not bad:
        return (f"lag increases with load at every f < {FIG18_FREQ_HZ:g} Hz "
                f"({', '.join(sw.controllers)})")
    return "lags [deg] by increasing load out of order at " + "; ".join(
        f"{c.upper()} {f:g} Hz: " + "/".join(f"{v:.1f}" for v in _low_lags(sw, f, c))
        for c, f in bad)


def _pid_leads_pi(sw, po_cap):
    if FIG18_LOAD_N not in sw.loads or not {"pi", "pid"} <= set(sw.controllers):
        return None
    pi, pid = sw.curve(FIG18_LOAD_N, "pi"), sw.curve(FIG18_LOAD_N, "pid")
    return [Margin(a.phase_lag_deg - b.phase_lag_deg, 0.0, +1, 10.0, load=FIG18_LOAD_N,
                   freq=a.freq) for a, b in zip(pi, pid)]


def _pid_leads_pi_detail(sw, po_cap, margins):
    m, f = min((m.value, m.freq) for m in margins)
    return f"smallest PI - PID lag {m:+.2f} deg (at {f:g} Hz)"


def _po_reaches_cap(sw, po_cap):
    p = sw.point(FIG18_LOAD_N, FIG18_FREQ_HZ, "pi")
    if p is None:
        return None
    return [Margin(p.po_max, (1.0 - PO_CAP_RTOL) * po_cap, +1, 0.1 * po_cap,
                   load=FIG18_LOAD_N, freq=FIG18_FREQ_HZ, controller="pi")]


def _po_reaches_cap_detail(sw, po_cap, margins):
    p = sw.point(FIG18_LOAD_N, FIG18_FREQ_HZ, "pi")
    return (f"regulator-gauge Po max {p.po_max / MPA:.4f} MPa "
            f"(pass: >= {margins[0].limit / MPA:.4f} MPa); "
            f"chamber Po max {p.po_chamber_max / MPA:.4f} MPa")


def _po_cap_heavy_fast_only(sw, po_cap):
    f = min(sw.freqs)
    light = [load for load in sw.loads if load < FIG18_LOAD_N]
    points = [(load, sw.point(load, f, "pi")) for load in light]
    if f >= FIG18_FREQ_HZ or not points or any(p is None for _, p in points):
        return None
    return [Margin(p.po_max, PO_SLOW_LIGHT_MAX_FRAC * po_cap, -1, 0.1 * po_cap, load=load,
                   freq=f, controller="pi") for load, p in points]


def _po_cap_heavy_fast_only_detail(sw, po_cap, margins):
    return ", ".join(f"{m.load:g} N at {m.freq:g} Hz: Po max {m.value / MPA:.4f} MPa"
                     for m in margins) + f" (pass: < {margins[0].limit / MPA:.4f} MPa)"


SWEEP_FINDINGS = (
    Finding("gain_falls_lag_grows", "gain falls, lag grows with frequency",
            "gain falls and phase lag grows with frequency (every load and controller)",
            _falls_and_grows, _falls_and_grows_detail, "needs >= 2 frequencies"),
    Finding("gain_spread", "gains of the loads within 5 %",
            f"gains of the loads within {GAIN_LOAD_RTOL:.0%} at each frequency",
            _gain_spread, _gain_spread_detail, "needs >= 2 loads"),
    Finding("lag_order_low_freq", "lag smaller at lower load below 0.5 Hz",
            f"below {FIG18_FREQ_HZ:g} Hz the phase lag is smaller at lower load",
            _lag_rises_with_load, _lag_rises_with_load_detail,
            f"needs >= 2 loads and a frequency below {FIG18_FREQ_HZ:g} Hz"),
    Finding("pid_leads_pi", "PID lag < PI lag at 150 N",
            f"PID lag < PI lag at {FIG18_LOAD_N:g} N at every frequency",
            _pid_leads_pi, _pid_leads_pi_detail,
            f"needs {FIG18_LOAD_N:g} N and both PI and PID"),
    Finding("po_reaches_cap", "Po reaches its cap at 150 N, 0.5 Hz",
            "Po reaches the {po_cap_mpa:g} MPa cap at "
            f"{FIG18_LOAD_N:g} N, {FIG18_FREQ_HZ:g} Hz (PI)",
            _po_reaches_cap, _po_reaches_cap_detail,
            f"needs the {FIG18_LOAD_N:g} N, {FIG18_FREQ_HZ:g} Hz PI run"),
    Finding("po_cap_light_slow", "Po < 0.07 MPa at 0.1 Hz, 50/100 N",
            "the cap is the heavy, fast case's limit: at the lowest frequency the lighter "
            f"loads keep Po below {PO_SLOW_LIGHT_MAX_FRAC:.3g} of the cap (PI)",
            _po_cap_heavy_fast_only, _po_cap_heavy_fast_only_detail,
            f"needs a frequency below {FIG18_FREQ_HZ:g} Hz and a load below "
            f"{FIG18_LOAD_N:g} N"),
)


# ---- Table 2 (on a `wpam_mj.experiments.responses.Table2Result`)


def _po_row_errors(t2) -> dict[float, float]:
    paper = t2.paper()["open_po"]
    return {load: t2.open_po[load] / paper[load] - 1.0 for load in t2.loads if load in paper}


def _po_row(t2, po_cap):
    errs = _po_row_errors(t2)
    return [Margin(abs(e), TABLE2_PO_RTOL, -1, 0.1, load=load)
            for load, e in errs.items()] or None


def _po_row_detail(t2, po_cap, margins):
    paper = t2.paper()["open_po"]
    return ", ".join(f"{load:g} N: {t2.open_po[load]:.4f} vs {paper[load]:.4f} ({e:+.1%})"
                     for load, e in _po_row_errors(t2).items())


def _feedback_row(t2, po_cap):
    fb = [t2.feedback[load] for load in t2.loads]
    ratio = ([Margin(t2.feedback[150.0] / t2.feedback[100.0], FEEDBACK_150_OVER_100_MIN, +1,
                     1.0, load=150.0)]
             if {100.0, 150.0} <= set(t2.loads) and t2.feedback[100.0] > 0.0 else [])
    return ([Margin(v, FEEDBACK_MAX, -1, 0.01, load=load) for load, v in zip(t2.loads, fb)]
            + [Margin(b - a, 0.0, +1, 0.01, load=load)
               for load, a, b in zip(t2.loads[1:], fb, fb[1:])] + ratio)


def _feedback_row_detail(t2, po_cap, margins):
    return ", ".join(f"{load:g} N: {t2.feedback[load]:.4f}" for load in t2.loads)


def plateau_error_limit(t2) -> dict[float, float]:
    """Per load [N], the settled PI plateau error [m] that Table 2's feedback-row limit
    allows (§4.1, Fig. 16): the closed-loop loop is the plateau means (Pi, x), so a split
    of delta between the way up and the way down over its Pi span dPi encloses about
    delta dPi; below FEEDBACK_MAX of the open-loop area A_open that is
    delta <= FEEDBACK_MAX A_open / dPi. At 150 N the paper's own cell (0.0170) sits just
    under this limit, so the paper's plateaus differ by nearly as much."""
    out = {}
    for o, f in zip(t2.open_loops, t2.feedback_runs):
        span = float(np.ptp(f.pi_mean))
        out[o.load] = FEEDBACK_MAX * o.area / span if span > 0.0 else math.inf
    return out


TABLE2_FINDINGS = (
    Finding("table2_po_row", "Table 2 'Po = 0.04' row within 15 %",
            f"Table 2 'Po = {PO_DOWN_STATIC_MPA:g} MPa' row within {TABLE2_PO_RTOL:.0%} "
            "of the paper", _po_row, _po_row_detail, "no paper loads"),
    Finding("table2_feedback_row", "Table 2 feedback row < 0.02, ordered, 150 N >= 3x",
            f"Table 2 feedback row < {FEEDBACK_MAX}, increasing with load, 150 N >= "
            f"{FEEDBACK_150_OVER_100_MIN:g}x 100 N",
            _feedback_row, _feedback_row_detail, ""),
)


def sweep_checks(sw, po_cap: float) -> list[Check]:
    """The §4.2 findings on a `wpam_mj.experiments.responses.SweepResult` (po_cap [Pa])."""
    return check_all(SWEEP_FINDINGS, sw, po_cap)


def table2_checks(t2) -> list[Check]:
    """The Table 2 targets on a `wpam_mj.experiments.responses.Table2Result`."""
    return check_all(TABLE2_FINDINGS, t2, math.nan)

# Every finding by name: code and files refer to findings this way, never by position.
FINDINGS = {f.name: f for f in (*TABLE2_FINDINGS, *SWEEP_FINDINGS)}


def checks_text(checks: Sequence[Check]) -> str:
    """One line per check: verdict, finding, worst margin (scale units), our numbers."""
    return "\n".join(f"[{c.verdict}] {c.finding} (margin {c.worst_margin:+.3f}): {c.detail}"
                     for c in checks)


def checks_markdown(checks: Sequence[Check]) -> str:
    """The checks as a Markdown table (the report's)."""
    lines = ["| finding (paper) | result | worst margin (scale units, >= 0 holds) | our numbers |",
             "|---|---|---|---|"]
    for c in checks:
        lines.append(f"| {c.finding} | **{c.verdict}** | {c.worst_margin:+.3f} | {c.detail} |")
    return "\n".join(lines)
