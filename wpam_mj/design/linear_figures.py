"""Bode plot of the linear models' G_yr beside the simulated frequency response.

`control.bode_plot` draws the models on a pyplot-free `Figure` (as
`wpam_mj.experiments.figures` does); the simulated gain and lag at each amplitude go on
the same axes as markers. Display units: Hz, gain [1] on a log axis, phase [deg]
(negative = lag).
"""

from __future__ import annotations

import math

import control as ct
import numpy as np
from matplotlib.figure import Figure

from wpam_mj.design.linear_study import LinearComparison
from wpam_mj.units import MM

FREQ_RANGE_HZ = (0.03, 30.0)  # our choice: the paper's 0.1-1 Hz and the loop's crossover
_MODEL_STYLE = {"paper": "-", "extended": "--"}
_CONTROL_COLOUR = {"pi": "tab:blue", "pid": "tab:red"}
_AMPLITUDE_MARKERS = ("o", "s", "^", "v", "D", "x")
GAIN_FLOOR = 1e-3  # simulated gains below it: the load stuck in friction (drawn on the
#                    floor of the gain axis; their phase, and that of any point whose load
#                    never moved, has no meaning and is left out)


def comparison_figure(cmp: LinearComparison) -> Figure:
    """G_yr of each model and controller, and the simulated points at each amplitude."""
    fig = Figure(figsize=(7.5, 7.0), layout="constrained")
    axes = fig.subplots(2, 1, sharex=True)
    omega = 2 * math.pi * np.geomspace(*FREQ_RANGE_HZ, 400)
    for lp in cmp.loops:
        label = f"{'§3' if lp.model == 'paper' else 'extended'} model, {lp.control.upper()}"
        ct.bode_plot(ct.frequency_response(lp.g_yr, omega), ax=axes[:, np.newaxis],
                     Hz=True, deg=True, wrap_phase=False, initial_phase=0.0,
                     color=_CONTROL_COLOUR[lp.control], ls=_MODEL_STYLE[lp.model],
                     label=label + ("" if lp.stable else " (unstable)"), title="")
    ax_g, ax_ph = axes
    for i, (amp, sw) in enumerate(cmp.sweeps.items()):
        for ctrl in sw.controllers:
            pts = sw.curve(cmp.load, ctrl)
            style = dict(color=_CONTROL_COLOUR.get(ctrl, "k"), ls="none", ms=6,
                         marker=_AMPLITUDE_MARKERS[i % len(_AMPLITUDE_MARKERS)],
                         mfc="none" if i else None,
                         label=f"simulated, {ctrl.upper()}, {amp / MM:g} mm")
            freqs = np.array([p.freq for p in pts])
            gains = np.array([p.gain for p in pts])
            moving = (gains >= GAIN_FLOOR) & np.array([p.load_moved for p in pts], dtype=bool)
            ax_g.plot(freqs, np.maximum(gains, GAIN_FLOOR), **style)
            ax_ph.plot(freqs[moving], [-p.phase_lag_deg for p, m in zip(pts, moving) if m],
                       **style)
    ax_g.set_ylim(bottom=0.5 * GAIN_FLOOR)
    ax_g.set_ylabel("gain |G_yr| [1]")
    ax_g.text(0.01, 0.02, f"simulated gains below {GAIN_FLOOR:g} (load stuck) on the floor",
              transform=ax_g.transAxes, fontsize=7)
    ax_ph.set_ylabel("phase [deg]")
    ax_ph.set_xlabel("frequency [Hz]")
    ax_ph.set_ylim(bottom=max(ax_ph.get_ylim()[0], -200.0))
    if ax_g.get_legend() is not None:  # bode_plot's own, of the models only
        ax_g.get_legend().remove()
    handles, labels = ax_g.get_legend_handles_labels()
    fig.legend(handles, labels, fontsize=7, ncol=3, loc="outside lower center")
    fig.suptitle(f"G_yr at {cmp.load:g} N about {cmp.contraction / MM:g} mm: linear models "
                 "and simulation")
    return fig
