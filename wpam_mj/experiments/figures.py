"""Figures of the paper's experiments from the `wpam_mj.experiments.responses` response objects.

Every function returns a `matplotlib.figure.Figure` built without pyplot (no global
state, no display needed; PNG output goes through the Agg renderer). `save_figure`
writes a figure atomically. Display units: mm, MPa, s, Hz, deg.
"""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np
from matplotlib.figure import Figure

from wpam_mj.control.controllers import pi_feedforward
from wpam_mj.experiments.drives import step_targets
from wpam_mj.infra.manifest import png_metadata
from wpam_mj.physics.muscle_types import MUSCLE_TYPES
from wpam_mj.physics.muscle import MuscleModel
from wpam_mj.units import MM, MPA
from wpam_mj.simulation.results import SimResult
from wpam_mj.infra.files import write_atomic
from wpam_mj.paper import TABLE2
from wpam_mj.experiments.responses import StaticLoop, StepRun, SweepResult, Table2Result

DPI = 100
_LOAD_COLOURS = ("tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple",
                 "tab:brown")
_CONTROL_STYLE = {"open": ":", "pi": "-", "pid": "--"}


def save_figure(fig: Figure, path: str | Path, run_id: str | None = None) -> Path:
    """Save `fig` as PNG at `path`, whole or not at all, recording `run_id` (the run's id
    in its manifest, `wpam_mj.infra.manifest`) in the PNG's metadata when given."""
    metadata = None if run_id is None else png_metadata(run_id)
    return write_atomic(path, lambda p: fig.savefig(p, format="png", dpi=DPI,
                                                    metadata=metadata))


def _colour(i: int) -> str:
    return _LOAD_COLOURS[i % len(_LOAD_COLOURS)]


def _load_colours(loads: Sequence[float]) -> dict[float, str]:
    return {load: _colour(i) for i, load in enumerate(sorted(set(loads)))}


# ------------------------------------------------------------------ static loops


def _legend_below(ax) -> None:
    """The legend under the axes, where no curve can be covered (constrained layout
    makes room)."""
    ax.legend(fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.16), frameon=False)


def _legend_right(ax) -> None:
    """The legend right of the axes, where no curve can be covered."""
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False)


def _direction_arrows(ax, p: np.ndarray, x: np.ndarray, colour: str, n: int = 3) -> None:
    """Arrows along each branch of the polyline (p, x) [display units] (paper Figs. 8-9)."""
    turn = int(np.argmax(p))
    for branch in (slice(0, turn + 1), slice(turn, None)):
        bp, bx = p[branch], x[branch]
        if bp.size < 3:
            continue
        # arc length in axis-normalized units, so arrows spread along the visible path
        span_p = max(np.ptp(p), 1e-12)
        span_x = max(np.ptp(x), 1e-12)
        s = np.concatenate([[0.0], np.cumsum(np.hypot(np.diff(bp) / span_p,
                                                      np.diff(bx) / span_x))])
        if s[-1] <= 0.0:
            continue
        for frac in np.arange(1, n + 1) / (n + 1):
            i = int(np.searchsorted(s, frac * s[-1]))
            j = min(i + max(1, bp.size // 50), bp.size - 1)
            i = max(min(i, j - 1), 0)
            if bp[j] == bp[i] and bx[j] == bx[i]:
                continue
            ax.annotate("", xy=(bp[j], bx[j]), xytext=(bp[i], bx[i]),
                        arrowprops=dict(arrowstyle="-|>", color=colour, lw=1.2,
                                        mutation_scale=14))


def static_figure(loops: Sequence[StaticLoop], *, title: str | None = None) -> Figure:
    """x [mm] against measured Pi [MPa] for each loop, arrows for the direction.

    Loops of one preset are coloured by load; several presets (Fig. 3) get one panel
    per load, coloured by preset.
    """
    presets = list(dict.fromkeys(lp.preset for lp in loops))
    loads = sorted({lp.load for lp in loops})
    by_preset = len(presets) > 1
    panels = loads if by_preset else [None]
    fig = Figure(figsize=(5.2 * len(panels), 4.2), layout="constrained")
    axes = fig.subplots(1, len(panels), squeeze=False)[0]
    colours = _load_colours(loads)
    for ax, panel_load in zip(axes, panels):
        for lp in loops:
            if by_preset and lp.load != panel_load:
                continue
            r = lp.result
            p, x = r.pi / MPA, r.x / MM
            colour = (MUSCLE_TYPES[lp.preset].colour if by_preset else colours[lp.load])
            label = (f"{lp.preset}" if by_preset else f"{lp.load:g} N") + \
                f" (area {lp.area_mpa_mm:.3g} MPa mm)"
            dashed = by_preset and lp.preset == "wpam"  # visible over an identical rlam
            ax.plot(p, x, color=colour, lw=1.4, ls="--" if dashed else "-", label=label,
                    zorder=3 if dashed else 2)
            _direction_arrows(ax, p, x, colour)
        ax.set_xlabel("internal pressure Pi [MPa]")
        ax.set_ylabel("contraction x [mm]")
        ax.grid(alpha=0.3)
        _legend_below(ax)
        if by_preset:
            ax.set_title(f"load {panel_load:g} N")
    po = {lp.po_down for lp in loops}
    po_text = ("Po = 0" if po == {0.0} else
               "Po = " + ", ".join(f"{v / MPA:g}" for v in sorted(po)) + " MPa while Pi falls")
    fig.suptitle(title or f"Static characteristic, open loop, {po_text}")
    return fig


# ------------------------------------------------------------------ step runs


def _result_label(r: SimResult, by: str) -> str:
    if by == "load":
        return f"{r.load:g} N"
    return {"open": "open loop", "pi": "PI on Po", "pid": "PID on Po"}.get(r.control,
                                                                           r.control)


def step_figure(results: Sequence[SimResult], *, title: str | None = None) -> Figure:
    """Staircase runs (paper Figs. 12-15): x and target [mm], then Pi and Po [MPa], vs t [s].

    Runs that differ in load are coloured by load; otherwise by controller.
    """
    by = "load" if len({r.load for r in results}) > 1 else "control"
    colours = _load_colours([r.load for r in results])
    ctrl_colours = {"open": "tab:gray", "pi": "tab:blue", "pid": "tab:purple"}
    fig = Figure(figsize=(9.0, 6.4), layout="constrained")
    ax_x, ax_p = fig.subplots(2, 1, sharex=True)
    target_drawn = False
    for r in results:
        colour = colours[r.load] if by == "load" else ctrl_colours.get(r.control, "k")
        label = _result_label(r, by)
        ax_x.plot(r.time, r.x / MM, color=colour, lw=1.3, label=f"x, {label}")
        if np.all(np.isfinite(r.x_ref)) and not target_drawn:
            ax_x.plot(r.time, r.x_ref / MM, color="k", lw=1.0, ls="--", label="target x_r")
            target_drawn = True
        single = len(results) == 1  # one run: Pi red, Po blue
        ax_p.plot(r.time, r.pi / MPA, color="tab:red" if single else colour, lw=1.3,
                  label=f"Pi, {label}")
        ax_p.plot(r.time, r.po / MPA, color="tab:blue" if single else colour, lw=1.1,
                  ls="-" if single else ":", label=f"Po, {label}")
    if not target_drawn:  # open loop only: show the staircase the Pi schedule aims at
        r = results[0]
        ax_x.plot(r.time, step_targets(r.time) / MM, color="k", lw=1.0, ls="--",
                  label="target x_r")
    ax_x.set_ylabel("contraction x [mm]")
    ax_p.set_ylabel("pressure [MPa]")
    ax_p.set_xlabel("time t [s]")
    for ax in (ax_x, ax_p):
        ax.grid(alpha=0.3)
        _legend_right(ax)
    loads = sorted({r.load for r in results})
    fig.suptitle(title or "Step response, load " + ", ".join(f"{v:g}" for v in loads) + " N")
    return fig


def closed_loop_static_figure(runs: Sequence[StepRun]) -> Figure:
    """Plateau means x [mm] against mean chamber Pi [MPa] (paper Fig. 16), beside the
    mechanical-equilibrium model (the Pi feedforward at Po = po_feedforward) of the
    parameters the runs were made with."""
    fig = Figure(figsize=(8.4, 4.6), layout="constrained")
    ax = fig.subplots()
    colours = _load_colours([r.load for r in runs])
    params = runs[0].context.params
    muscle = MuscleModel.from_params(params)
    x_model = np.linspace(0.0, 50.0, 101) * MM
    po_ff = params.controller.po_feedforward
    for run in runs:
        c = colours[run.load]
        p, x = run.pi_mean / MPA, run.x_mean / MM
        turn = int(np.argmax(p))
        ax.plot(p[:turn + 1], x[:turn + 1], "o-", color=c, ms=5, lw=1.2,
                label=f"{run.load:g} N, up (area {run.area / (MPA * MM):.2g} MPa mm)")
        ax.plot(p[turn:], x[turn:], "v--", color=c, ms=5, lw=1.0, mfc="none",
                label=f"{run.load:g} N, down")
        pi_model = pi_feedforward(muscle, params, x_model, run.load, po_ff)
        # a wide pale band under the data: the PI brings the plateaus onto the model, so
        # a thin line would hide beneath them
        ax.plot(pi_model / MPA, x_model / MM, color=c, lw=7, alpha=0.25, zorder=1,
                solid_capstyle="butt")
    ax.plot([], [], color="gray", lw=7, alpha=0.35,
            label=f"model (eq. 5), Po = {po_ff / MPA:g} MPa")
    ax.set_xlabel("mean internal pressure Pi [MPa]")
    ax.set_ylabel("mean contraction x [mm]")
    ax.grid(alpha=0.3)
    _legend_right(ax)
    ax.set_title(f"Closed-loop static characteristic (PI; last {runs[0].settle:g} s "
                 "of each plateau)")
    return fig


# ------------------------------------------------------------------ Table 2


def table2_figure(t2: Table2Result) -> Figure:
    """Normalized loop areas, paper vs simulation, per load (paper Table 2)."""
    fig = Figure(figsize=(9.0, 3.8), layout="constrained")
    ax_po, ax_fb = fig.subplots(1, 2)
    loads = list(t2.loads)
    idx = np.arange(len(loads))
    w = 0.38
    for ax, row, ours, title in ((ax_po, "open_po", t2.open_po,
                                  f"open loop, Po = {t2.po_down / MPA:g} MPa while Pi falls"),
                                 (ax_fb, "feedback", t2.feedback, "PI feedback (Fig. 16)")):
        paper = [TABLE2[row].get(load, np.nan) for load in loads]
        sim = [ours[load] for load in loads]
        b1 = ax.bar(idx - w / 2, paper, w, color="0.6", label="paper")
        b2 = ax.bar(idx + w / 2, sim, w, color="tab:blue", label="simulation")
        ax.bar_label(b1, fmt="%.4f", fontsize=7)
        ax.bar_label(b2, fmt="%.4f", fontsize=7)
        ax.set_xticks(idx, [f"{v:g} N" for v in loads])
        ax.set_ylabel("loop area / open-loop (Po = 0) area [1]")
        ax.set_title(title, fontsize=10)
        ax.grid(axis="y", alpha=0.3)
        ax.legend(fontsize=8)
        ax.margins(y=0.15)
    fig.suptitle("Table 2: hysteresis-loop areas, normalized per load")
    return fig


# ------------------------------------------------------------------ frequency sweep


# The paper's Fig. 17 as its text reads it: it prints no numbers, so there is nothing to plot
# beside ours; the note states what the figure should show.
SWEEP_PAPER_NOTE = ("Paper (Fig. 17, §4.2; qualitative, no numbers given): gain falls and lag "
                    "grows with frequency; gain hardly depends on load;\nbelow 0.5 Hz lag is "
                    "smaller at lower load; PID lags less than PI at 150 N.")


def sweep_figure(sw: SweepResult) -> Figure:
    """Gain [1] and phase lag [deg] against frequency [Hz] per load and controller
    (paper Fig. 17)."""
    fig = Figure(figsize=(7.0, 6.4), layout="constrained")
    ax_g, ax_ph = fig.subplots(2, 1, sharex=True)
    colours = _load_colours(sw.loads)
    for load in sw.loads:
        for ctrl in sw.controllers:
            pts = sw.curve(load, ctrl)
            if not pts:
                continue
            f = [p.freq for p in pts]
            style = dict(color=colours[load], ls=_CONTROL_STYLE.get(ctrl, "-"),
                         marker="o" if ctrl == "pi" else "s", ms=4,
                         label=f"{load:g} N, {ctrl.upper()}")
            ax_g.plot(f, [p.gain for p in pts], **style)
            ax_ph.plot(f, [p.phase_lag_deg for p in pts], **style)
    ax_g.set_ylabel("amplitude gain [1]")
    ax_ph.set_ylabel("phase lag [deg]")
    ax_ph.set_xlabel("frequency [Hz]")
    ax_ph.set_xscale("log")
    ax_ph.set_xticks(sw.freqs, [f"{v:g}" for v in sw.freqs])
    ax_ph.minorticks_off()
    for ax in (ax_g, ax_ph):
        ax.grid(alpha=0.3)
    ax_g.legend(fontsize=8, ncol=2)
    fig.suptitle(f"Frequency response, {sw.amplitude / MM:g} mm amplitude about 25 mm")
    fig.supxlabel(SWEEP_PAPER_NOTE, fontsize=7, style="italic")
    return fig


def sine_figure(r: SimResult, freq: float) -> Figure:
    """One sinusoidal run (paper Figs. 18-19) at `freq` [Hz]: x and target [mm]; Pi and Po
    [MPa] with the run's Po cap drawn as a line."""
    po_cap = r.context.po_cap
    fig = Figure(figsize=(9.0, 6.0), layout="constrained")
    ax_x, ax_p = fig.subplots(2, 1, sharex=True)
    ax_x.plot(r.time, r.x_ref / MM, "k--", lw=1.0, label="target x_r")
    ax_x.plot(r.time, r.x / MM, color="tab:blue", lw=1.4, label="x")
    ax_p.plot(r.time, r.pi_reg / MPA, color="tab:red", lw=1.3, label="Pi (regulator gauge)")
    ax_p.plot(r.time, r.pi / MPA, color="tab:red", lw=0.8, ls="--", label="Pi (chamber)")
    ax_p.plot(r.time, r.po_reg / MPA, color="tab:blue", lw=1.3, label="Po (regulator gauge)")
    ax_p.plot(r.time, r.po / MPA, color="tab:blue", lw=0.8, ls="--", label="Po (chamber)")
    ax_p.axhline(po_cap / MPA, color="k", lw=0.9, ls="--",
                 label=f"Po cap {po_cap / MPA:g} MPa")
    ax_x.set_ylabel("contraction x [mm]")
    ax_p.set_ylabel("pressure [MPa]")
    ax_p.set_xlabel("time t [s]")
    for ax in (ax_x, ax_p):
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8, loc="upper right")
    fig.suptitle(f"Sinusoidal target, {r.load:g} N, {freq:g} Hz, {r.control.upper()}")
    return fig
