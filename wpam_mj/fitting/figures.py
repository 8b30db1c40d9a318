"""Figures of a fit to measured data (`wpam_mj.fitting.measured_fit.FileFit`), without pyplot.

Display units: mm, MPa, s.
"""

from __future__ import annotations

import numpy as np
from matplotlib.figure import Figure

from wpam_mj.units import MM, MPA


def file_fit_figure(ff) -> Figure:
    """Measured and simulated x against time (left) and against the measured Pi (right)."""
    e = ff.experiment
    fig = Figure(figsize=(10, 4), layout="constrained")
    ax_t, ax_p = fig.subplots(1, 2)
    kind = "held out" if ff.held_out else "fitted"
    fig.suptitle(f"{e.name} ({e.load:g} N, {kind}): RMS {ff.rms / MM:.3f} mm")
    ax_t.plot(e.time, e.x / MM, color="0.7", lw=2.0, label="measured")
    ax_t.plot(e.time, ff.x_sim / MM, color="tab:blue", lw=1.0, label="simulated")
    if e.x_ref is not None and np.any(np.isfinite(e.x_ref)):
        ax_t.plot(e.time, e.x_ref / MM, color="k", ls=":", lw=0.8, label="target")
    ax_t.set(xlabel="time [s]", ylabel="contraction x [mm]")
    ax_t.legend(loc="best", fontsize="small")
    ax_p.plot(e.pi / MPA, e.x / MM, color="0.7", lw=2.0, label="measured")
    ax_p.plot(e.pi / MPA, ff.x_sim / MM, color="tab:blue", lw=1.0, label="simulated")
    ax_p.set(xlabel="measured Pi [MPa]", ylabel="contraction x [mm]")
    for ax in (ax_t, ax_p):
        ax.grid(True, alpha=0.3)
    return fig
