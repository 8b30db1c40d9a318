"""Whether the nominal feedforward over-contracts a plant: the quasi-static condition for
the Po loop to reach the paper's step targets.

§4.1: Pi comes from the mechanical equilibrium model so that the muscle sits in "the
excessive contraction state calculated by the mechanical equilibrium model", and the Po
feedback brings it back. Po can only hold a contraction back: at the regulator's floor
p_min the feedback has no more to give. So a plant reaches every target only where the
experimenter's Pi, computed from the nominal values (`Controller.feedforward_friction`
φ, Po assumed at `po_feedforward`), lies at or beyond the plant's own contracting branch
(eq. 5) at Po = p_min. `plant_share` measures that as the branch the Pi puts the plant on
(`MuscleModel.friction_share`: 1 the contracting branch); `needed_share` the nominal φ
that would put this plant on its branch. Both are quasi-static (no simulation), worst over
the paper's loads and staircase targets.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from wpam_mj import paper
from wpam_mj.physics.muscle import MuscleModel
from wpam_mj.physics.params import Params
from wpam_mj.units import MM

TARGETS_MM = tuple(sorted({x for x in paper.STEP_LEVELS_MM if x > 0}))  # x_r = 0: the stop
TARGETS = np.array(TARGETS_MM) * MM  # [m]


def _shares(reader: Params, writer: Params, load: float, writer_po: float,
            writer_share: float, reader_po: float) -> np.ndarray:
    """At each target: the branch on which `reader`'s muscle, at `reader_po` [Pa], is held
    by the Pi that `writer`'s equilibrium model gives on branch `writer_share` at
    `writer_po` [Pa]."""
    pi = MuscleModel.from_params(writer).equilibrium_pressure(TARGETS, load, writer_po,
                                                              writer_share)
    return MuscleModel.from_params(reader).friction_share(TARGETS, load, pi, reader_po)


def plant_share(params: Params, loads: Sequence[float] = paper.LOADS_N) -> float:
    """The lowest branch (friction share) at which the feedforward's Pi, computed from
    `params`' nominal values, holds its plant (`params.plant`) at Po = p_min over `loads`
    and the staircase's targets: >= 1 where the plant over-contracts at every one of
    them, so the Po loop can bring it to each target."""
    c, p_min = params.controller, params.pneumatics.p_min
    return min(float(np.min(_shares(params.plant, params, load, c.po_feedforward,
                                     c.feedforward_friction, p_min))) for load in loads)


def needed_share(params: Params, loads: Sequence[float] = paper.LOADS_N) -> float:
    """The nominal φ at which the feedforward puts `params.plant` on its own contracting
    branch (at Po = p_min) at every load and target: the margin this plant asks of φ."""
    po_ff, p_min = params.controller.po_feedforward, params.pneumatics.p_min
    return max(float(np.max(_shares(params, params.plant, load, p_min, 1.0, po_ff)))
               for load in loads)
