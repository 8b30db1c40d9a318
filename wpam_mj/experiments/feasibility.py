"""Runs that cannot mean anything: loads the muscle cannot lift, and loads that never move.

A load is liftable when the contracting-branch equilibrium Pi (paper eq. 5,
`MuscleModel.equilibrium_pressure` with direction +1) at the largest contraction a run
asks for is within the regulator's range with Po = 0 (the most favourable Po: any Po
only lowers the tension). Beyond that load a step run sits 50 mm short of its top target
and a sweep measures a gain of nothing, so the command line refuses it.

A run can still leave the load where it hangs (e.g. a line so restricted that the chamber
never fills): `load_moved` tells, and the commands flag such open-loop runs.
"""

from __future__ import annotations

from typing import Iterable

import numpy as np

from wpam_mj.simulation.context import LOAD_RANGE_N
from wpam_mj.physics.muscle import MuscleModel
from wpam_mj.paper import STEP_LEVELS_MM
from wpam_mj.physics.params import Params
from wpam_mj.errors import ParameterError
from wpam_mj.units import MM, MPA
from wpam_mj.simulation.results import SimResult

TOP_CONTRACTION_MM = float(max(STEP_LEVELS_MM))  # highest target of step runs, ramps and sines
MOVE_MIN_MM = 0.5  # our choice: a load that spans less than this never moved


def max_liftable_load(params: Params, x: float = TOP_CONTRACTION_MM * MM) -> float:
    """The largest load [N] held at contraction `x` [m] on the contracting branch with
    Pi at the regulator maximum and Po = 0; 0 if the braid cannot hold any load there.

    Pi_C is affine in the load (eq. 5: Pi = Po + (F + Kf Fco + A_ax Po + F_f0) / ((Kf - mu) S)),
    so two loads large enough to keep the numerator positive give the line exactly.
    """
    model = MuscleModel.from_params(params)
    lo, hi = LOAD_RANGE_N[1] / 2, LOAD_RANGE_N[1]
    p_lo, p_hi = (model.equilibrium_pressure(x, f, 0.0, +1) for f in (lo, hi))
    if not (np.isfinite(p_lo) and np.isfinite(p_hi)) or p_hi <= p_lo:
        return 0.0
    return max(0.0, lo + (params.pneumatics.p_max - p_lo) * (hi - lo) / (p_hi - p_lo))


def check_liftable(params: Params, loads: Iterable[float], name: str = "load",
                   x: float = TOP_CONTRACTION_MM * MM) -> tuple[float, ...]:
    """`loads` [N] unchanged, or ParameterError naming the first one the muscle cannot
    lift to `x` [m] at the regulator maximum, and the largest it can."""
    loads = tuple(loads)
    limit = max_liftable_load(params, x)
    model = MuscleModel.from_params(params)
    for load in loads:
        if not model.equilibrium_pressure(x, load, 0.0, +1) <= params.pneumatics.p_max:
            allowed = f"the allowed range is [{LOAD_RANGE_N[0]:g}, {limit:.1f}] N" \
                if limit >= LOAD_RANGE_N[0] else \
                f"it lifts no load of [{LOAD_RANGE_N[0]:g}, {LOAD_RANGE_N[1]:g}] N that high"
            raise ParameterError(
                f"{name} = {load:g} N: the {params.preset} muscle cannot lift it to "
                f"{x / MM:g} mm at the regulator maximum Pi = "
                f"{params.pneumatics.p_max / MPA:g} MPa; {allowed}")
    return loads


def load_moved(result: SimResult, window=None) -> bool:
    """Whether the contraction spanned at least `MOVE_MIN_MM` during the run (or over the
    samples `window` selects: a sine's analysed cycles, where its gain and lag come from)."""
    x = result.x if window is None else result.x[window]
    return bool(x.size and np.ptp(x) >= MOVE_MIN_MM * MM)
