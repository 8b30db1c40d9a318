"""The static loops of a slow pressure ramp, from the equilibrium model alone.

On a ramp slow beside every time constant of the rig (regulator lag, line filling, the
load's fall), the load is always at rest except where it slides, and dry friction with
true stiction leaves it where it is as long as the friction band can hold it (paper
§2.2, eqs. 1-6). With the contracting and extending equilibria of eqs. 5-6,

    x_C(Pi, Po): T(x) - Ff(x) = F_load     (the largest contraction Pi can pull to)
    x_E(Pi, Po): T(x) + Ff(x) = F_load     (the smallest contraction friction holds),

x_C <= x_E, and one ramp sample after another the contraction is

    x_k = min(max(x_{k-1}, x_C(Pi_k, Po_k)), x_E(Pi_k, Po_k)),

a Prandtl play operator: x stays while it lies inside the band, else it moves to the
nearer edge (kinetic friction equals the static level, so a sliding load stops exactly
there). This is the paper's own reading of Fig. 8 ("the amount of contraction does not
change for a while after the pressure is decreased, and then rapidly extends").

x_s is found by inverting Pi_s(x) (`MuscleModel.equilibrium_pressure`, closed form and
increasing in x, since S = dV/dx falls with contraction) on a grid of the stroke, so a
whole loop costs a few hundred microseconds: cheap enough to screen thousands of
parameter sets before any of them is simulated (`wpam_mj.reproduction.search`).
Units: Pa, m, N.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from wpam_mj.physics.muscle import MuscleModel

GRID_POINTS = 2001  # samples of the stroke: 0.045 mm apart on the W-PAM's 90 mm


def branch_contraction(model: MuscleModel, pi: npt.ArrayLike, po: float, load: float,
                       direction: int) -> np.ndarray:
    """x_C (direction +1) or x_E (-1) [m] at internal pressures `pi` [Pa], shape (n,),
    with external pressure `po` [Pa] and `load` [N]; clipped to [0, max_contraction]."""
    x = np.linspace(0.0, model.geometry.max_contraction, GRID_POINTS)
    p_of_x = np.asarray(model.equilibrium_pressure(x, load, po, direction), dtype=float)
    finite = np.isfinite(p_of_x)
    if not finite.any():  # Kf <= mu: friction beats any pressure, the braid never moves
        return np.zeros(np.shape(pi))
    # Pi_s(x) rises with x; a pressure below Pi_s(0) holds nothing (x = 0), one above the
    # last finite Pi_s reaches the stop. maximum.accumulate guards the flat start (rhs
    # clipped at 0 gives Pi_s = Po there).
    p_grid = np.maximum.accumulate(p_of_x[finite])
    return np.interp(np.asarray(pi, dtype=float), p_grid, x[finite],
                     left=0.0, right=float(x[finite][-1]))


def ramp_contraction(model: MuscleModel, pi: npt.ArrayLike, po: npt.ArrayLike,
                     load: float, x0: float = 0.0) -> np.ndarray:
    """Contraction x [m] along a quasi-static ramp: samples of `pi` and `po` [Pa], shape
    (n,), under `load` [N], starting at rest at `x0` [m] (the play operator above).

    Po takes few values on the paper's ramps (0 on the way up, a constant on the way
    down), so each distinct Po gets its branch tables once."""
    pi = np.asarray(pi, dtype=float)
    po = np.broadcast_to(np.asarray(po, dtype=float), pi.shape)
    lo, hi = np.empty_like(pi), np.empty_like(pi)
    for value in np.unique(po):
        at = po == value
        lo[at] = branch_contraction(model, pi[at], float(value), load, +1)
        hi[at] = branch_contraction(model, pi[at], float(value), load, -1)
    x = np.empty_like(pi)
    prev = x0
    for k in range(pi.size):  # the play operator is sequential; n is a few hundred
        prev = min(max(prev, lo[k]), hi[k])
        x[k] = prev
    return x
