"""Calibrate the parameters the paper does not give, against the paper's own results.

One cost, every target at once (`PaperTargets`): a stage that fits the static parameters
without the step runs trades the steps for Table 2 (docs/physics.md), so every residual
is computed from one batch of runs at the same parameters:

  * Table 2's "Po = 0.04 MPa" row: the log error of each cell (open-loop loop areas with
    Po on the way down, normalized by the Po = 0 loops; paper Figs. 8-9);
  * the step staircases (Fig. 14), PI at 50/100/150 N as the paper ran them (PID appears
    only in its frequency response): each settled (steady-state mean) plateau error
    beyond the split Table 2's feedback-row limit allows at that load
    (`findings.plateau_error_limit`) and x peak-to-peak beyond 0.18 mm (target 0.2 mm,
    a plateau that has converged);
  * Table 2's feedback row (Fig. 16) as the margins of its finding,
    `findings.FINDINGS["table2_feedback_row"]`;
  * the frequency response (§4.2, Figs. 17-19; PI and PID, every load and frequency): the
    margins of the paper's sentences among `findings.SWEEP_FINDINGS` (gain falls and lag
    grows with frequency, gains agree across loads, lag smaller at lower load and alike
    from 0.5 Hz, PI and PID gains equal and PID's visible lead at 150 N, Po's cap reached
    at 150 N, 0.5 Hz); the extras, readings of ours that no sentence states, are reported
    and not fitted to;
  * Po rising with load (Fig. 15, §4.2): the plateau-mean Po of the PI staircase;
  * walls where the 150 N ramp top or feedforward would need more than 95 % of p_max.

The search (`calibrate`): optionally a seeded random search of the plausible ranges
(`samples`; the gain reading `controller.command_scale` drawn as a category from
`READINGS`), then bounded least squares from the best point on the engine of `wpam fit`
(`wpam_mj.fitting.estimation`: scaled coordinates, parallel Jacobian columns), with a forward
difference step wide enough to see trends through stick-slip (`DIFF_STEP`). Every
evaluation is journaled, so an interrupted calibration resumes where it stopped
(`resume=True`) and ends exactly where an uninterrupted one does. Deterministic: the same
start, seed and settings give the same fit.

The fitted values go to a TOML file that `--config` (or, shipped as
`models/wpam/calibrated.toml`, `wpam_mj.physics.params.preset`) applies.
"""

from __future__ import annotations

import math
import sys
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from wpam_mj import paper
from wpam_mj.reproduction import feedforward_fit, findings, robustness
from wpam_mj.fitting import estimation
from wpam_mj.experiments.drives import STATIC_TOP_MM
from wpam_mj.physics.muscle import MuscleModel
from wpam_mj.physics.params import Params, preset
from wpam_mj.errors import ParameterError, check_int, check_range
from wpam_mj.units import MM, MPA
from wpam_mj.infra.pool import Workers, open_workers
from wpam_mj.experiments.protocol import SHIPPED, Protocol, open_loop_tasks, table2_batch
from wpam_mj.infra.files import write_text_atomic
from wpam_mj.simulation.execution import execute
from wpam_mj.experiments.paper_studies import PLATEAU_SETTLE_S, sweep_batch

# The parameters fitted to the paper, by name: the plant parameters a fit frees by default
# (`estimation.default_free`: a plausible range, and not measurable on a rig as the
# slide's damping and the regulators' lag and dead time are), and the share of the
# friction band the Pi feedforward adds, a reading of the paper's controller.
FREE = (*estimation.default_free(), "controller.feedforward_friction",
        "controller.po_feedforward")
# A protocol reading written with the fit but not fitted: the gain reading (drawn by the
# random search; docs/physics.md)
KEPT = ("controller.command_scale",)
# The paper's unitless gains read as MPa/mm, as volts on the ITV's 0-5 V input and on its
# 0-10 V input (docs/physics.md): controller.command_scale [MPa per unit].
READINGS = (1.0, 0.1, 0.05)
DIFF_STEP = 0.01  # forward-difference step in scaled coordinates: 1 % of each range
SAMPLES_RANGE = (0, 10_000)
NFEV_RANGE = (1, 500)


@dataclass(frozen=True)
class Weights:
    """How much each calibration residual counts (the one place to tune them)."""

    table2: float = 1.0  # per unit log error of a Table 2 "Po = 0.04" cell ...
    table2_limit: float = 1.0  # ... and per unit of its finding's margin residuals
    step_error_share: float = 0.9  # a plateau's settled error costs beyond this share of
    # findings.plateau_error_limit ...
    step_pp_mm: float = 0.18  # ... and its x peak-to-peak beyond this [mm] ...
    step: float = 2.0  # ... this residual per mm
    feedback_row: float = 0.3  # per unit of the feedback-row margins' residuals
    sweep: float = 1.0  # per unit of the §4.2 findings' margin residuals
    po_rise_mpa: float = 0.01  # plateau-mean Po falling by this much with load costs 1
    pressure_share: float = 0.95  # the 150 N ramp top and feedforward may use this share
    pressure_wall: float = 10.0  # of p_max; beyond it a wall of this slope


WEIGHTS = Weights()


@dataclass(frozen=True)
class Scores:
    """The figures a calibration is judged by, at one parameter set."""

    table2_po_row: tuple[float, ...]  # 50/100/150 N, normalized loop areas
    feedback_row: tuple[float, ...]
    step_error_mm: dict[str, tuple[float, ...]]  # controller -> per load
    step_pp_mm: dict[str, tuple[float, ...]]
    step_limit_mm: tuple[float, ...]  # findings.plateau_error_limit per load
    po_plateau_mpa: tuple[float, ...]  # PI staircase, mean over plateaus, per load
    po_max_mpa: dict[tuple[float, float], float]  # (load, freq) -> PI sine's Po max
    sweep_checks: tuple[findings.Check, ...]  # the §4.2 findings checked on the sweep

    @property
    def sweep_failed(self) -> tuple[str, ...]:
        """The §4.2 findings that do not hold."""
        return tuple(c.finding for c in self.sweep_checks if c.passed is False)

    def text(self) -> str:
        row = [paper.TABLE2["open_po"][f] for f in paper.LOADS_N]
        errs = ", ".join(f"{v:.4f} ({v / p - 1:+.1%})" for v, p in zip(self.table2_po_row, row))
        lines = [f"Table 2 'Po = 0.04' row (50/100/150 N): {errs}",
                 "Table 2 feedback row: " + "/".join(f"{v:.4f}" for v in self.feedback_row)]
        for c in self.step_error_mm:
            lines.append(f"{c.upper()} steps, settled plateau error (limit) / x p-p [mm]: "
                         + ", ".join(f"{e:.2f} ({lim:.2f})/{p:.2f}" for e, lim, p in
                                     zip(self.step_error_mm[c], self.step_limit_mm,
                                         self.step_pp_mm[c])))
        lines.append("PI plateau-mean Po [MPa]: "
                     + "/".join(f"{v:.4f}" for v in self.po_plateau_mpa))
        lines.append("PI sine Po max [MPa]: " + ", ".join(
            f"{load:g} N {freq:g} Hz {v:.4f}" for (load, freq), v in self.po_max_mpa.items()
            if freq in (min(paper.SWEEP_FREQS_HZ), paper.FIG18_FREQ_HZ)))
        lines.append(f"§4.2 findings that fail: {len(self.sweep_failed)} of "
                     f"{len(findings.SWEEP_FINDINGS)}" + "".join(f"\n  - {f}"
                                                            for f in self.sweep_failed))
        return "\n".join(lines)


@dataclass(frozen=True)
class PaperTargets:
    """`estimation.ResidualModel` of the paper's targets (module docstring), the static
    ramps run and measured under `protocol` (`wpam_mj.experiments.protocol`)."""

    dt: float = 1e-3
    protocol: Protocol = SHIPPED
    # Table 2's open-loop ramps already run on this plant (`open_loop_tasks`' order):
    # then only the closed-loop runs are tasks
    open_loops: tuple = ()

    def _batches(self, params: Params):
        return (table2_batch(params, self.protocol, dt=self.dt, open_loops=self.open_loops),
                sweep_batch(params, keep=(), dt=self.dt))

    def tasks(self, params: Params) -> list:
        t2, sw = self._batches(params)
        return [*t2.tasks, *sw.tasks]

    def calibration_tasks(self, params: Params) -> list:
        """Table 2's open loops of `params`: what the controller's model is fitted to as
        `wpam reproduce` fits it (`feedforward_fit`)."""
        return open_loop_tasks(params, self.protocol, dt=self.dt)

    def calibrated(self, params: Params, loops) -> tuple[Params, "PaperTargets"]:
        """`params` with the controller's model fitted to `loops`, the results of
        `calibration_tasks` (the plant kept), and the targets that reuse those loops for
        Table 2, so that only the closed-loop runs remain tasks."""
        model, _ = feedforward_fit.fitted_to(params, loops)
        return model, replace(self, open_loops=tuple(loops))

    def _assemble(self, params: Params, results: list):
        t2, sw = self._batches(params)
        n = len(t2.tasks)
        table2 = t2.assemble(results[:n])
        return table2, {"pi": table2.feedback_runs}, sw.assemble(results[n:])

    def scores(self, params: Params, results: list) -> Scores:
        return self._scores(*self._assemble(params, results))

    def scores_and_table2(self, params: Params, results: list):
        """`scores` and the Table 2 result they come from (its checks need it)."""
        table2, steps, sweep = self._assemble(params, results)
        return self._scores(table2, steps, sweep), table2

    @staticmethod
    def _scores(table2, steps, sweep) -> Scores:
        loads = paper.LOADS_N
        return Scores(
            table2_po_row=tuple(table2.open_po[f] for f in loads),
            feedback_row=tuple(table2.feedback[f] for f in loads),
            step_error_mm={c: tuple(r.worst_error(PLATEAU_SETTLE_S) / MM for r in runs)
                           for c, runs in steps.items()},
            step_pp_mm={c: tuple(r.worst_peak_to_peak(PLATEAU_SETTLE_S) / MM
                                 for r in runs) for c, runs in steps.items()},
            step_limit_mm=tuple(v / MM for v in findings.plateau_error_limit(table2).values()),
            po_plateau_mpa=tuple(float(np.mean(r.po_mean)) / MPA for r in steps["pi"]),
            po_max_mpa={(p.load, p.freq): p.po_max / MPA for p in sweep.points
                        if p.controller == "pi"},
            sweep_checks=tuple(findings.sweep_checks(sweep)))

    def residual_groups(self, params: Params, results: list) -> dict[str, np.ndarray]:
        """The residuals by target (each §4.2 finding as "sweep.<name>"), in the order
        `residuals` concatenates them."""
        w = WEIGHTS
        table2, steps, sweep = self._assemble(params, results)
        s = self._scores(table2, steps, sweep)
        row = [paper.TABLE2["open_po"][f] for f in paper.LOADS_N]
        beyond = []
        for c in s.step_error_mm:
            beyond += [w.step * max(0.0, e - w.step_error_share * lim)
                       for e, lim in zip(s.step_error_mm[c], s.step_limit_mm)]
            beyond += [w.step * max(0.0, p - w.step_pp_mm) for p in s.step_pp_mm[c]]
        po = s.po_plateau_mpa
        groups = {
            "table2": [w.table2 * math.log(v / p) for v, p in zip(s.table2_po_row, row)],
            "table2_po_row": w.table2_limit * findings.residuals(
                [findings.check(findings.FINDINGS["table2_po_row"], table2)]),
            "steps": beyond,
            "feedback_row": w.feedback_row * findings.residuals(
                [findings.check(findings.FINDINGS["table2_feedback_row"], table2)]),
            # the paper's sentences only: an extra (a reading of ours) is not asked for
            **{f"sweep.{c.name}": w.sweep * findings.residuals([c]) for c in s.sweep_checks
               if c.counted},
            "po_rise": [max(0.0, a - b) / w.po_rise_mpa for a, b in zip(po, po[1:])],
            "pressure": _pressure_walls(params, self.protocol)}
        return {k: np.asarray(v, dtype=float) for k, v in groups.items()}

    def residuals(self, params: Params, results: list) -> np.ndarray:
        return np.concatenate(list(self.residual_groups(params, results).values()))


@dataclass(frozen=True)
class _CalibratedRuns:
    """One parameter set's runs as `wpam reproduce` reads them (a worker task): Table 2's
    open loops, the controller's model fitted to them (`PaperTargets.calibrated`), then
    the closed-loop runs with that model; (the model's parameters, the loops, the runs)."""

    targets: PaperTargets
    params: Params

    @property
    def cost(self) -> float:
        return sum(t.cost for t in self.targets.tasks(self.params))

    def run(self) -> tuple[Params, tuple, list]:
        loops = tuple(t.run() for t in self.targets.calibration_tasks(self.params))
        model, closed = self.targets.calibrated(self.params, loops)
        return model, loops, [t.run() for t in closed.tasks(model)]


@dataclass(frozen=True)
class CalibratedTargets:
    """`PaperTargets` with each parameter set's controller model fitted to its own open
    loops first, as `wpam reproduce` runs it (`--feedforward-model calibrated`): one task
    a set, its two phases in order on one worker; the residuals are those of the fitted
    model on the plant's runs."""

    targets: PaperTargets

    def tasks(self, params: Params) -> list:
        return [_CalibratedRuns(self.targets, params)]

    def _read(self, results: list) -> tuple[PaperTargets, Params, list]:
        ((model, loops, runs),) = results
        return replace(self.targets, open_loops=loops), model, runs

    def residuals(self, params: Params, results: list) -> np.ndarray:
        targets, model, runs = self._read(results)
        return targets.residuals(model, runs)

    def scores(self, params: Params, results: list) -> Scores:
        targets, model, runs = self._read(results)
        return targets.scores(model, runs)


@dataclass(frozen=True, eq=False)
class RobustTargets:
    """`PaperTargets` on a parameter set and on the plants sampled about it within their
    uncertainty (`robustness.sampled_plants`, seeded): their residuals stacked, so that
    least squares fits what survives the plant's uncertainty, not the point alone."""

    targets: PaperTargets | CalibratedTargets
    deviations: np.ndarray  # (plants, len(robustness.UNMEASURED)) relative deviations

    def plants(self, params: Params) -> list[Params]:
        return [params, *robustness.sampled_plants(params, self.deviations)]

    def tasks(self, params: Params) -> list:
        return [t for p in self.plants(params) for t in self.targets.tasks(p)]

    def residuals(self, params: Params, results: list) -> np.ndarray:
        out, start = [], 0
        for p in self.plants(params):
            n = len(self.targets.tasks(p))
            out.append(self.targets.residuals(p, results[start:start + n]))
            start += n
        return np.concatenate(out)


def _pressure_walls(params: Params, protocol: Protocol) -> list[float]:
    """Walls if 150 N at the top step would need more than `pressure_share` of p_max."""
    w, p_max, worst = WEIGHTS, params.pneumatics.p_max, paper.LOADS_N[-1]
    need_ramp = protocol.top(params, worst) / p_max
    need_ff = MuscleModel.from_params(params).equilibrium_pressure(
        STATIC_TOP_MM * MM, worst, params.controller.po_feedforward) / p_max
    return [w.pressure_wall * max(0.0, need - w.pressure_share)
            for need in (need_ramp, need_ff)]


# ---- search ----


@dataclass(frozen=True)
class CalibrationResult:
    params: Params
    fitted: dict[str, float]
    cost: float  # 1/2 |r|^2 at the fitted values
    start_cost: float  # ... and at the start of the least-squares search
    scores: Scores
    evaluations: int
    seconds: float

    def table(self) -> str:
        lines = ["fitted parameter                      value"]
        lines += [f"  {k:<34s} {v:.6g}{' (kept)' if k in KEPT else ''}"
                  for k, v in self.fitted.items()]
        lines.append(f"cost {self.cost:.4f} (least-squares start {self.start_cost:.4f}); "
                     f"{self.evaluations} parameter sets in {self.seconds / 60:.1f} min")
        lines.append(self.scores.text())
        return "\n".join(lines)

    def toml(self) -> str:
        sections: dict[str, dict[str, float]] = {}
        for key, v in self.fitted.items():
            s, n = key.split(".")
            sections.setdefault(s, {})[n] = v
        out = ["# Fitted by `wpam calibrate` (wpam_mj/reproduction/calibrate.py); SI units.", ""]
        for s, values in sections.items():
            out.append(f"[{s}]")
            out += [f"{n} = {v!r}" for n, v in values.items()]
            out.append("")
        return "\n".join(out)


def journal_path(out: Path, robust: int = 0, feedforward: str = "nominal") -> Path:
    """Where `calibrate` journals every evaluation of a fit to `out` (a robust fit's
    residuals are its plants' too, and a calibrated controller's are its fitted model's,
    so each keeps a journal of its own)."""
    tag = (f".robust{robust}" if robust else "") + \
        ("" if feedforward == "nominal" else f".{feedforward}")
    return out.with_name(f".{out.name}{tag}.journal.json")


def random_starts(start: Params, samples: int, seed: int) -> list[Params]:
    """`start` and `samples` parameter sets drawn uniformly over the plausible ranges of
    FREE (log-uniform for conductances, as `estimation.FreeParameter` scales them), each with
    a gain reading drawn from READINGS (seeded: the same seed, the same sets)."""
    rng = np.random.default_rng(seed)
    free = [estimation.FreeParameter.of(n) for n in FREE]
    out = [start]
    for _ in range(samples):
        z = rng.uniform(size=len(free))
        reading = float(rng.choice(READINGS))
        values = {p.name: p.from_z(zi) for p, zi in zip(free, z)}
        out.append(start.with_values({**values, "controller.command_scale": reading}))
    return out


def _best_start(model: estimation.ResidualModel, candidates: list[Params], ex: Workers,
                journal: estimation.ResidualJournal, progress: bool) -> Params:
    """The candidate of least cost (the first on ties: the given start)."""
    costs = []
    batch = 8 if ex.remote or ex.slots > 1 else 1
    started = time.perf_counter()
    for i in range(0, len(candidates), batch):
        chunk = candidates[i:i + batch]
        for r in estimation.evaluate(model, chunk, ex, journal=journal):
            costs.append(math.inf if r is None else 0.5 * float(r @ r))
        if progress:
            done = len(costs)
            left = (time.perf_counter() - started) / done * (len(candidates) - done)
            print(f"[calibrate] random search {done}/{len(candidates)}: start cost "
                  f"{costs[0]:.4f}, best sample {min(costs[1:], default=math.inf):.4f}, "
                  f"{left / 60:.1f} min left", file=sys.stderr, flush=True)
    best = int(np.argmin(costs))
    if not math.isfinite(costs[best]):
        raise ParameterError("the simulation fails at the start values and every sample")
    return candidates[best]


def calibrate(*, out: Path | None = None, jobs: int = 2, dt: float = 1e-3,
              progress: bool = True, start: Params | None = None, samples: int = 0,
              seed: int = 7, max_nfev: int = 6, resume: bool = False,
              protocol: Protocol = SHIPPED, robust: int = 0,
              feedforward: str = "calibrated") -> CalibrationResult:
    """Fit FREE to `PaperTargets` (module docstring) and write the TOML to `out` (None: do
    not write).

    Args:
      start: where the search starts (default: the shipped calibration).
      samples: random samples of the plausible ranges scored before the least-squares
        search, which starts from the best of them and `start` (0: from `start`).
      seed: the random search's seed.
      max_nfev: most least-squares steps (each also runs a Jacobian: len(FREE) + 1 sets).
      resume: replay the journal of an interrupted fit to `out` (evaluations already run
        are not run again).
      protocol: the static ramps' readings (`wpam_mj.experiments.protocol`) Table 2 is
        measured with.
      robust: fit each parameter set on itself and `robust` plants sampled within +-5 %
        of its unmeasured values (`RobustTargets`; 0: the set alone).
      feedforward: the controller's equilibrium model each set is scored with:
        "calibrated", fitted to the set's own open loops first, as `wpam reproduce` runs
        it (`CalibratedTargets`); "nominal", the set's own values.
    """
    check_range("samples", samples, *SAMPLES_RANGE, "")
    check_range("max_nfev", max_nfev, *NFEV_RANGE, "")
    check_int("seed", seed, 0, 2**32 - 1)
    check_int("robust", robust, 0, 64)
    feedforward_fit.check_feedforward_model(feedforward)
    params = start if start is not None else preset("wpam")
    journal_file = None if out is None else journal_path(Path(out), robust, feedforward)
    if resume and (journal_file is None or not journal_file.exists()):
        raise ParameterError(f"--resume: no journal {journal_file} of an interrupted fit")
    journal = estimation.ResidualJournal(journal_file, keep=resume)
    model = PaperTargets(dt, protocol)
    if feedforward == "calibrated":
        model = CalibratedTargets(model)
    fitted_model = (RobustTargets(model, robustness.sample_deviations(robust,
                                                                       robustness.ROBUST_SEED))
                    if robust else model)
    started = time.perf_counter()
    with open_workers(jobs) as ex:
        if samples:
            params = _best_start(fitted_model, random_starts(params, samples, seed), ex,
                                 journal, progress)
        free = [estimation.FreeParameter.of(n) for n in FREE]
        fit = estimation.fit(fitted_model, params, free, executor=ex, max_nfev=max_nfev,
                             diff_step=DIFF_STEP, progress=progress, journal=journal)
        (first,) = estimation.evaluate(fitted_model, [params], ex, journal=journal)
        tasks = model.tasks(fit.params)  # once more, for the figures behind the residuals
        results = execute(tasks, ex)
    # the fit, then the protocol readings it started from (written with it)
    fitted = {n: fit.params.value(n) for n in (*FREE, *KEPT)}
    result = CalibrationResult(fit.params, fitted, cost=0.5 * float(fit.residuals @ fit.residuals),
                               start_cost=0.5 * float(first @ first),
                               scores=model.scores(fit.params, results),
                               evaluations=journal.size, seconds=time.perf_counter() - started)
    if out is not None:
        write_text_atomic(out, result.toml())
        journal.remove()
    return result
