"""Figures: no legend covers a curve (each sits outside its axes), the model of Fig. 16
is drawn where the plateaus cannot hide it."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import wpam_mj
from wpam_mj.experiments import figures as plots
from wpam_mj.units import MM, MPA
from wpam_mj.simulation.context import RunContext
from wpam_mj.simulation.results import SimResult
from wpam_mj.experiments.responses import StaticLoop, StepRun

PARAMS = wpam_mj.preset()
LOADS = (50.0, 100.0, 150.0)


def synthetic(load: float, control: str) -> SimResult:
    """A 20 s staircase-like run filling the axes (no simulation)."""
    t = np.arange(0.0, 20.0, 0.01)
    x = 25 * MM * (1 - np.cos(2 * np.pi * t / 20))
    series = {f.name: np.zeros(len(t)) for f in dataclasses.fields(SimResult)}
    series.update(time=t, x=x, x_ref=x, pi=(0.03 + load / 2000) * MPA + x * 1e3,
                  po=np.full(len(t), 0.01 * MPA), context=RunContext(PARAMS, 1e-3, load, control))
    return SimResult(**series)


def step_run(load: float) -> StepRun:
    levels = np.array([0, 10, 20, 30, 40, 50, 40, 30, 20, 10, 0]) * MM
    pi = np.interp(levels, [0, 50 * MM], [(0.02 + load / 4000) * MPA, (0.04 + load / 2000)
                                           * MPA])
    return StepRun(5.0, levels, levels, pi, np.full(len(levels), 5e3),
                   result=synthetic(load, "pi"))


def figures():
    yield plots.static_figure([StaticLoop(0.04 * MPA, 1.0, synthetic(f, "open"))
                               for f in LOADS])
    yield plots.step_figure([synthetic(100.0, "open"), synthetic(100.0, "pi")])
    yield plots.closed_loop_static_figure([step_run(f) for f in LOADS])


@pytest.mark.parametrize("index", range(3))
def test_legends_sit_outside_the_axes(index) -> None:
    fig = list(figures())[index]
    fig.draw_without_rendering()  # lays the figure out
    for ax in fig.axes:
        box, frame = ax.get_legend().get_window_extent(), ax.get_window_extent()
        assert not box.overlaps(frame), f"the legend of {ax.get_ylabel()!r} covers its axes"


def test_fig16_model_is_a_band_wider_than_the_data_it_lies_under() -> None:
    ax = plots.closed_loop_static_figure([step_run(f) for f in LOADS]).axes[0]
    widths = sorted(line.get_linewidth() for line in ax.get_lines() if len(line.get_xdata()))
    assert widths[-len(LOADS):] == [7] * len(LOADS) and widths[-len(LOADS) - 1] < 2
