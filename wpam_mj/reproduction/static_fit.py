"""The quasi-static screen: friction coefficient and axial area fitted to Table 2's "Po =
0.04 MPa" row on the equilibrium model's loops, in milliseconds, before any simulation.

The open-loop loops of Table 2 follow from the equilibrium model alone on slow ramps
(`wpam_mj.physics.quasistatic`, `wpam_mj.experiments.protocol.quasi_static_po_row`),
within a few per cent of the simulated ones. The region of the credible box where the
row holds is a narrow strip (about 1 % of the friction coefficient's range wide at one
ramp top), which uniform sampling almost never hits; fitting the two parameters that
place the row (the friction coefficient sets the width of the open-loop band, the axial
area the extension Po brings) on the quasi-static loops puts every point the search and
the calibration simulate on that strip, and tells which points no fit can bring there.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
from scipy.optimize import least_squares

from wpam_mj import paper
from wpam_mj.experiments.protocol import Protocol, quasi_static_po_row
from wpam_mj.fitting import estimation
from wpam_mj.physics.params import Params

STATIC_FIT = ("muscle.friction_coeff", "muscle.axial_area")
STATIC_GRID = (11, 8)  # starts of the fit: friction coefficient x axial area


def _static_errors(params: Params, protocol: Protocol) -> np.ndarray:
    row = quasi_static_po_row(params, protocol)
    return np.array([math.log(row[f] / paper.TABLE2["open_po"][f])
                     if row[f] > 0.0 else 10.0 for f in paper.LOADS_N])


def static_fit(params: Params, protocol: Protocol) -> tuple[Params, float]:
    """`params` with STATIC_FIT chosen inside their plausible ranges to meet Table 2's "Po
    = 0.04" row on the quasi-static loops (`protocol.quasi_static_po_row`): the best of a
    grid, polished by bounded least squares on the cells' log errors. Returns the fitted
    parameters and the worst cell's |relative error| there (milliseconds per loop: the
    pre-screen that spares a simulation of points no static fit can bring near the row).
    """
    free = [estimation.FreeParameter.of(n) for n in STATIC_FIT]

    def at(z) -> Params:
        return params.with_values({f.name: f.from_z(float(v)) for f, v in zip(free, z)})

    def resid(z) -> np.ndarray:
        return _static_errors(at(z), protocol)

    grid = [np.array(z) for z in itertools.product(*(np.linspace(0.0, 1.0, k)
                                                     for k in STATIC_GRID))]
    z0 = min(grid, key=lambda z: float(np.sum(resid(z) ** 2)))
    fit = least_squares(resid, z0, bounds=(0.0, 1.0), diff_step=1e-3, max_nfev=60)
    best = at(fit.x)
    return best, float(np.max(np.abs(np.expm1(_static_errors(best, protocol)))))
