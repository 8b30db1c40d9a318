"""§4.1's findings: Table 2 and the PI staircases (on a
`wpam_mj.experiments.responses.Table2Result`), and the open-loop staircase of Fig. 12 (on a
`wpam_mj.experiments.responses.StepRun`); each a `margins.Finding` with the paper's words."""

from __future__ import annotations

import math

import numpy as np

from wpam_mj.paper import (FEEDBACK_FACTOR, OPEN_LOOP_GIVE_BACK_MAX, OPEN_LOOP_TURN_S,
                           PO_DOWN_STATIC_MPA, STEP_PP_MM, TABLE2, TABLE2_PO_RTOL)
from wpam_mj.experiments.paper_studies import PLATEAU_SETTLE_S
from wpam_mj.reproduction.margins import Finding, Margin
from wpam_mj.units import MM, MPA


def _po_row_errors(t2) -> dict[float, float]:
    paper = t2.paper()["open_po"]
    return {load: t2.open_po[load] / paper[load] - 1.0 for load in t2.loads if load in paper}


def _po_row(t2):
    errs = _po_row_errors(t2)
    return [Margin(abs(e), TABLE2_PO_RTOL, -1, 0.1, load=load)
            for load, e in errs.items()] or None


def _po_row_detail(t2, margins):
    paper = t2.paper()["open_po"]
    return ", ".join(f"{load:g} N: {t2.open_po[load]:.4f} vs {paper[load]:.4f} ({e:+.1%})"
                     for load, e in _po_row_errors(t2).items())


def _feedback_row(t2):
    """Each cell within FEEDBACK_FACTOR of the paper's: |log(ours / paper)| <= log 2."""
    paper = t2.paper().get("feedback", {})
    out = []
    for load in t2.loads:
        if load in paper:
            ratio = max(t2.feedback[load], 1e-12) / paper[load]
            out.append(Margin(abs(math.log(ratio)), math.log(FEEDBACK_FACTOR), -1, 0.5,
                              load=load))
    return out or None


def _feedback_row_detail(t2, margins):
    paper = t2.paper()["feedback"]
    return ", ".join(f"{load:g} N: {t2.feedback[load]:.4f} vs {paper[load]:.4f} "
                     f"(x{t2.feedback[load] / paper[load]:.2f})"
                     for load in t2.loads if load in paper)


def _shape(t2):
    """Po = 0.04 MPa shrinks every loop, more at heavier loads; the feedback loop is
    smaller still at every load."""
    po, fb = t2.open_po, t2.feedback
    return ([Margin(po[load], 1.0, -1, 0.1, load=load) for load in t2.loads]
            + [Margin(po[b] - po[a], 0.0, -1, 0.1, load=b)
               for a, b in zip(t2.loads, t2.loads[1:])]
            + [Margin(fb[load] - po[load], 0.0, -1, 0.1, load=load) for load in t2.loads])


def _shape_detail(t2, margins):
    return ("Po row " + "/".join(f"{t2.open_po[v]:.4f}" for v in t2.loads)
            + ", feedback row " + "/".join(f"{t2.feedback[v]:.4f}" for v in t2.loads)
            + " (" + "/".join(f"{v:g}" for v in t2.loads) + " N)")


def plateau_error_limit(t2) -> dict[float, float]:
    """Per load [N], the settled PI plateau error [m] that the paper's own Table 2
    feedback cell implies (§4.1, Fig. 16): the closed-loop loop is the plateau means
    (Pi, x), so a split delta between the way up and the way down over its Pi span dPi
    encloses about delta dPi; the paper's cell c of the open-loop area A_open gives
    delta = c A_open / dPi. Loads the paper did not run take its largest cell."""
    cells = TABLE2["feedback"]
    out = {}
    for o, f in zip(t2.open_loops, t2.feedback_runs):
        span = float(np.ptp(f.pi_mean))
        cell = cells.get(o.load, max(cells.values()))
        out[o.load] = cell * o.area / span if span > 0.0 else math.inf
    return out


def _steps_settle(t2):
    limits = plateau_error_limit(t2)
    out = []
    for run in t2.feedback_runs:
        out.append(Margin(run.worst_error(PLATEAU_SETTLE_S), limits[run.load], -1,
                          limits[run.load], load=run.load))
        out.append(Margin(run.worst_peak_to_peak(PLATEAU_SETTLE_S), STEP_PP_MM * MM, -1,
                          STEP_PP_MM * MM, load=run.load))
    return out or None


def _steps_settle_detail(t2, margins):
    err, pp = margins[0::2], margins[1::2]  # per run: its error, then its peak-to-peak
    floors = landing_floors(t2)
    return ("worst settled error " + "/".join(f"{m.value / MM:.2f}" for m in err)
            + " mm against " + "/".join(f"{m.limit / MM:.2f}" for m in err)
            + " mm (Table 2's cells); p-p " + "/".join(f"{m.value / MM:.2f}" for m in pp)
            + f" mm (<= {STEP_PP_MM:g} mm); from where the plateaus landed, no quasi-static "
            "plant (any friction law) gets below "
            + "/".join("-" if math.isnan(v) else f"{v / MM:.2f}" for v in floors.values())
            + " mm (the PI's zero)")


def landing_floors(t2) -> dict[float, float]:
    """Per load [N], the largest `StepRun.landing_floor` of its PI staircase [m]: the least
    worst settled error its landings leave any quasi-static plant (nan if none landed)."""
    out = {}
    for run in t2.feedback_runs:
        floor = run.landing_floor(PLATEAU_SETTLE_S)
        out[run.load] = float(np.nanmax(floor)) if np.isfinite(floor).any() else math.nan
    return out


def decided_at_landing(t2) -> bool:
    """Whether some load's landings alone leave more than `plateau_error_limit` allows."""
    limits = plateau_error_limit(t2)
    return any(floor > limits[load] for load, floor in landing_floors(t2).items())


def _plateau_pressures(t2) -> tuple[list[float], list[float]]:
    """Mean over the plateaus of the PI staircase's chamber Pi and Po, per load [Pa]."""
    return ([float(np.mean(r.pi_mean)) for r in t2.feedback_runs],
            [float(np.mean(r.po_mean)) for r in t2.feedback_runs])


def _pressures_rise(t2):
    if len(t2.loads) < 2:
        return None
    pi, po = _plateau_pressures(t2)
    return [Margin(b - a, 0.0, +1, 0.01 * MPA, load=load)
            for series in (pi, po) for load, a, b in zip(t2.loads[1:], series, series[1:])]


def _pressures_rise_detail(t2, margins):
    pi, po = _plateau_pressures(t2)
    return ("plateau-mean Pi " + "/".join(f"{v / MPA:.4f}" for v in pi) + " MPa, Po "
            + "/".join(f"{v / MPA:.4f}" for v in po) + " MPa ("
            + "/".join(f"{v:g}" for v in t2.loads) + " N)")


TABLE2_FINDINGS = (
    Finding("table2_po_row", "Table 2 'Po = 0.04' row within 15 %",
            "Table 2, open loop with Po = 0.04 MPa: 0.7042 / 0.1899 / 0.0638",
            f"Table 2 'Po = {PO_DOWN_STATIC_MPA:g} MPa' row within {TABLE2_PO_RTOL:.0%} "
            "of the paper", _po_row, _po_row_detail, "no paper loads"),
    Finding("table2_feedback_row", "Table 2 feedback row within x2",
            "Table 2, feedback control: 0.0008 / 0.0019 / 0.0170; 'for F = 150 N, the "
            "hysteresis loop remains slightly' (§4.1)",
            f"each Table 2 feedback cell within a factor of {FEEDBACK_FACTOR:g} of the paper's",
            _feedback_row, _feedback_row_detail, "no paper loads"),
    Finding("table2_shape", "Po shrinks the loop, more when heavier; feedback below",
            "'Figure 16 shows that the hysteresis loop has been eliminated compared to "
            "Figure 8' (§4.1); Table 2's Po row falls with load",
            "Po = 0.04 MPa shrinks the loop at every load, more at heavier loads; the "
            "feedback loop is smaller than it at every load", _shape, _shape_detail,
            "no loads"),
    Finding("steps_settle", "PI steps settle within Table 2's split",
            "'the amount of contraction quickly converges to the target value in both the "
            "extension and contraction directions under each loading condition' (§4.1, "
            "Fig. 14)",
            "each PI plateau's settled error within the split the paper's own feedback cell "
            f"implies, and its x peak-to-peak <= {STEP_PP_MM:g} mm",
            _steps_settle, _steps_settle_detail, "needs the PI staircases"),
    Finding("pressures_rise_with_load", "Pi and Po rise with load",
            "'both internal and external pressures tend to increase with increasing load' "
            "(§4.2; Fig. 15)",
            "the PI staircases' plateau-mean chamber Pi and Po rise with load",
            _pressures_rise, _pressures_rise_detail, "needs >= 2 loads"),
)


def _give_back(run) -> tuple[float, float]:
    """(x at the turn, x given back after it) [m] of an open-loop staircase."""
    r = run.result
    turn = r.time >= OPEN_LOOP_TURN_S
    x_turn = float(r.x[turn][0])
    return x_turn, x_turn - float(r.x[-1])


def _hardly_extends(run):
    if run.control != "open" or run.result.time[-1] <= OPEN_LOOP_TURN_S:
        return None
    x_turn, back = _give_back(run)
    return [Margin(back, OPEN_LOOP_GIVE_BACK_MAX * x_turn, -1, 0.1 * max(x_turn, MM),
                   load=run.load, controller="open")]


def _hardly_extends_detail(run, margins):
    x_turn, back = _give_back(run)
    return (f"{run.load:g} N: x {x_turn / MM:.1f} mm at {OPEN_LOOP_TURN_S:g} s, gives back "
            f"{back / MM:.1f} mm while the target falls 50 mm (pass: <= "
            f"{OPEN_LOOP_GIVE_BACK_MAX:.0%} of it)")


OPEN_STEP_FINDINGS = (
    Finding("open_loop_hardly_extends", "open loop hardly extends after 60 s",
            "'in the case of open loop, extension and contraction behaviors are different. "
            "In particular, after 60 s, the W-PAM is hardly extended' (§4.1, Fig. 12)",
            "open loop at 100 N, Po = 0: from 60 s, while the targets step down to 0, x gives "
            f"back at most {OPEN_LOOP_GIVE_BACK_MAX:.0%} of its contraction",
            _hardly_extends, _hardly_extends_detail, "needs an open-loop staircase"),
)
