"""Post-processing of recorded runs: hysteresis-loop areas, sinusoid fits, step averages.

Pure NumPy on arrays; no plotting, no simulation. Functions accept any consistent units
(they return results in the units they are given) unless a docstring says otherwise.

  * `loop_area`            area of a hysteresis loop x(p) (the paper's Table 2).
  * `fit_sinusoid`         least-squares offset, amplitude and phase at a known frequency.
  * `frequency_response`   gain and phase lag of a tracked sinusoid (the paper's Fig. 17).
  * `steady_state_means`   mean of each step plateau after it has settled (Fig. 16).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from wpam_mj.errors import ParameterError, shown

LOOP_AREA_METHODS = ("branches", "shoelace")


def _as_series(name: str, values: npt.ArrayLike, min_len: int = 1) -> np.ndarray:
    arr = np.asarray(values, dtype=float)
    if arr.ndim != 1:
        raise ParameterError(f"{name} must be one-dimensional, got shape {arr.shape}")
    if arr.size < min_len:
        raise ParameterError(f"{name} has {arr.size} samples; at least {min_len} are needed")
    if not np.all(np.isfinite(arr)):
        raise ParameterError(f"{name} contains NaN or infinite values")
    return arr


def _same_length(**arrays: np.ndarray) -> None:
    lengths = {name: a.size for name, a in arrays.items()}
    if len(set(lengths.values())) > 1:
        raise ParameterError("arrays must have the same length; got "
                             + ", ".join(f"{k}: {v}" for k, v in lengths.items()))


# --------------------------------------------------------------------------- loop area


def loop_area(p: npt.ArrayLike, x: npt.ArrayLike, *, method: str = "branches") -> float:
    """Area enclosed by a hysteresis loop traced as the polyline (p[k], x[k]).

    Args:
      p: abscissa samples, shape (n,), n >= 3 (the paper: internal pressure Pi).
      x: ordinate samples, shape (n,) (the paper: contraction x).
      method:
        "branches" (used for Table 2): the loop is a sweep of p up to a turning point and
        back (or down and back up), as in the static experiments. It is split at the
        turning point (the first sample farthest from p[0]) into two branches x_a(p),
        x_b(p); each branch is put in increasing-p order (a stable sort, so noise in p is
        tolerated and vertical runs such as the one at the turning point stay jumps), and
        the area is the integral of |x_b(p) - x_a(p)| dp over the p range both branches
        cover, computed exactly for the piecewise-linear branches (crossings included).
        Every lobe counts positive: a figure-eight loop whose branches cross gives the
        sum of its lobe areas. Resampling the same polyline does not change the result.
        "shoelace": |signed area| of the closed polygon (last point joined to the first).
        Any polyline is accepted, but the lobes of a figure-eight have opposite sign and
        cancel; for a simple (non-crossing) loop it equals "branches".

    Returns:
      The area in p-units times x-units (e.g. Pa m, or MPa mm for display), >= 0.
    """
    p = _as_series("p", p, 3)
    x = _as_series("x", x, 3)
    _same_length(p=p, x=x)
    if method == "shoelace":
        return _shoelace_area(p, x)
    if method == "branches":
        return _branch_area(p, x)
    raise ParameterError(f"unknown loop_area method {method!r}; "
                         f"valid methods: {', '.join(LOOP_AREA_METHODS)}")


def _shoelace_area(p: np.ndarray, x: np.ndarray) -> float:
    # centre first: cancels most of the rounding of large absolute coordinates
    pc, xc = p - p.mean(), x - x.mean()
    return float(0.5 * abs(np.dot(pc, np.roll(xc, -1)) - np.dot(np.roll(pc, -1), xc)))


def _increasing_branch(p: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Branch ordered by non-decreasing p, keeping traversal order among equal p.

    `p` must already run mostly upward (reverse a descending branch first); a stable sort
    then only reorders noise, while a vertical run (equal p, changing x, e.g. the
    turning point) keeps its order and so stays a jump in x(p).
    """
    order = np.argsort(p, kind="stable")
    return p[order], x[order]


def _right_limit(pp: np.ndarray, xx: np.ndarray, q: np.ndarray) -> np.ndarray:
    """x(q+) of the polyline (pp, xx), pp non-decreasing, pp[0] <= q < pp[-1]."""
    i = np.searchsorted(pp, q, side="right") - 1  # last point with pp <= q
    j = np.minimum(i + 1, pp.size - 1)
    span = pp[j] - pp[i]
    w = np.divide(q - pp[i], span, out=np.zeros_like(q), where=span > 0.0)
    return xx[i] + w * (xx[j] - xx[i])


def _left_limit(pp: np.ndarray, xx: np.ndarray, q: np.ndarray) -> np.ndarray:
    """x(q-) of the polyline (pp, xx), pp non-decreasing, pp[0] < q <= pp[-1]."""
    j = np.searchsorted(pp, q, side="left")  # first point with pp >= q
    i = np.maximum(j - 1, 0)
    span = pp[j] - pp[i]
    w = np.divide(pp[j] - q, span, out=np.zeros_like(q), where=span > 0.0)
    return xx[j] + w * (xx[i] - xx[j])


def _branch_area(p: np.ndarray, x: np.ndarray) -> float:
    turn = int(np.argmax(np.abs(p - p[0])))
    if turn == 0 or turn == p.size - 1:
        raise ParameterError("loop_area(method='branches') needs a sweep of p out to a "
                             "turning point and back; p is monotone here (use "
                             "method='shoelace' for a general closed polygon)")
    first, second = (slice(0, turn + 1), slice(turn, None))
    if p[turn] > p[0]:  # up, then down: orient the second branch upward
        pa, xa = _increasing_branch(p[first], x[first])
        pb, xb = _increasing_branch(p[second][::-1], x[second][::-1])
    else:  # down, then up
        pa, xa = _increasing_branch(p[first][::-1], x[first][::-1])
        pb, xb = _increasing_branch(p[second], x[second])
    lo, hi = max(pa[0], pb[0]), min(pa[-1], pb[-1])
    if not hi > lo:
        return 0.0
    grid = np.union1d(pa, pb)
    grid = np.union1d(grid[(grid > lo) & (grid < hi)], [lo, hi])
    # both branches are linear between grid points: integrate |xb - xa| exactly, taking
    # one-sided limits so that vertical runs (jumps) fall between intervals
    d0 = _right_limit(pb, xb, grid[:-1]) - _right_limit(pa, xa, grid[:-1])
    d1 = _left_limit(pb, xb, grid[1:]) - _left_limit(pa, xa, grid[1:])
    return _integral_abs_linear(np.diff(grid), d0, d1)


def _integral_abs_linear(h: np.ndarray, d0: np.ndarray, d1: np.ndarray) -> float:
    """Exact sum of the integrals of |d| over intervals of width h where d runs
    linearly from d0 to d1."""
    a0, a1 = np.abs(d0), np.abs(d1)
    same_sign = d0 * d1 >= 0.0
    trapezoid = 0.5 * (a0 + a1) * h
    # a sign change inside the interval: two triangles meeting at the crossing
    total = a0 + a1
    crossing = np.divide(0.5 * (d0 * d0 + d1 * d1) * h, total,
                         out=np.zeros_like(h), where=total > 0.0)
    return float(np.sum(np.where(same_sign, trapezoid, crossing)))


# ------------------------------------------------------------------- sinusoid fitting


def fit_sinusoid(t: npt.ArrayLike, y: npt.ArrayLike, freq: float) -> tuple[float, float, float]:
    """Least-squares fit of y = offset + amplitude sin(2 pi freq t + phase).

    Solves y = c + a sin(w t) + b cos(w t) (w = 2 pi freq) over all samples given; trim
    the series to whole steady cycles before calling.

    Args:
      t: sample times [s], shape (n,), n >= 3.
      y: samples, shape (n,), any unit.
      freq: frequency [Hz], > 0.

    Returns:
      (offset, amplitude, phase): offset and amplitude (>= 0) in the unit of y; phase
      [rad] in (-pi, pi], referred to t = 0 (not to the first sample).
    """
    t = _as_series("t", t, 3)
    y = _as_series("y", y, 3)
    _same_length(t=t, y=y)
    freq = _positive("freq", freq, "Hz")
    # relative to the first sample: keeps the columns well conditioned for late windows;
    # the phase is shifted back to t = 0 below
    w = 2.0 * math.pi * freq
    tau = t - t[0]
    basis = np.column_stack([np.ones_like(tau), np.sin(w * tau), np.cos(w * tau)])
    (c, a, b), *_ = np.linalg.lstsq(basis, y, rcond=None)
    amplitude = math.hypot(a, b)
    phase = _wrap_rad(math.atan2(b, a) - w * t[0])
    return float(c), amplitude, phase


def _positive(name: str, value: float, unit: str) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ParameterError(f"{name} = {value!r} is not a number") from None
    if not (math.isfinite(v) and v > 0.0):
        raise ParameterError(f"{name} = {value!r} {unit} must be finite and > 0")
    return v


def _wrap_rad(angle: float) -> float:
    """Wrap to (-pi, pi]; within rounding of -pi counts as pi (atan2 of a -0.0 ordinate)."""
    wrapped = math.remainder(angle, 2.0 * math.pi)  # in [-pi, pi]
    return math.pi if wrapped <= -math.pi * (1.0 - 1e-12) else wrapped


@dataclass(frozen=True)
class FrequencyPoint:
    """Response of the contraction to a sinusoidal target at one frequency.

    freq_hz: target frequency [Hz].
    gain: out_amplitude / ref_amplitude [1].
    phase_lag_deg: phase of the target minus phase of the output [deg], in (-180, 180];
      positive when the output lags the target.
    ref_amplitude, out_amplitude: fitted amplitudes, in the unit of the input series.
    """

    freq_hz: float
    gain: float
    phase_lag_deg: float
    ref_amplitude: float
    out_amplitude: float


def frequency_response(t: npt.ArrayLike, x_ref: npt.ArrayLike, x: npt.ArrayLike,
                       freq: float, *, settle_cycles: int, n_cycles: int) -> FrequencyPoint:
    """Gain and phase lag of x following a sinusoidal target x_ref of frequency `freq`.

    Uses the `n_cycles` whole cycles that start `settle_cycles` cycles after t[0], i.e.
    the samples with t[0] + settle_cycles / freq <= t < t[0] + (settle_cycles +
    n_cycles) / freq, and fits both signals at `freq` (`fit_sinusoid`).

    Args:
      t: sample times [s], shape (n,), increasing.
      x_ref: target, shape (n,); x: output, shape (n,), same unit as x_ref.
      freq: target frequency [Hz].
      settle_cycles: cycles skipped as transient, >= 0.
      n_cycles: cycles analysed, >= 1.
    """
    t = _as_series("t", t)
    x_ref = _as_series("x_ref", x_ref)
    x = _as_series("x", x)
    _same_length(t=t, x_ref=x_ref, x=x)
    freq = _positive("freq", freq, "Hz")
    if int(settle_cycles) != settle_cycles or settle_cycles < 0:
        raise ParameterError(f"settle_cycles = {shown(settle_cycles)} must be an integer >= 0")
    if int(n_cycles) != n_cycles or n_cycles < 1:
        raise ParameterError(f"n_cycles = {shown(n_cycles)} must be an integer >= 1")
    if np.any(np.diff(t) <= 0.0):
        raise ParameterError("t must be strictly increasing")
    period = 1.0 / freq
    t0 = t[0] + settle_cycles * period
    t1 = t0 + n_cycles * period
    eps = 1e-9 * max(period, abs(t1))
    spacing = float(np.median(np.diff(t))) if t.size > 1 else 0.0
    if t[-1] + spacing < t1 - eps:  # the last sample of a whole cycle is at t1 - spacing
        raise ParameterError(
            f"the series ends at t = {t[-1]:g} s but {settle_cycles} settling + {n_cycles} "
            f"analysed cycles at {freq:g} Hz need data up to t = {t1:g} s")
    window = (t >= t0 - eps) & (t < t1 - eps)
    if np.count_nonzero(window) < 3:
        raise ParameterError(f"only {np.count_nonzero(window)} samples in the analysed "
                             "cycles; sample faster or analyse more cycles")
    _, ref_amp, ref_phase = fit_sinusoid(t[window], x_ref[window], freq)
    _, out_amp, out_phase = fit_sinusoid(t[window], x[window], freq)
    if ref_amp <= 1e-12 * float(np.abs(x_ref[window]).max()):
        raise ParameterError(f"x_ref has no component at {freq:g} Hz in the analysed cycles")
    lag = math.degrees(_wrap_rad(ref_phase - out_phase))
    return FrequencyPoint(freq_hz=freq, gain=out_amp / ref_amp, phase_lag_deg=lag,
                          ref_amplitude=ref_amp, out_amplitude=out_amp)


# ----------------------------------------------------------------- step plateaus


def steady_state_means(t: npt.ArrayLike, x: npt.ArrayLike, segments: npt.ArrayLike,
                       settle: float) -> np.ndarray:
    """Mean of x over the last `settle` seconds of each plateau.

    Args:
      t: sample times [s], shape (n,), increasing.
      x: samples, shape (n,), any unit.
      segments: plateau spans [s], shape (m, 2): plateau i is [t0_i, t1_i).
      settle: averaging window [s], 0 < settle <= t1_i - t0_i; plateau i is averaged
        over t1_i - settle <= t < t1_i.

    Returns:
      Means, shape (m,), in the unit of x.
    """
    t = _as_series("t", t)
    x = _as_series("x", x)
    _same_length(t=t, x=x)
    seg = np.asarray(segments, dtype=float)
    if seg.ndim != 2 or seg.shape[1] != 2:
        raise ParameterError(f"segments must have shape (m, 2), got {seg.shape}")
    if not np.all(np.isfinite(seg)):
        raise ParameterError("segments contain NaN or infinite values")
    settle = _positive("settle", settle, "s")
    means = np.empty(seg.shape[0])
    for i, (t0, t1) in enumerate(seg):
        if settle > t1 - t0 + 1e-9 * max(abs(t1), 1.0):
            raise ParameterError(f"settle = {settle:g} s is longer than plateau {i} "
                                 f"[{t0:g}, {t1:g}) s")
        eps = 1e-9 * max(abs(t1), 1.0)
        window = (t >= t1 - settle - eps) & (t < t1 - eps)
        if not np.any(window):
            raise ParameterError(f"no samples in the last {settle:g} s of plateau {i} "
                                 f"[{t0:g}, {t1:g}) s")
        means[i] = x[window].mean()
    return means
