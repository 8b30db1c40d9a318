"""Global search of the credible box for a plant that meets the paper's findings.

A point is a parameter set of the credible ranges (`calibrate.FREE`,
`wpam_mj.physics.params`) and the one Pi ramp top the paper does not state; the other
static-ramp readings are the shipped ones (`wpam_mj.experiments.protocol.SHIPPED`: one
ramp for every load, 60 s each way, every loop lobe counted). Two stages:

  * a quasi-static screen (`wpam_mj.reproduction.static_fit`): the open-loop loops of
    Table 2 follow from the equilibrium model alone in milliseconds, within a few per
    cent of the simulated ones; for each point the friction coefficient, the axial area
    and the ramp top are fitted there to the "Po = 0.04" row, so every point the search
    simulates already lies on the narrow strip where that row holds, and a point no
    static fit brings within the row's tolerance is scored without simulating it;
  * the dynamic findings: scipy's `differential_evolution` (Storn & Price 1997) over the
    remaining coordinates, each in [0, 1] of its range, Latin-hypercube start (no known
    point given), generations evaluated together ("deferred" updating) on a process pool,
    each point scored on calibrate's one cost (`calibrate.PaperTargets`, 1/2 |r|^2) with
    the signed margin of every finding (`FINDINGS`, in units of each margin's scale,
    >= 0 holds), so that the archive is also a measured feasibility map
    (`wpam_mj.reproduction.findings_map`) and `convergence` shows how the search got there.

Seeded and deterministic: the simulator is, results come back in task order, and the same
seed draws the same trials. Every evaluation is appended to a JSON-lines journal, so a
search run again with `resume=True` replays what it has done without running it and
continues. The regulators' lag and dead time and the slide damping stay at their measured
values (`wpam_mj.physics.params`): they are identified, not free. The gain reading stays
the shipped one (volts on the regulator's 0-5 V input; docs/physics.md).
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
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Callable, Sequence

import numpy as np
from scipy.optimize import differential_evolution

from wpam_mj.paper import CALIBRATION_HEADROOM, TABLE2_PO_RTOL
from wpam_mj.reproduction import findings
from wpam_mj.fitting import estimation
from wpam_mj.infra.pool import executor_for
from wpam_mj.reproduction.calibrate import FREE, PaperTargets
from wpam_mj.physics.params import Params, ParameterError, check_range, preset
from wpam_mj.experiments.protocol import SHIPPED, Protocol
from wpam_mj.reproduction.static_fit import STATIC_FIT, static_fit
from wpam_mj.infra.files import write_text_atomic

PO_RISE_SCALE_MPA = 0.01
STEP_PP_MM = 0.2  # a converged plateau (Fig. 14: "quickly converges"); our reading
TRACK_MM = 5.0  # half a 10 mm step: a PI staircase worse than this does not follow it
FAILED_COST = 1e6  # DE needs a finite cost where a simulation fails
STATIC_MISS_COST = 1e3  # ... and where the screen finds no static fit (plus its error)
SEARCH_DT = 1e-3  # s, the physics step of every evaluation (as reproduce)
POPSIZE, MAXITER = 3, 8  # `wpam search`'s defaults: 21 points a generation, 9 generations


# The searched coordinates: every fitted parameter but those the static fit places, each
# on its plausible range (conductances in log scale), as `wpam calibrate` frees them.
SPACE = tuple(estimation.FreeParameter.of(n) for n in FREE if n not in STATIC_FIT)


def keep_static(params: Params, protocol: Protocol) -> tuple[Params, Protocol, float]:
    """No static fit: the static plant and the ramp top stay the base point's (a local
    search of the dynamic readings; the Po row is then checked by simulation alone)."""
    return params, protocol, 0.0


@dataclass(frozen=True)
class Region:
    """What a search varies: `names`, each on its plausible range scaled to [0, 1]
    (`estimation.FreeParameter`), and the `fit` every point gets, (params, protocol) ->
    (params, protocol, static error)."""

    names: tuple[str, ...]
    fit: Callable = static_fit

    @property
    def dims(self) -> tuple[estimation.FreeParameter, ...]:
        return tuple(estimation.FreeParameter.of(n) for n in self.names)


# `wpam search`'s default: the whole box, every point on the Po row's strip
GLOBAL = Region(tuple(d.name for d in SPACE))


@dataclass(frozen=True)
class Point:
    """A parameter set and a protocol; `static_error` is the worst relative error of the
    quasi-static Table 2 "Po = 0.04" row its static fit reached (`static_fit`);
    `searched`: the names its search varied."""

    params: Params
    protocol: Protocol
    static_error: float = 0.0
    searched: tuple[str, ...] = GLOBAL.names

    def values(self) -> dict[str, object]:
        """Every searched and statically fitted value by name, and the ramp top."""
        out: dict[str, object] = {n: self.params.value(n) for n in self.searched}
        out.update({n: self.params.value(n) for n in STATIC_FIT})
        out["protocol.ramp_top"] = self.protocol.ramp_top
        return out


_POINTS: dict[tuple, Point | None] = {}  # (u, base, region) -> point: each fitted once


def _point_task(arg: tuple) -> Point | None:
    """The point at (u, base) in `region`, with the region's fit, None where its
    parameters are refused (a worker task)."""
    u, base, region = arg
    v = {d.name: d.from_z(x) for d, x in zip(region.dims, u)}
    try:
        params, protocol, err = region.fit(base.with_values(v), SHIPPED)
    except (ParameterError, ArithmeticError):
        return None
    return Point(params, protocol, err, region.names)


def point_of(u: Sequence[float], base: Params, region: Region = GLOBAL) -> Point:
    """The point at coordinates `u` (one per dim of `region`, in [0, 1]) on top of
    `base`, with its fit (computed once per point)."""
    key = (tuple(float(x) for x in u), base, region)
    if key not in _POINTS:
        _POINTS[key] = _point_task(key)
    point = _POINTS[key]
    if point is None:
        raise ParameterError("the point's parameters are refused")
    return point


def coordinates_of(params: Params, region: Region = GLOBAL) -> np.ndarray:
    """The searched coordinates of a parameter set."""
    return np.array([d.to_z(params.value(d.name)) for d in region.dims])


# ---- scoring: the cost and every finding's signed margin

# The findings of `wpam reproduce` (`findings.FINDINGS`), then two the paper shows without a
# number: settled steps (Figs. 12-15) and Po rising with load (Fig. 15, §4.2).
FINDING_TEXT = {**{name: f.short for name, f in findings.FINDINGS.items()},
                "steps_settle": "PI steps settle: error <= Table 2's split, p-p <= 0.2 mm",
                "po_rises_with_load": "plateau-mean Po rises with load"}
FINDINGS = tuple(FINDING_TEXT)
PAPER_CHECKS = tuple(findings.FINDINGS)  # the eight that `wpam reproduce` checks


def _worst(margins) -> float:
    return min(m.margin / m.scale for m in margins)


def finding_margins(scores, table2) -> dict[str, float]:
    """Each finding's worst margin in units of its scale (>= 0: holds)."""
    checks = [*findings.table2_checks(table2), *scores.sweep_checks]
    out = {c.name: _worst(c.margins) for c in checks}
    steps = [min((lim - e) / lim, (STEP_PP_MM - p) / STEP_PP_MM)
             for e, p, lim in zip(scores.step_error_mm["pi"], scores.step_pp_mm["pi"],
                                  scores.step_limit_mm)]
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
        return 0 if self.margins is None else sum(self.margins[f] >= 0.0
                                                  for f in PAPER_CHECKS)

    def as_json(self) -> dict:
        return {"u": list(self.u), "cost": self.cost, "margins": self.margins,
                "figures": self.figures, "seconds": self.seconds}

    @classmethod
    def from_json(cls, d: dict) -> "Record":
        return cls(tuple(d["u"]), d["cost"], d["margins"], d["figures"], d.get("seconds"))


# ---- objectives: what DE minimises (journals keep margins, so either replays any journal)

SHORTFALL_CAP = 3.0  # scale units: one far miss counts as three near ones, no more


def shortfall(rec: Record, wanted: Sequence[str] = (*PAPER_CHECKS, "steps_settle")) -> float:
    """The "checks" objective: how far the point falls short of every check of `wpam
    reproduce` and of settled PI steps (or of the findings `wanted`), each shortfall in
    units of its margin's scale measured from CALIBRATION_HEADROOM past its limit and
    capped at SHORTFALL_CAP (0: all met with headroom). Unlike calibrate's cost it asks
    no more of a finding than its check does, so a point's value falls only by meeting
    checks."""
    if rec.margins is None:
        return rec.cost  # failed or screened out: the same large cost as "cost"
    return sum(min(max(0.0, CALIBRATION_HEADROOM - rec.margins[f]), SHORTFALL_CAP)
               for f in wanted)


def findings_shortfall(rec: Record) -> float:
    """The "findings" objective: the checks' shortfall with every finding of FINDINGS
    asked, Po rising with load among them (what "checks" may trade away)."""
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


class Evaluator:
    """Scores lists of coordinates: journaled points are replayed, the rest run together
    on `executor`, longest runs first (None: here, one after the other)."""

    def __init__(self, base: Params, journal: Journal, executor: Executor | None,
                 targets=None, progress: bool = False, planned: int = 0,
                 region: Region = GLOBAL, objective: str = "cost") -> None:
        self.base, self.journal, self.executor = base, journal, executor
        self.region = region
        self.objective = OBJECTIVES[objective]  # Record -> the value DE minimises
        # targets(protocol) -> `Targets`-like (a cheap stand-in in the smoke test)
        self.targets = targets or (lambda protocol: Targets(SEARCH_DT, protocol))
        self.progress, self.planned = progress, planned
        # points run together: enough runs to keep every worker busy, few enough that
        # an interruption loses little
        self.chunk = 4
        # a resumed search's clock goes on from its journal's last point
        done = max((r.seconds or 0.0 for r in journal.records.values()), default=0.0)
        self.ran, self.seen, self.started = 0, 0, time.perf_counter() - done
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
                self.journal.add(k, replace(rec, seconds=time.perf_counter() - self.started))
            self.seen += len(chunk)
            self.ran += len(chunk)
            self._report()
        return [self.journal.records[k] for k in keys]

    def costs(self, func, us) -> list[float]:
        """The map-like `workers` of `differential_evolution` (func: its own wrapper of
        `cost`, replaced here by the batched, journaled evaluation)."""
        return [self.objective(r) for r in self.records([list(u) for u in us])]

    def _run(self, us: list) -> list[Record]:
        points = self._points(us)
        groups = [self.targets(p.protocol).tasks(p.params)
                  if p is not None and p.static_error <= TABLE2_PO_RTOL else [] for p in points]
        flat = sorted(((g, i, t) for g, ts in enumerate(groups) for i, t in enumerate(ts)),
                      key=lambda x: -x[2].cost)
        from wpam_mj.simulation.execution import execute  # noqa: PLC0415 (the one layer)
        done = dict(zip([(g, i) for g, i, _ in flat],
                        execute([t for _, _, t in flat], self.executor, failed=None)))
        out = []
        for g, (u, p) in enumerate(zip(us, points)):
            res = [done[g, i] for i in range(len(groups[g]))]
            if p is not None and not groups[g]:  # screened out: never simulated
                out.append(Record(tuple(float(x) for x in u),
                                  STATIC_MISS_COST * (1.0 + p.static_error), None,
                                  {"static_error": p.static_error}))
                continue
            ok = p is not None and all(r is not None for r in res)
            cost, margins, figs = (score(self.targets(p.protocol), p.params, res) if ok
                                   else score(None, None, None))
            out.append(Record(tuple(float(x) for x in u), cost, margins, figs))
        return out

    def _points(self, us: list) -> list[Point | None]:
        """Each coordinate's point with its static fit, the fits run on the workers."""
        keys = [(tuple(float(x) for x in u), self.base, self.region) for u in us]
        todo = [k for k in dict.fromkeys(keys) if k not in _POINTS]
        fitted = (map(_point_task, todo) if self.executor is None
                  else self.executor.map(_point_task, todo))
        for k, point in zip(todo, fitted):
            _POINTS[k] = point
        return [_POINTS[k] for k in keys]

    def _report(self) -> None:
        if not self.progress:
            return
        elapsed = time.perf_counter() - self.started
        best = min((self.objective(r) for r in self.journal.records.values()),
                   default=math.inf)
        rate = elapsed / self.ran if self.ran else 0.0
        left = max(0, self.planned - self.seen) * rate
        print(f"[search] {self.seen}/{self.planned} points ({self.ran} run, "
              f"{elapsed / 60:.1f} min), best {best:.4f}, ~{left / 60:.1f} min left",
              file=sys.stderr, flush=True)


def cost(u, evaluator: Evaluator) -> float:
    """One point's objective (what DE would call without `workers`)."""
    return evaluator.objective(evaluator.records([list(u)])[0])


# ---- the search


@dataclass(frozen=True)
class SearchResult:
    best: Record
    records: tuple[Record, ...]  # every point this search scored, in order
    evaluations: int
    seconds: float
    message: str
    region: Region = GLOBAL


def planned_evaluations(popsize: int, maxiter: int, dims: int = len(SPACE)) -> int:
    """Points scored: DE's initial population, `maxiter` generations of it and its best
    once more (some of them screened out by their static fit, in milliseconds)."""
    return popsize * dims * (maxiter + 1) + 1


# What a local search may vary: the lines and the feedforward's readings; the rest of
# FREE is the static plant, which sets the Po row
LOCAL_READINGS = tuple(n for n in FREE if n.startswith(("pneumatics.", "controller.")))


def local_region(names: Sequence[str]) -> Region:
    """The dynamic readings `names` alone, without a static fit (`keep_static`)."""
    names = tuple(dict.fromkeys(names))
    for n in names:
        if n not in FREE:
            raise ParameterError(f"--free {n}: a search varies the fitted parameters, one "
                                 f"of {', '.join(FREE)}")
        if n not in LOCAL_READINGS:
            raise ParameterError(f"--free {n}: a local search keeps the static plant "
                                 f"(it sets the Po row); free only "
                                 f"{', '.join(LOCAL_READINGS)}")
    return Region(names, keep_static)


def search(out: Path | None, *, base: Params | None = None, seed: int = 20,
           popsize: int = POPSIZE, maxiter: int = MAXITER, jobs: int = 2,
           resume: bool = False, progress: bool = True, targets=None,
           fit=None, objective: str = "cost", free: Sequence[str] | None = None,
           radius: float = 0.25) -> SearchResult:
    """Run DE over SPACE, every coordinate drawn from its whole range (a Latin hypercube,
    not started from any known point): `base` (default: the wpam preset) gives only the
    parameters that are not searched. Journals to `out`/journal.jsonl (None: in memory).

    popsize: DE's multiplier (population popsize * dims); maxiter: generations;
    targets: protocol -> `Targets` (default: the paper's, at SEARCH_DT); fit: the static
    screen (default `static_fit`); objective: what DE minimises (OBJECTIVES).
    free: a local search instead (`local_region`): only these dynamic readings, in a box
    of +-`radius` (of each range) around `base`, whose point DE's first population holds.
    """
    if objective not in OBJECTIVES:
        raise ParameterError(f"objective = {objective!r} must be one of "
                             f"{', '.join(OBJECTIVES)}")
    check_range("popsize", popsize, 1, 100)
    check_range("maxiter", maxiter, 0, 1000)
    check_range("seed", seed, 0, 2**32 - 1)
    base = base if base is not None else preset("wpam")
    region = GLOBAL if free is None else local_region(free)
    region = region if fit is None else Region(region.names, fit)
    bounds, x0 = [(0.0, 1.0)] * len(region.names), None
    if free is not None:
        check_range("radius", radius, 0.0, 1.0, lo_open=True)
        x0 = coordinates_of(base, region)
        bounds = [(max(0.0, z - radius), min(1.0, z + radius)) for z in x0]
    path = None if out is None else Path(out) / "journal.jsonl"
    if resume and (path is None or not path.exists()):
        raise ParameterError(f"--resume: no journal {path} of an interrupted search")
    journal = Journal(path, keep=resume)
    started = time.perf_counter()
    with executor_for(jobs) as ex:
        ev = Evaluator(base, journal, ex, targets, progress,
                       planned_evaluations(popsize, maxiter, len(bounds)), region, objective)
        res = differential_evolution(
            cost, bounds, args=(ev,), seed=seed, popsize=popsize, x0=x0,
            maxiter=maxiter, tol=0.0, polish=False, init="latinhypercube",
            updating="deferred", workers=ev.costs)
        (best,) = ev.records([list(res.x)])
    records = tuple(journal.records[k] for k in ev.asked)
    return SearchResult(best, records, len(records), time.perf_counter() - started,
                        str(res.message), region)


def convergence(records: Sequence[Record],
                objective: str = "cost") -> list[tuple[int, float, int, float]]:
    """(points scored, least objective so far, most checks met so far by a point whose
    PI staircase tracks its targets: `Record.tracks`, as the map counts them, wall
    seconds into the search: NaN where the journal did not record it) after each point,
    in the order the search scored them."""
    out, cost, held = [], math.inf, 0
    for i, r in enumerate(records, 1):
        cost = min(cost, OBJECTIVES[objective](r))
        held = max(held, r.held if r.tracks else 0)
        out.append((i, cost, held, math.nan if r.seconds is None else r.seconds))
    return out


def load_records(out: Path) -> list[Record]:
    """Every record of the journal in `out` (a finished or interrupted search)."""
    return list(Journal(Path(out) / "journal.jsonl", keep=True).records.values())


def describe_point(u: Sequence[float], base: Params, region: Region = GLOBAL) -> str:
    """The point's values, one per line (display units)."""
    p = point_of(u, base, region)
    lines = [f"  {k:<34s} {v:.6g}" if isinstance(v, float) else f"  {k:<34s} {v}"
             for k, v in p.values().items()]
    return "\n".join(lines + [f"  protocol: {p.protocol.describe()}"])


def at_bounds(u: Sequence[float], base: Params, region: Region = GLOBAL,
              tol: float = 1e-3) -> list[str]:
    """The searched and statically fitted values within `tol` (of their range) of a
    bound of their range."""
    point = point_of(u, base, region)
    near = [d.name for d, x in zip(region.dims, u) if x <= tol or x >= 1.0 - tol]
    for name in STATIC_FIT:
        z = estimation.FreeParameter.of(name).to_z(point.params.value(name))
        if z <= tol or z >= 1.0 - tol:
            near.append(name)
    return near



def write_search(out: Path, **kw) -> list[Path]:
    """`search` into `out`, then `write_outputs` of its archive."""
    load0, cpu0 = os.getloadavg()[0], _cpu_seconds()
    r = search(out, **kw)
    timing = (f"{r.evaluations} points in {r.seconds / 60:.1f} min wall, "
              f"{(_cpu_seconds() - cpu0) / 60:.1f} CPU-min (load average {load0:.2f} at "
              f"the start, {os.getloadavg()[0]:.2f} at the end); {r.message}")
    return write_outputs(out, r.records, kw.get("base") or preset("wpam"), timing,
                         kw.get("objective", "cost"), r.region)


def _cpu_seconds() -> float:
    """CPU time of this process and its finished workers [s] (the machine is shared:
    wall time alone says more about the others' load than about the search)."""
    own, kids = resource.getrusage(resource.RUSAGE_SELF), \
        resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


def write_outputs(out: Path, records: Sequence[Record], base: Params,
                  timing: str = "", objective: str = "cost",
                  region: Region = GLOBAL) -> list[Path]:
    """The best compromise of `records` under `objective` (best.toml, best.txt), how the
    search converged (convergence.csv, convergence.png) and their feasibility map
    (feasibility.md, feasibility.png) in `out`."""
    from wpam_mj.reproduction import findings_map  # noqa: PLC0415 (it imports this module)

    conv = convergence(records, objective)
    written = [write_text_atomic(out / "convergence.csv", findings_map.convergence_csv(conv)),
               findings_map.convergence_figure(
                   {out.name: conv}, out / "convergence.png",
                   f"Convergence of the search: {len(records)} points, "
                   f"{sum(r.margins is not None for r in records)} simulated",
                   OBJECTIVE_TEXT[objective])]
    if not any(r.tracks for r in records):
        return written  # nothing simulated tracks its targets: no map to draw
    pm = findings_map.pair_margins(records)
    best = findings_map.best_compromise(records, OBJECTIVES[objective])
    most = findings_map.most_findings(records)
    return written + [
            write_text_atomic(out / "best.toml", point_toml(point_of(best.u, base, region))),
            write_text_atomic(out / "best.txt", summary(timing, best, base, region) + "\n"
                              + "the point meeting the most findings:\n"
                              + summary("", most, base, region)),
            write_text_atomic(out / "feasibility.md", findings_map.markdown(pm, records)
                              + "\n\n" + findings_map.verdict(pm) + "\n\n"
                              + findings_map.rest_verdict(records) + "\n"),
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


def summary(timing: str, best: Record, base: Params, region: Region = GLOBAL) -> str:
    """A point of the search and its findings (plain text)."""
    return (f"{timing}\n" * bool(timing)
            + f"cost {best.cost:.4f}, {best.held} of the {len(PAPER_CHECKS)} checks of "
            "`wpam reproduce` met\n"
            + describe_point(best.u, base, region)
            + f"\nat a bound: {', '.join(at_bounds(best.u, base, region)) or 'none'}"
            + "\nmargins:\n" + "\n".join(f"  {k:<24s} {v:+.3f}"
                                         for k, v in (best.margins or {}).items())
            + f"\nfigures: {json.dumps(best.figures)}\n")
