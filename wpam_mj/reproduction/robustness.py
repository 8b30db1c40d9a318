"""Robustness: the paper's findings over plants sampled within their uncertainty.

A reproduction is a region, not a point. Every plant parameter nobody can measure on the
rig (`UNMEASURED`: those the paper does not give, fitted within a plausible range, and the
line's critical ratio and tube volume, which are estimates, the regulators' supply, which
the paper does not state, and their exhaust valve, which the catalogue does not give) is
known to perhaps +-5 %.
`robustness` samples N plants in that box by a seeded Latin hypercube
(scipy.stats.qmc.LatinHypercube: every parameter's range cut into N strata, each used
once), runs every study of `wpam reproduce` on each, and reports per finding the fraction
of plants that hold it and the spread of each Table 2 cell. The controller's feedforward
is an experimenter's model of the plant, not the plant (`Params.plant_deviation`): by
default it is fitted to each plant's own open-loop loops (Figs. 8-9) as the paper's
experimenter fits the mechanical equilibrium model (`wpam_mj.reproduction.feedforward_fit`);
with feedforward="nominal" it keeps the nominal values throughout.
"""

from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np
from scipy.stats import binomtest, qmc

from wpam_mj import paper
from wpam_mj.experiments.paper_studies import StepTask, sweep_batch
from wpam_mj.experiments.protocol import SHIPPED, Protocol, table2_batch
from wpam_mj.infra.files import csv_text, write_text_atomic
from wpam_mj.physics.params import Params, fitted_parameters
from wpam_mj.errors import ParameterError, check_int, check_range
from wpam_mj.infra.pool import open_workers
from wpam_mj.reproduction import authority, feedforward_fit, findings
from wpam_mj.reproduction.margins import Check
from wpam_mj.reproduction.table2_findings import decided_at_landing
from wpam_mj.simulation.execution import Batch, Failed, execute
from wpam_mj.units import MM

# Unmeasured plant parameters: the fitted ones, the line's ISO 6358 critical ratio and the
# tube volume (estimates), the supply the paper does not state and the exhaust valve the
# catalogue does not give (models/README.md)
UNMEASURED = (*fitted_parameters(), "pneumatics.critical_ratio", "pneumatics.tube_volume",
              "pneumatics.supply_pressure", "pneumatics.exhaust_valve_conductance")
DEFAULT_REL = 0.05  # +-5 %: what an unmeasured value is known to (issue targets, our reading)
SAMPLES_RANGE = (1, 4096)
ROBUST_SEED = 0  # the plants a robust search or calibration scores each point on
ADMISSIBLE_HALVINGS = 10  # a deviation halved this often is within 0.1 % of the nominal
HOLD_TARGET = 0.8  # a finding "holds across the plant's uncertainty" in >= 80 % of plants
CELLS = tuple((row, load) for row in ("open_po", "feedback") for load in paper.LOADS_N)


def check_measured(measured: Mapping[str, float],
                   names: Sequence[str] = UNMEASURED) -> tuple[tuple[str, float], ...]:
    """Validate per-parameter half-widths: {name: r}, r in [0, 0.5] (0: known exactly)."""
    for name, r in measured.items():
        if name not in names:
            raise ParameterError(f"uncertainty of {name!r}: not an unmeasured parameter; "
                                 f"one of {', '.join(names)}")
        check_range(f"uncertainty of {name}", r, 0.0, 0.5)
    return tuple((name, float(r)) for name, r in measured.items())


def half_widths(rel: float, measured: Mapping[str, float] | None = None,
                names: Sequence[str] = UNMEASURED) -> np.ndarray:
    """Each name's relative half-width: its own where `measured` gives one, else rel."""
    return np.array([(measured or {}).get(name, rel) for name in names], dtype=float)


def sample_deviations(n: int, seed: int, rel: float = DEFAULT_REL,
                      names: Sequence[str] = UNMEASURED,
                      measured: Mapping[str, float] | None = None) -> np.ndarray:
    """(n, len(names)) relative deviations, column j within +-its half-width (rel, or its
    own in `measured`): a seeded Latin hypercube. The draw does not depend on `measured`,
    so narrowing one value's range keeps every plant's other deviations."""
    n = check_int("samples", n, *SAMPLES_RANGE)
    rel = check_range("rel", rel, 0.0, 0.5, lo_open=True)
    width = half_widths(rel, dict(check_measured(measured or {}, names)), names)
    u = qmc.LatinHypercube(d=len(names), seed=seed).random(n)
    return width * (2.0 * u - 1.0)


def sampled_plants(nominal: Params, deviations: np.ndarray,
                   names: Sequence[str] = UNMEASURED) -> list[Params]:
    """The nominal parameters with each row of `deviations` as its plant's deviation. A row
    whose plant physics does not admit (a rule of `wpam_mj.physics.rules` broken: e.g. a
    braid angle pushed past the locking angle) is halved toward the nominal point until it
    is admissible: a plant that cannot exist is not part of the uncertainty."""
    plants = []
    for row in deviations:
        for _ in range(ADMISSIBLE_HALVINGS):
            plant = dataclasses.replace(nominal,
                                        plant_deviation=tuple(zip(names, map(float, row))))
            try:
                plant.plant  # noqa: B018 (builds, so checks, the deviated plant)
                break
            except ParameterError:
                row = row / 2.0
        else:
            plant = dataclasses.replace(nominal, plant_deviation=())
        plants.append(plant)
    return plants


@dataclass(frozen=True)
class PlantOutcome:
    """One sampled plant: its deviations, its checks and its Table 2 cells (or why it
    could not be run: `error`)."""

    deviation: tuple[tuple[str, float], ...]
    checks: tuple[Check, ...]
    cells: dict[tuple[str, float], float]
    error: str = ""
    # the branch the controller's feedforward puts this plant on (>= 1: over-contracted,
    # so the Po loop can reach every target) and the φ of its model that would put the
    # plant on its own contracting branch (`wpam_mj.reproduction.authority`); nan where
    # not computed
    feedforward_share: float = math.nan
    needed_share: float = math.nan
    # whether a PI plateau lands beyond what the PI's zero can remove before the settle
    # window at some load (`table2_findings.decided_at_landing`); None where not run
    steps_decided_at_landing: bool | None = None
    # the controller's equilibrium model against this plant: (name, model / plant - 1)
    # for each value it reads (`feedforward_fit.FEEDFORWARD_MODEL`), and, where it was
    # fitted to the plant's loops, the fit's rms x residual [m] (nan: nominal values)
    model_error: tuple[tuple[str, float], ...] = ()
    fit_rms: float = math.nan

    def holds(self, name: str) -> bool | None:
        """This plant's verdict on finding `name` (False where the plant failed to run)."""
        if self.error:
            return False
        return next((c.passed for c in self.checks if c.name == name), False)

    def margin(self, name: str) -> float:
        """This plant's worst margin on finding `name` (nan where it was not checked)."""
        return next((c.worst_margin for c in self.checks if c.name == name), math.nan)


@dataclass(frozen=True)
class Sensitivity:
    """What decides a finding over the sample: r2 of a plane of its worst margin in the
    deviations, and each parameter's slope (margin change at +rel), largest first."""

    r2: float
    slopes: tuple[tuple[str, float], ...]

    def describe(self, top: int = 2) -> str:
        return ", ".join(f"{name.partition('.')[2]} {slope:+.2f}"
                         for name, slope in self.slopes[:top]) + f" (R² {self.r2:.2f})"


@dataclass(frozen=True)
class Robustness:
    """Every sampled plant's outcome and the summaries the report prints."""

    outcomes: tuple[PlantOutcome, ...]
    rel: float
    seed: int
    measured: tuple[tuple[str, float], ...] = ()  # (name, its own half-width) pairs
    feedforward: str = "nominal"  # the controller's model (feedforward_fit.FEEDFORWARD_MODELS)
    calibration_ramp_time: float | None = None  # s; None: the protocol's ramps

    def half_widths(self, names: Sequence[str] = UNMEASURED) -> np.ndarray:
        """Each of `names`' relative half-width in this sample (`half_widths`)."""
        return half_widths(self.rel, dict(self.measured), names)

    def box(self) -> str:
        """The sampled box in words: "+-5%" or "+-5%, braid_angle +-1%"."""
        return ", ".join([f"+-{self.rel:.0%}"] + [f"{name.partition('.')[2]} +-{r:.0%}"
                                                  for name, r in self.measured])

    def describe_feedforward(self) -> str:
        """The controller's equilibrium model in words, with how far it sits from the
        plants (median |model / plant - 1| of each value it reads)."""
        if self.feedforward == "nominal":
            return "the controller's feedforward keeps the nominal values."
        errors = self.model_errors()
        ramps = ("" if self.calibration_ramp_time is None
                 else f", ramps of {self.calibration_ramp_time:g} s")
        return ("the controller's equilibrium model is fitted to each plant's own open-loop "
                f"loops (Figs. 8-9{ramps}, the gauges at 1 kPa; `feedforward_fit`), "
                "median |model / plant - 1|: "
                + ", ".join(f"{n.partition('.')[2]} {e:.1%}" for n, e in errors.items()) + ".")

    def model_errors(self) -> dict[str, float]:
        """Per value the controller's model reads, the median |model / plant - 1|."""
        rows = [dict(o.model_error) for o in self.outcomes if o.model_error]
        return {n: float(np.median([abs(r[n]) for r in rows]))
                for n in feedforward_fit.FEEDFORWARD_MODEL} if rows else {}

    def held_fraction(self) -> dict[str, float]:
        """Per finding, the fraction of plants that hold it (a plant that failed to run
        holds none; a finding its data cannot check, nan)."""
        return self._held(self.outcomes)

    def held_interval(self, confidence: float = 0.95) -> dict[str, tuple[float, float]]:
        """Per finding, the Wilson score interval of its held fraction at `confidence`
        (scipy's binomtest): how far the fraction of the whole box could lie from the
        sample's. It treats the plants as independent draws; a Latin hypercube spreads
        them more evenly than that, so for a finding that moves with the deviations the
        interval is, if anything, too wide. (nan, nan) where no plant could check it."""
        out = {}
        for name in findings.FINDINGS:
            known = self._verdicts(self.outcomes, name)
            ci = binomtest(sum(known), len(known)).proportion_ci(confidence, "wilson") \
                if known else None
            out[name] = (ci.low, ci.high) if ci else (math.nan, math.nan)
        return out

    @staticmethod
    def _verdicts(outcomes, name: str) -> list[bool]:
        """The plants' verdicts on finding `name`, those that could not check it left out."""
        return [v for v in (o.holds(name) for o in outcomes) if v is not None]

    @staticmethod
    def _held(outcomes) -> dict[str, float]:
        out = {}
        for name in findings.FINDINGS:
            known = Robustness._verdicts(outcomes, name)
            out[name] = sum(known) / len(known) if known else math.nan
        return out

    def over_contracted(self) -> tuple[list[PlantOutcome], list[PlantOutcome]]:
        """The plants the controller's feedforward over-contracts (share >= 1) and the rest."""
        shares = [o for o in self.outcomes if math.isfinite(o.feedforward_share)]
        return ([o for o in shares if o.feedforward_share >= 1.0],
                [o for o in shares if o.feedforward_share < 1.0])

    def cell_spread(self) -> dict[tuple[str, float], tuple[float, float, float]]:
        """Per Table 2 cell: (5th percentile, median, 95th percentile) over the plants."""
        out = {}
        for cell in CELLS:
            v = [o.cells[cell] for o in self.outcomes if cell in o.cells]
            out[cell] = tuple(np.percentile(v, [5, 50, 95])) if v else (math.nan,) * 3
        return out

    def decided_at_landing(self) -> tuple[int, int]:
        """(plants whose PI steps miss and land beyond what the PI's zero can remove,
        plants whose PI steps miss)."""
        missed = [o for o in self.outcomes if not o.error and o.holds("steps_settle") is False]
        return sum(bool(o.steps_decided_at_landing) for o in missed), len(missed)

    def needed_share_quantiles(self) -> dict[float, float]:
        """The φ of the controller's model that would over-contract half, HOLD_TARGET and
        all of the plants (quantiles of their needed shares; empty where none was
        computed)."""
        needed = [o.needed_share for o in self.outcomes if math.isfinite(o.needed_share)]
        return {q: float(np.quantile(needed, q)) for q in (0.5, HOLD_TARGET, 1.0)} \
            if needed else {}

    def sensitivity(self) -> dict[str, Sensitivity]:
        """Per finding, what decides it over the sample: a least-squares plane of its worst
        margin over the plants' deviations, each deviation scaled so that +-1 is +-rel.
        A slope is how far a deviation to the top of its range (+rel, or its own
        half-width) moves the margin (in the check's scale; the finding holds at margin
        >= 0). Values known exactly are left out, as are findings whose margin does not
        vary (or that no plant could check). Needs more plants than parameters."""
        ran = [o for o in self.outcomes if not o.error and o.deviation]
        if not ran:
            return {}
        names = [n for n, _ in ran[0].deviation]
        width = self.half_widths(names)
        names = [n for n, w in zip(names, width) if w > 0.0]
        if len(ran) <= len(names) + 1:
            return {}
        x = np.array([[d for _, d in o.deviation] for o in ran])[:, width > 0.0] \
            / width[width > 0.0]
        design = np.column_stack([np.ones(len(ran)), x])
        out = {}
        for name in findings.FINDINGS:
            y = np.array([o.margin(name) for o in ran])
            ok = np.isfinite(y)
            if ok.sum() <= len(names) + 1 or np.ptp(y[ok]) == 0.0:
                continue
            coef, *_ = np.linalg.lstsq(design[ok], y[ok], rcond=None)
            resid = y[ok] - design[ok] @ coef
            r2 = 1.0 - float(resid @ resid) / float(np.sum((y[ok] - y[ok].mean()) ** 2))
            order = np.argsort(-np.abs(coef[1:]))
            out[name] = Sensitivity(r2, tuple((names[i], float(coef[1 + i])) for i in order))
        return out

    def markdown(self) -> str:
        held = self.held_fraction()
        n = len(self.outcomes)
        lines = [f"{n} plants, every unmeasured parameter within {self.box()} of its "
                 f"nominal value (Latin hypercube, seed {self.seed}); "
                 f"{self.describe_feedforward()} A finding holds across the plant's "
                 f"uncertainty where at least {HOLD_TARGET:.0%} of the plants hold it.", "",
                 "Decided by: the two deviations that move the finding's worst margin "
                 "most, each as the change at the top of its range (the check's scale; it "
                 "holds at >= 0), and how much of the margin's spread a plane in all of them "
                 "explains (R²).", "",
                 "Over-contracted: the plants whose own contracting branch the nominal "
                 "feedforward's Pi reaches at Po = p_min at every load and staircase target "
                 "(§4.1's excessive contraction; Po can only hold a contraction back), and "
                 "the others.", "",
                 "95 % interval: the fractions of the whole box the sample is consistent "
                 "with (Wilson score; the plants taken as independent draws).", "",
                 "| finding | plants holding it | 95 % interval | | decided by | "
                 "over-contracted | others |",
                 "|---|---|---|---|---|---|---|"]
        sens = self.sensitivity()
        interval = self.held_interval()
        over, short = self.over_contracted()
        held_over, held_short = self._held(over), self._held(short)

        def share(frac: float, k: int) -> str:
            return "-" if not k or math.isnan(frac) else f"{round(frac * k)} of {k}"

        for name, frac in held.items():
            f = findings.FINDINGS[name]
            mark = "n/a" if math.isnan(frac) else ("holds" if frac >= HOLD_TARGET else
                                                     "**fragile**")
            extra = "" if f.counted else " (extra)"
            count = "n/a" if math.isnan(frac) else f"{frac:.0%} ({round(frac * n)} of {n})"
            lo, hi = interval[name]
            ci = "n/a" if math.isnan(lo) else f"{lo:.0%}-{hi:.0%}"
            lines.append(f"| {f.short}{extra} | {count} | {ci} | "
                         f"{mark} | {sens[name].describe() if name in sens else '-'} | "
                         f"{share(held_over[name], len(over))} | "
                         f"{share(held_short[name], len(short))} |")
        if needed := self.needed_share_quantiles():
            lines += ["", f"The feedforward over-contracts {len(over)} of {n} plants. "
                      "The friction share φ of its model that would over-contract "
                      + ", ".join(f"{q:.0%} of them is {phi:.2f}" for q, phi in needed.items())
                      + "."]
        landed, missed = self.decided_at_landing()
        if missed:
            lines += ["", f"PI steps: in {landed} of the {missed} plants that miss them, a "
                      "plateau lands beyond what the PI's own zero (exp(-t Ki/Kp)) can remove "
                      "before the settle window, so no friction law would settle it "
                      "(`StepRun.landing_floor`)."]
        lines += ["", "Table 2 cells over the plants (5th percentile / median / 95th "
                  "percentile) beside the paper's:", "",
                  "| cell | 5 % | median | 95 % | paper |", "|---|---|---|---|---|"]
        for (row, load), (lo, mid, hi) in self.cell_spread().items():
            lines.append(f"| {row} {load:g} N | {lo:.4f} | {mid:.4f} | {hi:.4f} | "
                         f"{paper.TABLE2[row][load]:.4f} |")
        failed = [o for o in self.outcomes if o.error]
        if failed:
            lines += ["", f"{len(failed)} plant(s) could not be run: "
                      + "; ".join(o.error for o in failed[:3])]
        return "\n".join(lines)


def _plant_batches(fit: feedforward_fit.Calibration, protocol: Protocol,
                   dt: float) -> list[Batch]:
    plant = fit.params
    return [table2_batch(plant, protocol, dt=dt, open_loops=fit.loops),
            Batch([StepTask(plant, 100.0, "open", dt)], lambda r: r[0]),
            sweep_batch(plant, dt=dt, keep=())]


def _failure(results) -> str | None:
    failed = next((r for r in results if isinstance(r, Failed)), None)
    if failed is None:
        return None
    return str(failed.error).splitlines()[0] if str(failed.error) else \
        type(failed.error).__name__


def robustness(nominal: Params, n: int = 32, *, seed: int = 0, rel: float = DEFAULT_REL,
               measured: Mapping[str, float] | None = None, dt: float = 1e-3, jobs: int = 1,
               progress: bool = False, protocol: Protocol = SHIPPED,
               feedforward: str = "calibrated",
               calibration_ramp_time: float | None = None) -> Robustness:
    """Run every study of `wpam reproduce` on `n` plants sampled around `nominal`, every
    unmeasured value within +-rel of it but those `measured` gives their own half-width;
    the controller's equilibrium model `feedforward`: "calibrated" (fitted to each plant's
    own open-loop loops, `feedforward_fit.calibrate`, on ramps of `calibration_ramp_time`
    [s], default the protocol's) or "nominal" (the nominal values)."""
    measured = check_measured(measured or {})
    feedforward_fit.check_feedforward_model(feedforward)
    plants = sampled_plants(nominal, sample_deviations(n, seed, rel, measured=dict(measured)))
    deviations = [p.plant_deviation for p in plants]
    with open_workers(jobs) as workers:
        fits = (feedforward_fit.calibrate(plants, protocol, dt, workers, progress,
                                          calibration_ramp_time)
                if feedforward == "calibrated" else
                [feedforward_fit.Calibration(p, math.nan, ()) for p in plants])
        results = iter(execute([b for f in fits if not isinstance(f, Failed)
                                for b in _plant_batches(f, protocol, dt)],
                               workers, failed=Failed, progress=progress, desc="robustness"))
    outcomes = []
    for fit, deviation in zip(fits, deviations):
        if isinstance(fit, Failed):
            outcomes.append(PlantOutcome(deviation, (), {}, _failure([fit])))
            continue
        plant, fit_rms = fit.params, fit.rms
        t2, open_step, sw = (next(results) for _ in range(3))
        known = dict(feedforward_share=authority.plant_share(plant),
                     needed_share=authority.needed_share(plant),
                     model_error=feedforward_fit.model_error(plant), fit_rms=fit_rms)
        error = _failure((t2, open_step, sw))
        if error is None:
            checks = findings.all_checks(t2, open_step, sw)
            cells = {**{("open_po", k): v for k, v in t2.open_po.items()},
                     **{("feedback", k): v for k, v in t2.feedback.items()}}
            outcomes.append(PlantOutcome(deviation, tuple(checks), cells,
                                         steps_decided_at_landing=decided_at_landing(t2),
                                         **known))
        else:
            outcomes.append(PlantOutcome(deviation, (), {}, error, **known))
    return Robustness(tuple(outcomes), rel, seed, measured, feedforward,
                      calibration_ramp_time if feedforward == "calibrated" else None)


def write_robustness(out: Path, result: Robustness) -> list[Path]:
    """robustness.csv (one row per plant: deviations, Table 2 cells, each finding's
    verdict and worst margin), robustness.json (the summary), robustness.md and
    robustness.png; each written whole."""
    rows = []
    for i, o in enumerate(result.outcomes):
        row = {"plant": i, **{f"dev_{name}": d for name, d in o.deviation},
               **{f"{r}_{load:g}N": o.cells.get((r, load), math.nan) for r, load in CELLS},
               "feedforward_share": o.feedforward_share, "needed_share": o.needed_share,
               "steps_decided_at_landing": o.steps_decided_at_landing,
               **{f"model_error_{name}": e for name, e in o.model_error},
               "fit_rms_mm": o.fit_rms / MM, "error": o.error}
        for c in o.checks:
            row[f"{c.name}_holds"] = c.passed
            row[f"{c.name}_margin"] = c.worst_margin
        rows.append(row)
    summary = {"plants": len(result.outcomes), "rel": result.rel, "seed": result.seed,
               "parameters": list(UNMEASURED),
               "uncertainty": dict(zip(UNMEASURED, result.half_widths())),
               "feedforward": result.feedforward,
               "calibration_ramp_time_s": result.calibration_ramp_time,
               "model_error_median": result.model_errors(),
               "hold_target": HOLD_TARGET,
               "held_fraction": result.held_fraction(),
               "held_interval_95": {name: list(ci) for name, ci
                                    in result.held_interval().items()},
               "over_contracted": len(result.over_contracted()[0]),
               "steps_decided_at_landing": dict(zip(("landed", "missed"),
                                                    result.decided_at_landing())),
               "needed_share_quantiles": {f"{q:g}": phi for q, phi
                                          in result.needed_share_quantiles().items()},
               "sensitivity": {name: {"r2": s.r2, "margin_change_at_plus_rel": dict(s.slopes)}
                               for name, s in result.sensitivity().items()},
               "table2_cells": {f"{r} {load:g} N": {"p5": lo, "median": mid, "p95": hi,
                                                    "paper": paper.TABLE2[r][load]}
                                for (r, load), (lo, mid, hi) in result.cell_spread().items()}}
    from wpam_mj.reproduction.robustness_figure import robustness_figure  # noqa: PLC0415
    from wpam_mj.experiments.figures import save_figure  # noqa: PLC0415
    return [write_text_atomic(out / "robustness.csv", csv_text(rows)),
            write_text_atomic(out / "robustness.json", json.dumps(summary, indent=2) + "\n"),
            write_text_atomic(out / "robustness.md", "# Robustness\n\n" + result.markdown()
                              + "\n"),
            save_figure(robustness_figure(result), out / "robustness.png")]
