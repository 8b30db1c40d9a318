"""Global search of the credible box and the protocol readings.

One point of the search is a parameter set (the credible ranges of `calibrate.FREE`,
`wpam_mj.physics.params`) together with the readings the paper does not state: the Pi
feedforward's nominal Po and share phi of the friction band, the gain reading, and the
static ramps' `wpam_mj.experiments.protocol.Protocol` (ramp top per load or common, ramp time, hold
at the top with Po on, loop-area definition). Each point is scored on calibrate's one
cost (`calibrate.PaperTargets`, 1/2 |r|^2) and keeps the signed margin of every finding
(`FINDINGS`), in units of each margin's scale (>= 0 holds), so that the archive of the
search is also a measured feasibility map (`wpam_mj.reproduction.findings_map`).

The optimiser is scipy's `differential_evolution` (Storn & Price 1997): Latin-hypercube
start plus the shipped point, generations evaluated together ("deferred" updating) on a
process pool, categorical readings as integer coordinates. Seeded and deterministic:
the simulator is, results come back in task order, and the same seed draws the same
trials. After DE, each finding's best point is scored once more with each static-ramp
reading flipped (`probes`): DE meets a categorical value per point, so a reading
that helps one finding may not have been tried where that finding is best. Every
evaluation is appended to a JSON-lines journal, so a search run again
with `resume=True` replays what it has done without running it and continues.

The regulators' lag and dead time and the slide damping stay at their measured values
(`wpam_mj.physics.params`): they are identified, not free, and docs/physics.md measured them
to move the step errors without a trend.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import resource
import sys
import time
from concurrent.futures import Executor
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np
from scipy.optimize import differential_evolution

from wpam_mj import paper
from wpam_mj.reproduction import findings
from wpam_mj.fitting import estimation
from wpam_mj.infra.pool import executor_for
from wpam_mj.reproduction.calibrate import FREE, READINGS, PaperTargets
from wpam_mj.simulation.loop_contract import SimulationDiverged
from wpam_mj.physics.params import MPA, Params, ParameterError, check_range, preset
from wpam_mj.experiments.protocol import LOOP_METHODS, Protocol
from wpam_mj.infra.files import write_text_atomic

PHYSICAL = tuple(n for n in FREE if n != "controller.feedforward_friction")
PO_FF_RANGE_MPA = (0.005, 0.04)  # from p_min to the Po of Fig. 9
PHI_RANGE = (0.0, 1.05)  # params' plausible range of controller.feedforward_friction
RAMP_TOP_RANGE_MPA = (0.08, 0.45)  # a common top: below it 150 N barely contracts
RAMP_TIME_RANGE_S = (30.0, 120.0)  # "slow" ramps; 60 s vs 240 s moved Table 2 by <= 3 %
TOP_HOLD_RANGE_S = (0.0, 5.0)
STEP_ERROR_MM, STEP_PP_MM = 0.5, 0.2  # the paper's smooth, settled steps (docs/physics.md)
PO_RISE_SCALE_MPA = 0.01
TRACK_MM = 5.0  # half a 10 mm step: a PI staircase worse than this does not follow it
FAILED_COST = 1e6  # DE needs a finite cost where a simulation fails
SEARCH_DT = 1e-3  # s, the physics step of every evaluation (as reproduce)


@dataclass(frozen=True)
class Dim:
    """One coordinate: a parameter "section.field" or a protocol field, searched on
    [lo, hi] (log: as log(value)), or one of `choices` (an integer coordinate)."""

    name: str
    lo: float = 0.0
    hi: float = 1.0
    log: bool = False
    choices: tuple = ()

    @property
    def bounds(self) -> tuple[float, float]:
        return (0.0, len(self.choices) - 1.0) if self.choices else (0.0, 1.0)

    def value(self, u: float):
        if self.choices:
            return self.choices[int(round(u))]
        if self.log:
            return math.exp(math.log(self.lo) + u * (math.log(self.hi) - math.log(self.lo)))
        return self.lo + u * (self.hi - self.lo)

    def coordinate(self, value) -> float:
        if self.choices:
            return float(self.choices.index(value))
        if self.log:
            return (math.log(value) - math.log(self.lo)) / (math.log(self.hi) - math.log(self.lo))
        return (value - self.lo) / (self.hi - self.lo)


def _physical_dims() -> list[Dim]:
    out = []
    for name in PHYSICAL:
        f = estimation.FreeParameter.of(name)
        out.append(Dim(name, f.lo, f.hi, f.log))
    return out


SPACE = (*_physical_dims(),
         Dim("controller.feedforward_friction", *PHI_RANGE),
         Dim("controller.po_feedforward", PO_FF_RANGE_MPA[0] * MPA, PO_FF_RANGE_MPA[1] * MPA),
         Dim("controller.command_scale", choices=READINGS),
         Dim("protocol.common_top", choices=(False, True)),
         Dim("protocol.ramp_top", RAMP_TOP_RANGE_MPA[0] * MPA, RAMP_TOP_RANGE_MPA[1] * MPA),
         Dim("protocol.ramp_time", *RAMP_TIME_RANGE_S, log=True),
         Dim("protocol.top_hold", *TOP_HOLD_RANGE_S),
         Dim("protocol.loop_method", choices=LOOP_METHODS))


@dataclass(frozen=True)
class Point:
    """A parameter set and a protocol."""

    params: Params
    protocol: Protocol

    def values(self) -> dict[str, object]:
        """Every coordinate of SPACE by name (protocol fields as "protocol.<name>")."""
        out: dict[str, object] = {d.name: self.params.value(d.name) for d in SPACE
                                  if not d.name.startswith("protocol.")}
        pr = self.protocol
        out.update({"protocol.common_top": pr.ramp_top != 0.0,
                    "protocol.ramp_top": pr.ramp_top, "protocol.ramp_time": pr.ramp_time,
                    "protocol.top_hold": pr.top_hold, "protocol.loop_method": pr.loop_method})
        return out


def point_of(u: Sequence[float], base: Params) -> Point:
    """The point at coordinates `u` (one per SPACE dim) on top of `base`."""
    v = {d.name: d.value(x) for d, x in zip(SPACE, u)}
    protocol = Protocol(ramp_top=float(v["protocol.ramp_top"]) if v["protocol.common_top"]
                        else 0.0,
                        ramp_time=float(v["protocol.ramp_time"]),
                        top_hold=float(v["protocol.top_hold"]),
                        loop_method=str(v["protocol.loop_method"]))
    params = base.with_values({k: float(x) for k, x in v.items()
                               if not k.startswith("protocol.")})
    return Point(params, protocol)


def coordinates_of(point: Point) -> np.ndarray:
    """The inverse of `point_of` (a per-load top keeps the middle of the top's range)."""
    v = point.values()
    if not v["protocol.common_top"]:
        v["protocol.ramp_top"] = 0.5 * sum(RAMP_TOP_RANGE_MPA) * MPA
    u = np.array([d.coordinate(v[d.name]) for d in SPACE])
    return np.clip(u, [d.bounds[0] for d in SPACE], [d.bounds[1] for d in SPACE])


# ---- scoring: the cost and every finding's signed margin

# The findings of `wpam reproduce` (`findings.FINDINGS`), then two the paper shows without a
# number: settled steps (Figs. 12-15) and Po rising with load (Fig. 15, §4.2).
FINDING_TEXT = {**{name: f.short for name, f in findings.FINDINGS.items()},
                "steps_settle": "steps settle: error <= 0.5 mm, p-p <= 0.2 mm",
                "po_rises_with_load": "plateau-mean Po rises with load"}
FINDINGS = tuple(FINDING_TEXT)


def _worst(margins) -> float:
    return min(m.margin / m.scale for m in margins)


def finding_margins(scores, table2) -> dict[str, float]:
    """Each finding's worst margin in units of its scale (>= 0: holds)."""
    checks = [*findings.table2_checks(table2), *scores.sweep_checks]
    out = {c.name: _worst(c.margins) for c in checks}
    steps = [min((STEP_ERROR_MM - e) / STEP_ERROR_MM, (STEP_PP_MM - p) / STEP_PP_MM)
             for c in scores.step_error_mm
             for e, p in zip(scores.step_error_mm[c], scores.step_pp_mm[c])]
    po = scores.po_plateau_mpa
    out["steps_settle"] = min(steps)
    out["po_rises_with_load"] = min((b - a) / PO_RISE_SCALE_MPA for a, b in zip(po, po[1:]))
    return out


@dataclass(frozen=True)
class Record:
    """One evaluated point: coordinates, cost, margins (None: failed) and the figures."""

    u: tuple[float, ...]
    cost: float
    margins: dict[str, float] | None
    figures: dict | None

    @property
    def tracks(self) -> bool:
        """Whether the point ran and its PI staircase follows the targets at all. A muscle
        that never moves meets the feedback row vacuously (no loop): such points are not
        reproductions of the experiments and stay out of the map and the choice."""
        return self.margins is not None and \
            max(self.figures["step_error_mm"]["pi"]) <= TRACK_MM

    @property
    def held(self) -> int:
        return 0 if self.margins is None else sum(m >= 0.0 for m in self.margins.values())

    def as_json(self) -> dict:
        return {"u": list(self.u), "cost": self.cost, "margins": self.margins,
                "figures": self.figures}

    @classmethod
    def from_json(cls, d: dict) -> "Record":
        return cls(tuple(d["u"]), d["cost"], d["margins"], d["figures"])


def _figures(scores) -> dict:
    """The numbers a reader checks a point by (display units)."""
    return {"table2_po_row": list(scores.table2_po_row),
            "feedback_row": list(scores.feedback_row),
            "step_error_mm": {c: list(v) for c, v in scores.step_error_mm.items()},
            "step_pp_mm": {c: list(v) for c, v in scores.step_pp_mm.items()},
            "po_plateau_mpa": list(scores.po_plateau_mpa),
            "failed": list(scores.sweep_failed)}


@dataclass(frozen=True)
class Targets:
    """The paper's targets under one protocol: `tasks` to run, `score` of their results
    as (residual vector of calibrate's cost, finding margins, figures)."""

    dt: float
    protocol: Protocol

    def tasks(self, params: Params) -> list:
        return PaperTargets(self.dt, self.protocol).tasks(params)

    def score(self, params: Params, results: list):
        model = PaperTargets(self.dt, self.protocol)
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


# ---- evaluation: parallel over every run of a generation, journaled


def _key(u: Sequence[float]) -> str:
    return hashlib.sha256(repr([round(float(x), 12) for x in u]).encode()).hexdigest()[:24]


class Journal:
    """Records by coordinates, appended as JSON lines to `path` (None: in memory)."""

    def __init__(self, path: Path | None, keep: bool) -> None:
        self.path, self.records = path, {}
        if path is None:
            return
        if keep and path.exists():
            for line in path.read_text().splitlines():
                try:
                    d = json.loads(line)
                except ValueError:
                    continue  # a line cut by the interruption: run it again
                self.records[d["key"]] = Record.from_json(d)
        else:
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text("")

    def add(self, key: str, rec: Record) -> None:
        self.records[key] = rec
        if self.path is not None:
            with self.path.open("a") as fh:
                fh.write(json.dumps({"key": key, **rec.as_json()}) + "\n")


def _run(task):
    try:
        return estimation.run_task(task)
    except (SimulationDiverged, ParameterError, ArithmeticError):
        return None


class Evaluator:
    """Scores lists of coordinates: journaled points are replayed, the rest run together
    on `executor`, longest runs first (None: here, one after the other)."""

    def __init__(self, base: Params, journal: Journal, executor: Executor | None,
                 targets=None, progress: bool = False, planned: int = 0) -> None:
        self.base, self.journal, self.executor = base, journal, executor
        # targets(protocol) -> `Targets`-like (a cheap stand-in in the smoke test)
        self.targets = targets or (lambda protocol: Targets(SEARCH_DT, protocol))
        self.progress, self.planned = progress, planned
        # points run together: enough runs to keep every worker busy, few enough that
        # an interruption loses little
        self.chunk = 4
        self.ran, self.seen, self.started = 0, 0, time.perf_counter()
        self.asked: dict[str, None] = {}  # keys scored, in order (a journal may hold more)

    def records(self, us: Sequence[Sequence[float]]) -> list[Record]:
        keys = [_key(u) for u in us]
        self.asked.update(dict.fromkeys(keys))
        todo = {k: u for k, u in zip(keys, us) if k not in self.journal.records}
        self.seen += len(us) - len(todo)
        pending = list(todo)
        for i in range(0, len(pending), self.chunk):  # journaled chunk by chunk
            chunk = pending[i:i + self.chunk]
            for k, rec in zip(chunk, self._run([todo[k] for k in chunk])):
                self.journal.add(k, rec)
            self.seen += len(chunk)
            self.ran += len(chunk)
            self._report()
        return [self.journal.records[k] for k in keys]

    def costs(self, func, us) -> list[float]:
        """The map-like `workers` of `differential_evolution` (func: its own wrapper of
        `cost`, replaced here by the batched, journaled evaluation)."""
        return [r.cost for r in self.records([list(u) for u in us])]

    def _run(self, us: list) -> list[Record]:
        points, groups = [], []
        for u in us:
            try:
                p = point_of(u, self.base)
                groups.append(self.targets(p.protocol).tasks(p.params))
            except ParameterError:
                p = None
                groups.append([])
            points.append(p)
        flat = sorted(((g, i, t) for g, ts in enumerate(groups) for i, t in enumerate(ts)),
                      key=lambda x: -x[2].cost)
        if self.executor is None:
            done = {(g, i): _run(t) for g, i, t in flat}
        else:
            futs = {(g, i): self.executor.submit(_run, t) for g, i, t in flat}
            done = {k: f.result() for k, f in futs.items()}
        out = []
        for g, (u, p) in enumerate(zip(us, points)):
            res = [done[g, i] for i in range(len(groups[g]))]
            ok = p is not None and all(r is not None for r in res)
            cost, margins, figs = (score(self.targets(p.protocol), p.params, res) if ok
                                   else score(None, None, None))
            out.append(Record(tuple(float(x) for x in u), cost, margins, figs))
        return out

    def _report(self) -> None:
        if not self.progress:
            return
        elapsed = time.perf_counter() - self.started
        best = min((r.cost for r in self.journal.records.values()), default=math.inf)
        rate = elapsed / self.ran if self.ran else 0.0
        left = max(0, self.planned - self.seen) * rate
        print(f"[search] {self.seen}/{self.planned} points ({self.ran} run, "
              f"{elapsed / 60:.1f} min), best cost {best:.4f}, ~{left / 60:.1f} min left",
              file=sys.stderr, flush=True)


def cost(u, evaluator: Evaluator) -> float:
    """One point's cost (what DE would call without `workers`)."""
    return evaluator.records([list(u)])[0].cost


# ---- the search


@dataclass(frozen=True)
class SearchResult:
    best: Record
    records: tuple[Record, ...]  # every point this search scored, in order
    evaluations: int
    seconds: float
    message: str


def planned_evaluations(popsize: int, maxiter: int) -> int:
    """Points scored: DE's initial population, `maxiter` generations of it, its best
    once more and at most the `probes`."""
    n = max(5, popsize * len(SPACE))
    return n * (maxiter + 1) + 1 + len(PROBED) * (len(FINDINGS) + len(paper.LOADS_N))


def search(out: Path | None, *, base: Params | None = None, seed: int = 20,
           popsize: int = 2, maxiter: int = 5, jobs: int = 2, resume: bool = False,
           progress: bool = True, targets=None) -> SearchResult:
    """Run DE over SPACE from the start point (`base`, default the wpam preset, with the
    default readings `Protocol()`), journaling to `out`/journal.jsonl (None: in memory).

    popsize: DE's multiplier (population popsize * len(SPACE)); maxiter: generations;
    targets: protocol -> `Targets` (default: the paper's, at SEARCH_DT).
    """
    check_range("popsize", popsize, 1, 100)
    check_range("maxiter", maxiter, 0, 1000)
    check_range("seed", seed, 0, 2**32 - 1)
    base = base if base is not None else preset("wpam")
    path = None if out is None else Path(out) / "journal.jsonl"
    if resume and (path is None or not path.exists()):
        raise ParameterError(f"--resume: no journal {path} of an interrupted search")
    journal = Journal(path, keep=resume)
    started = time.perf_counter()
    with executor_for(jobs) as ex:
        ev = Evaluator(base, journal, ex, targets, progress,
                       planned_evaluations(popsize, maxiter))
        res = differential_evolution(
            cost, [d.bounds for d in SPACE], args=(ev,), seed=seed, popsize=popsize,
            maxiter=maxiter, tol=0.0, polish=False, init="latinhypercube",
            updating="deferred", workers=ev.costs,
            integrality=[bool(d.choices) for d in SPACE],
            x0=coordinates_of(Point(base, Protocol())))
        (best,) = ev.records([list(res.x)])
        ev.records(probes([journal.records[k] for k in ev.asked]))
    records = tuple(journal.records[k] for k in ev.asked)
    return SearchResult(best, records, len(records), time.perf_counter() - started,
                        str(res.message))


# The static ramps' categorical readings: DE draws them per point, so a finding's best
# point has met only one value of each; `probes` tries the other at that point.
PROBED = ("protocol.loop_method", "protocol.common_top")


def _cell_error(r: Record, k: int) -> float:
    """|relative error| of Table 2 "Po = 0.04" cell k (load paper.LOADS_N[k])."""
    ref = paper.TABLE2["open_po"][paper.LOADS_N[k]]
    return abs(r.figures["table2_po_row"][k] / ref - 1.0)


def probes(records: Sequence[Record]) -> list[list[float]]:
    """Each finding's best tracking point, then the best point of each Table 2 "Po =
    0.04" cell (the row's margin is its worst cell: a point that gets one end of the
    row right is where a reading may bring the rest), each with one `PROBED` reading
    flipped (the common top keeps the point's own top coordinate)."""
    tracking = [r for r in records if r.tracks]
    bests = dict.fromkeys([max(tracking, key=lambda r: r.margins[f]).u for f in FINDINGS]
                          + [min(tracking, key=lambda r: _cell_error(r, k)).u
                             for k in range(len(paper.LOADS_N))])
    out = []
    for u in bests:
        for name in PROBED:
            i = [d.name for d in SPACE].index(name)
            v = list(u)
            v[i] = 1.0 - round(u[i])
            out.append(v)
    return out


def load_records(out: Path) -> list[Record]:
    """Every record of the journal in `out` (a finished or interrupted search)."""
    return list(Journal(Path(out) / "journal.jsonl", keep=True).records.values())


def describe_point(u: Sequence[float], base: Params) -> str:
    """The point's values, one per line (display units)."""
    p = point_of(u, base)
    lines = [f"  {k:<34s} {v:.6g}" if isinstance(v, float) else f"  {k:<34s} {v}"
             for k, v in p.values().items()]
    return "\n".join(lines + [f"  protocol: {p.protocol.describe()}"])


def at_bounds(u: Sequence[float], tol: float = 1e-3) -> list[str]:
    """The continuous coordinates within `tol` of a bound of their range."""
    return [d.name for d, x in zip(SPACE, u) if not d.choices
            and (x <= d.bounds[0] + tol or x >= d.bounds[1] - tol)]



def write_search(out: Path, **kw) -> list[Path]:
    """`search` into `out`, then `write_outputs` of its archive."""
    load0, cpu0 = os.getloadavg()[0], _cpu_seconds()
    r = search(out, **kw)
    timing = (f"{r.evaluations} points in {r.seconds / 60:.1f} min wall, "
              f"{(_cpu_seconds() - cpu0) / 60:.1f} CPU-min (load average {load0:.2f} at "
              f"the start, {os.getloadavg()[0]:.2f} at the end); {r.message}")
    return write_outputs(out, r.records, kw.get("base") or preset("wpam"), timing)


def _cpu_seconds() -> float:
    """CPU time of this process and its finished workers [s] (the machine is shared:
    wall time alone says more about the others' load than about the search)."""
    own, kids = resource.getrusage(resource.RUSAGE_SELF), \
        resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


def write_outputs(out: Path, records: Sequence[Record], base: Params,
                  timing: str = "") -> list[Path]:
    """The best compromise of `records` (best.toml, best.txt) and their feasibility map
    (feasibility.md, feasibility.png) in `out`."""
    from wpam_mj.reproduction import findings_map  # noqa: PLC0415 (it imports this module)

    pm = findings_map.pair_margins(records)
    best = findings_map.best_compromise(records)
    most = findings_map.most_findings(records)
    return [write_text_atomic(out / "best.toml", point_toml(point_of(best.u, base))),
            write_text_atomic(out / "best.txt", summary(timing, best, base) + "\n"
                              + "the point meeting the most findings:\n"
                              + summary("", most, base)),
            write_text_atomic(out / "feasibility.md", findings_map.markdown(pm, records)
                              + "\n\n" + findings_map.verdict(pm) + "\n"),
            findings_map.figure(pm, out / "feasibility.png",
                                f"Feasibility of the paper's findings: {len(records)} "
                                "points of the credible box and protocol readings")]


def point_toml(point: Point) -> str:
    """The point's parameter values as a `--config` TOML and its protocol as comments."""
    sections: dict[str, list[str]] = {}
    for name, v in point.values().items():
        if not name.startswith("protocol."):
            s, n = name.split(".")
            sections.setdefault(s, []).append(f"{n} = {float(v)!r}")
    out = ["# Found by `wpam search` (wpam_mj/reproduction/search.py); SI units.",
           f"# protocol: {point.protocol.describe()}", ""]
    for s, lines in sections.items():
        out += [f"[{s}]", *lines, ""]
    return "\n".join(out)


def summary(timing: str, best: Record, base: Params) -> str:
    """A point of the search and its findings (plain text)."""
    return (f"{timing}\n" * bool(timing)
            + f"cost {best.cost:.4f}, {best.held} of {len(FINDINGS)} findings met\n"
            + describe_point(best.u, base)
            + f"\nat a bound: {', '.join(at_bounds(best.u)) or 'none'}"
            + "\nmargins:\n" + "\n".join(f"  {k:<24s} {v:+.3f}"
                                         for k, v in (best.margins or {}).items())
            + f"\nfigures: {json.dumps(best.figures)}\n")
