"""Tests of wpam_mj.experiments.analysis on loops and signals whose answer is known in
closed form."""

from __future__ import annotations

import math

import numpy as np
import pytest

from wpam_mj.experiments.analysis import (FrequencyPoint, fit_sinusoid, frequency_response,
                                          loop_area, steady_state_means)
from wpam_mj.errors import ParameterError


def polyline(vertices, points_per_edge):
    """Sample the open polyline through `vertices` with `points_per_edge` points per edge.

    Returns (p, x), each shape (n,); the last vertex is included once.
    """
    v = np.asarray(vertices, dtype=float)
    pieces = []
    for a, b in zip(v[:-1], v[1:]):
        s = np.linspace(0.0, 1.0, points_per_edge, endpoint=False)[:, None]
        pieces.append(a + s * (b - a))
    pieces.append(v[-1:])
    pts = np.vstack(pieces)
    return pts[:, 0], pts[:, 1]


# Up along x = 0 from p = 0 to 1, up the edge p = 1 to x = 2, back along x = 2.
RECTANGLE = [(0, 0), (1, 0), (1, 2), (0, 2)]
RECTANGLE_AREA = 2.0
# A ramp loop: contraction starts at p = 1 on the way up, ends at p = 0 on the way down.
PARALLELOGRAM = [(0, 0), (1, 0), (3, 2), (2, 2), (0, 0)]
PARALLELOGRAM_AREA = 2.0  # base 1 (along p) times height 2 (along x)
# Crossing branches: up along x = p to (3, 3), drop to (3, 2.5), back down to (0, 2).
# They cross at (2.4, 2.4): lobe 1 is the triangle (0,0) (2.4,2.4) (0,2), area 2.4;
# lobe 2 is the triangle (2.4,2.4) (3,3) (3,2.5), area 0.15.
FIGURE_EIGHT = [(0, 0), (3, 3), (3, 2.5), (0, 2)]
FIGURE_EIGHT_LOBES = (2.4, 0.15)


@pytest.mark.parametrize("vertices, area", [(RECTANGLE, RECTANGLE_AREA),
                                            (PARALLELOGRAM, PARALLELOGRAM_AREA)])
@pytest.mark.parametrize("method", ["branches", "shoelace"])
def test_loop_area_of_simple_loops(vertices, area, method):
    p, x = polyline(vertices, 7)
    assert loop_area(p, x, method=method) == pytest.approx(area, rel=1e-12)


def test_loop_area_figure_eight_sums_the_lobes():
    p, x = polyline(FIGURE_EIGHT, 11)
    assert loop_area(p, x) == pytest.approx(sum(FIGURE_EIGHT_LOBES), rel=1e-12)
    # the polygon (shoelace) area is the signed difference of the lobes
    assert loop_area(p, x, method="shoelace") == pytest.approx(
        FIGURE_EIGHT_LOBES[0] - FIGURE_EIGHT_LOBES[1], rel=1e-12)


@pytest.mark.parametrize("vertices, area", [(RECTANGLE, RECTANGLE_AREA),
                                            (PARALLELOGRAM, PARALLELOGRAM_AREA),
                                            (FIGURE_EIGHT, sum(FIGURE_EIGHT_LOBES))])
def test_loop_area_does_not_depend_on_sampling(vertices, area):
    for n in (1, 2, 10, 1000):
        p, x = polyline(vertices, n)
        assert loop_area(p, x) == pytest.approx(area, rel=1e-12), f"{n} points per edge"
    # irregular sampling along the same polyline
    rng = np.random.default_rng(3)
    p, x = polyline(vertices, 200)
    keep = np.sort(rng.choice(np.arange(1, p.size - 1), size=150, replace=False))
    keep = np.concatenate([[0], keep, [p.size - 1]])
    vertex_idx = np.arange(0, p.size, 200)  # keep the corners
    keep = np.union1d(keep, vertex_idx)
    assert loop_area(p[keep], x[keep]) == pytest.approx(area, rel=1e-12)


def test_loop_area_traversal_direction_and_offsets():
    p, x = polyline(PARALLELOGRAM, 5)
    assert loop_area(p[::-1], x[::-1]) == pytest.approx(PARALLELOGRAM_AREA, rel=1e-12)
    # starting at the top: down, then back up
    down_up = [(3, 2), (2, 2), (0, 0), (1, 0), (3, 2)]
    assert loop_area(*polyline(down_up, 5)) == pytest.approx(PARALLELOGRAM_AREA, rel=1e-12)
    # units scale, offsets do not matter (e.g. Pa m -> MPa mm)
    assert loop_area(1e6 * p + 5e4, 1e-3 * x + 0.02) == pytest.approx(
        PARALLELOGRAM_AREA * 1e3, rel=1e-9)


def test_loop_area_of_a_noisy_ramp_loop():
    """Measured pressures jitter: a branch that is not monotone in p still gives the area."""
    rng = np.random.default_rng(0)
    p, x = polyline(PARALLELOGRAM, 2000)
    p_noisy = p + rng.normal(0.0, 0.002, p.size)  # 0.1 % of the span
    assert loop_area(p_noisy, x) == pytest.approx(PARALLELOGRAM_AREA, rel=0.01)


def test_loop_area_of_a_branch_retraced_is_zero():
    up = np.linspace(0, 1, 50) ** 0.5
    p = np.concatenate([up, up[-2::-1]])
    x = p ** 2
    assert loop_area(p, x) == pytest.approx(0.0, abs=1e-15)


@pytest.mark.parametrize("p, x, match", [
    ([0, 1, 0, 1], [0, 1, 0], "same length"),
    ([0, 1], [0, 1], "at least 3"),
    ([0, np.nan, 0], [0, 1, 0], "NaN"),
    ([0, 1, 0], [0, np.inf, 0], "NaN or infinite"),
    ([0, 1, 2], [0, 1, 2], "turning point"),
])
def test_loop_area_rejects_bad_input(p, x, match):
    with pytest.raises(ParameterError, match=match):
        loop_area(p, x)


def test_loop_area_rejects_unknown_method():
    with pytest.raises(ParameterError, match="valid methods: branches, shoelace"):
        loop_area([0, 1, 0], [0, 1, 0], method="green")


# ------------------------------------------------------------------ sinusoids


def test_fit_sinusoid_recovers_offset_amplitude_phase():
    t = np.arange(0.0, 10.0, 0.01)
    f, phase = 0.25, -1.1
    y = 3.0 + 2.0 * np.sin(2 * np.pi * f * t + phase)
    c, a, ph = fit_sinusoid(t, y, f)
    assert (c, a, ph) == pytest.approx((3.0, 2.0, phase), abs=1e-12)
    # a late window gives the phase referred to t = 0, not to the window start
    late = t >= 6.3
    assert fit_sinusoid(t[late], y[late], f) == pytest.approx((3.0, 2.0, phase), abs=1e-9)


def test_fit_sinusoid_amplitude_positive_phase_in_range():
    t = np.arange(0.0, 4.0, 0.01)
    _, a, ph = fit_sinusoid(t, -3.0 * np.sin(2 * np.pi * t), 1.0)
    assert a == pytest.approx(3.0, rel=1e-12)
    assert ph == pytest.approx(math.pi, abs=1e-12)
    assert -math.pi < ph <= math.pi


def synthetic_tracking(freq, gain, lag_deg, *, noise, t_end, seed=1, dt=0.01):
    """Target 25 mm sinusoid about 30 mm and an output with known gain and lag [m]."""
    t = np.arange(0.0, t_end, dt)
    w = 2 * np.pi * freq
    x_ref = 0.030 + 0.025 * np.sin(w * t)
    x = 0.031 + gain * 0.025 * np.sin(w * t - np.radians(lag_deg))
    x = x + np.random.default_rng(seed).normal(0.0, noise, t.size)
    return t, x_ref, x


def test_frequency_response_recovers_gain_and_lag_in_noise():
    # 0.5 mm rms noise on a 20 mm output amplitude, 8 cycles of 200 samples
    t, x_ref, x = synthetic_tracking(0.5, 0.8, 30.0, noise=0.5e-3, t_end=22.0)
    fr = frequency_response(t, x_ref, x, 0.5, settle_cycles=2, n_cycles=8)
    assert isinstance(fr, FrequencyPoint)
    assert fr.freq_hz == 0.5
    assert fr.gain == pytest.approx(0.8, rel=0.01), "amplitude gain"
    assert fr.phase_lag_deg == pytest.approx(30.0, abs=0.5), "phase lag [deg]"
    assert fr.ref_amplitude == pytest.approx(0.025, rel=1e-9)
    assert fr.out_amplitude == pytest.approx(0.02, rel=0.01)


def test_frequency_response_ignores_settling_cycles():
    t, x_ref, x = synthetic_tracking(0.2, 0.9, 60.0, noise=0.0, t_end=30.0)
    x = x + np.where(t < 10.0, 0.01 * np.exp(-t), 0.0)  # transient within 2 cycles
    fr = frequency_response(t, x_ref, x, 0.2, settle_cycles=2, n_cycles=4)
    assert fr.gain == pytest.approx(0.9, rel=1e-9)
    assert fr.phase_lag_deg == pytest.approx(60.0, abs=1e-7)


def test_frequency_response_wraps_lag_and_reports_lead():
    t, x_ref, x = synthetic_tracking(1.0, 1.0, 200.0, noise=0.0, t_end=5.0)
    fr = frequency_response(t, x_ref, x, 1.0, settle_cycles=1, n_cycles=3)
    assert fr.phase_lag_deg == pytest.approx(-160.0, abs=1e-7)  # a 160 deg lead
    t, x_ref, x = synthetic_tracking(1.0, 1.0, -10.0, noise=0.0, t_end=5.0)
    fr = frequency_response(t, x_ref, x, 1.0, settle_cycles=1, n_cycles=3)
    assert fr.phase_lag_deg == pytest.approx(-10.0, abs=1e-7)


def test_frequency_response_rejects_bad_input():
    t, x_ref, x = synthetic_tracking(0.5, 1.0, 0.0, noise=0.0, t_end=10.0)
    with pytest.raises(ParameterError, match="need data up to t = 12"):
        frequency_response(t, x_ref, x, 0.5, settle_cycles=2, n_cycles=4)
    with pytest.raises(ParameterError, match="freq"):
        frequency_response(t, x_ref, x, 0.0, settle_cycles=0, n_cycles=1)
    with pytest.raises(ParameterError, match="n_cycles"):
        frequency_response(t, x_ref, x, 0.5, settle_cycles=0, n_cycles=0)
    with pytest.raises(ParameterError, match="settle_cycles"):
        frequency_response(t, x_ref, x, 0.5, settle_cycles=-1, n_cycles=1)
    with pytest.raises(ParameterError, match="same length"):
        frequency_response(t, x_ref[:-1], x, 0.5, settle_cycles=0, n_cycles=1)
    with pytest.raises(ParameterError, match="NaN"):
        frequency_response(t, np.full_like(t, np.nan), x, 0.5, settle_cycles=0, n_cycles=1)
    with pytest.raises(ParameterError, match="no component"):
        frequency_response(t, np.zeros_like(t), x, 0.5, settle_cycles=0, n_cycles=1)


# ------------------------------------------------------------------ plateaus


def test_steady_state_means_average_the_settled_end_of_each_plateau():
    dt = 0.01
    t = np.arange(0.0, 30.0, dt)
    levels = np.array([0.0, 0.010, 0.020])
    segments = np.array([[0.0, 10.0], [10.0, 20.0], [20.0, 30.0]])
    rng = np.random.default_rng(7)
    x = np.empty_like(t)
    prev = 0.0
    for (t0, t1), level in zip(segments, levels):
        w = (t >= t0) & (t < t1)
        x[w] = level + (prev - level) * np.exp(-(t[w] - t0) / 0.5)  # settles in ~3 s
        prev = level
    x += rng.normal(0.0, 1e-5, t.size)
    means = steady_state_means(t, x, segments, settle=2.0)
    assert means.shape == (3,)
    np.testing.assert_allclose(means, levels, atol=5e-6)
    # the window is [t1 - settle, t1): exactly 200 samples here
    ramp = t.copy()
    np.testing.assert_allclose(steady_state_means(t, ramp, segments, settle=2.0),
                               segments[:, 1] - 1.0 - dt / 2, rtol=1e-12)


def test_steady_state_means_rejects_bad_input():
    t = np.arange(0.0, 10.0, 0.1)
    x = np.zeros_like(t)
    with pytest.raises(ParameterError, match="shape"):
        steady_state_means(t, x, [0.0, 10.0], settle=1.0)
    with pytest.raises(ParameterError, match="longer than plateau 0"):
        steady_state_means(t, x, [[0.0, 1.0]], settle=2.0)
    with pytest.raises(ParameterError, match="settle"):
        steady_state_means(t, x, [[0.0, 10.0]], settle=0.0)
    with pytest.raises(ParameterError, match="no samples"):
        steady_state_means(t, x, [[20.0, 30.0]], settle=1.0)
    with pytest.raises(ParameterError, match="same length"):
        steady_state_means(t, x[:-1], [[0.0, 10.0]], settle=1.0)
