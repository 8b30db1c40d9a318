"""How `wpam search` scores a point: every finding's signed margin, the record journaled
for it, and the objectives differential evolution minimises over those records.

A point's runs are the paper's targets (`calibrate.PaperTargets`); its score is calibrate's
one cost (1/2 |r|^2) and the signed margin of every finding (`FINDINGS`, in units of each
margin's scale, >= 0 holds), so that a search's archive is also a measured feasibility map
(`wpam_mj.reproduction.findings_map`). Journals keep the margins, so every objective
replays any journal.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Sequence

from wpam_mj.experiments.protocol import Protocol
from wpam_mj.paper import CALIBRATION_HEADROOM
from wpam_mj.physics.params import Params
from wpam_mj.errors import ParameterError
from wpam_mj.reproduction import findings
from wpam_mj.reproduction.calibrate import PaperTargets

SHORTFALL_CAP = 3.0  # scale units: one far miss counts as three near ones, no more
TRACK_MM = 5.0  # half a 10 mm step: a PI staircase worse than this does not follow it
FAILED_COST = 1e6  # DE needs a finite cost where a simulation fails

# The findings a point's runs check (`findings.FINDINGS` but Fig. 12's open loop, which the
# search does not run), by name; the paper's sentences among them (the extras aside).
FINDING_TEXT = {f.name: f.short for f in (*findings.TABLE2_FINDINGS,
                                           *findings.SWEEP_FINDINGS)}
FINDINGS = tuple(FINDING_TEXT)
PAPER_CHECKS = tuple(name for name in FINDINGS if findings.FINDINGS[name].counted)


def _worst(margins) -> float:
    return min(m.margin / m.scale for m in margins)


def finding_margins(scores, table2) -> dict[str, float]:
    """Each finding's worst margin in units of its scale (>= 0: holds)."""
    checks = [*findings.table2_checks(table2), *scores.sweep_checks]
    return {c.name: _worst(c.margins) if c.margins else -SHORTFALL_CAP for c in checks}


def margin_of(rec: "Record", name: str) -> float:
    """A record's margin of one finding; a journal written before the finding existed
    counts it as a far miss."""
    return rec.margins.get(name, -SHORTFALL_CAP)


@dataclass(frozen=True)
class Record:
    """One evaluated point: coordinates, cost, margins (None: failed) and the figures."""

    u: tuple[float, ...]
    cost: float
    margins: dict[str, float] | None
    figures: dict | None
    # wall seconds into the search when it was scored (None: not recorded)
    seconds: float | None = field(default=None, compare=False)

    @property
    def tracks(self) -> bool:
        """Whether the point ran and its PI staircase follows the targets at all. A muscle
        that never moves meets the feedback row vacuously (no loop): such points are not
        reproductions of the experiments and stay out of the map and the choice."""
        return self.margins is not None and \
            max(self.figures["step_error_mm"]["pi"]) <= TRACK_MM

    @property
    def held(self) -> int:
        """How many of the paper's checks (`wpam reproduce`'s, PAPER_CHECKS) hold."""
        return 0 if self.margins is None else sum(margin_of(self, f) >= 0.0
                                                  for f in PAPER_CHECKS)

    def as_json(self) -> dict:
        return {"u": list(self.u), "cost": self.cost, "margins": self.margins,
                "figures": self.figures, "seconds": self.seconds}

    @classmethod
    def from_json(cls, d: dict) -> "Record":
        return cls(tuple(d["u"]), d["cost"], d["margins"], d["figures"], d.get("seconds"))


# ---- objectives: what DE minimises (journals keep margins, so either replays any journal)



def shortfall(rec: Record, wanted: Sequence[str] = PAPER_CHECKS) -> float:
    """The "checks" objective: how far the point falls short of every sentence check of
    `wpam reproduce` that its runs see (or of the findings `wanted`), each shortfall in
    units of its margin's scale measured from CALIBRATION_HEADROOM past its limit and
    capped at SHORTFALL_CAP (0: all met with headroom). Unlike calibrate's cost it asks
    no more of a finding than its check does, so a point's value falls only by meeting
    checks."""
    if rec.margins is None:
        return rec.cost  # failed or screened out: the same large cost as "cost"
    return sum(min(max(0.0, CALIBRATION_HEADROOM - margin_of(rec, f)), SHORTFALL_CAP)
               for f in wanted)


def findings_shortfall(rec: Record) -> float:
    """The "findings" objective: the checks' shortfall with every finding of FINDINGS
    asked, the extras among them (what "checks" may trade away)."""
    return shortfall(rec, FINDINGS)


OBJECTIVES = {"cost": lambda rec: rec.cost, "checks": shortfall,
              "findings": findings_shortfall}
OBJECTIVE_TEXT = {"cost": "calibrate's cost 1/2 |r|^2", "checks": "checks' summed shortfall",
                  "findings": "findings' summed shortfall"}


def _figures(scores) -> dict:
    """The numbers a reader checks a point by (display units)."""
    return {"table2_po_row": list(scores.table2_po_row),
            "feedback_row": list(scores.feedback_row),
            "step_error_mm": {c: list(v) for c, v in scores.step_error_mm.items()},
            "step_pp_mm": {c: list(v) for c, v in scores.step_pp_mm.items()},
            "step_limit_mm": list(scores.step_limit_mm),
            "po_plateau_mpa": list(scores.po_plateau_mpa),
            "failed": list(scores.sweep_failed)}


@dataclass(frozen=True)
class Targets:
    """The paper's targets under one protocol, as `wpam reproduce` reads them: the
    controller's model is `feedforward` (`feedforward_fit.FEEDFORWARD_MODELS`): fitted to
    the plant's own Table 2 open loops first ("calibrated": `calibration_tasks`, then
    `calibrated`), or the plant's nominal values. Then `tasks` to run and `score` of
    their results as (residual vector of calibrate's cost, finding margins, figures)."""

    dt: float
    protocol: Protocol
    feedforward: str = "calibrated"
    open_loops: tuple = ()  # the open loops the controller's model was fitted to

    def calibration_tasks(self, params: Params) -> list:
        """The runs the controller's model is fitted to (none: it is the nominal one)."""
        if self.feedforward == "nominal":
            return []
        return self._model().calibration_tasks(params)

    def calibrated(self, params: Params, results: list) -> tuple[Params, "Targets"]:
        """`params` with the controller's model fitted to `results` of
        `calibration_tasks` (the plant kept), and the targets that reuse those runs
        (`PaperTargets.calibrated`)."""
        if not results:
            return params, self
        model, paper = self._model().calibrated(params, results)
        return model, replace(self, open_loops=paper.open_loops)

    def _model(self) -> PaperTargets:
        return PaperTargets(self.dt, self.protocol, self.open_loops)

    def tasks(self, params: Params) -> list:
        return self._model().tasks(params)

    def score(self, params: Params, results: list):
        model = self._model()
        r = model.residuals(params, results)
        scores, table2 = model.scores_and_table2(params, results)
        return r, finding_margins(scores, table2), _figures(scores)


def score(targets, params: Params, results: list | None) -> tuple[float, dict | None,
                                                                    dict | None]:
    """(cost, margins, figures) of a point from its runs' results (None: failed)."""
    if results is None:
        return FAILED_COST, None, None
    try:
        r, margins, figures = targets.score(params, results)
    except (ParameterError, ArithmeticError):
        return FAILED_COST, None, None
    cost = 0.5 * float(r @ r)
    if not math.isfinite(cost):
        return FAILED_COST, None, None
    return cost, margins, figures


def worst_of(scored: Sequence[tuple[float, dict | None, dict | None]]
             ) -> tuple[float, dict | None, dict | None]:
    """One (cost, margins, figures) from several plants' scores: the worst cost, each
    finding's worst margin, the first (nominal) plant's figures; a failed plant fails
    the point."""
    if any(m is None for _, m, _ in scored):
        return FAILED_COST, None, None
    margins = {name: min(m[name] for _, m, _ in scored) for name in scored[0][1]}
    return max(c for c, _, _ in scored), margins, scored[0][2]
