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
    each point scored on calibrate's one cost with the signed margin of every finding
    (`wpam_mj.reproduction.search_scoring`), its controller's model fitted to its own
    open loops first as `wpam reproduce` runs it, so that the archive is also a measured
    feasibility map (`wpam_mj.reproduction.findings_map`) and `convergence` shows how the
    search got there; `wpam_mj.reproduction.search_outputs` writes what it found.

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
import sys
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Callable, Sequence

import numpy as np
from scipy.optimize import differential_evolution

from wpam_mj.paper import TABLE2_PO_RTOL
from wpam_mj.fitting import estimation
from wpam_mj.infra.pool import Workers, open_workers
from wpam_mj.reproduction.calibrate import FREE
from wpam_mj.reproduction import feedforward_fit, robustness
from wpam_mj.reproduction.search_scoring import OBJECTIVES, Record, Targets, score, worst_of
from wpam_mj.physics.params import Params, parameter_fields, preset
from wpam_mj.errors import ParameterError, check_range
from wpam_mj.experiments.protocol import SHIPPED, Protocol
from wpam_mj.reproduction.static_fit import STATIC_FIT, static_fit

STATIC_MISS_COST = 1e3  # a point the screen finds no static fit for (plus its error)
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


@dataclass(frozen=True)
class _StaticFit:
    """`_point_task` as a task of the execution layer."""

    key: tuple
    cost = 1.0

    def run(self) -> Point | None:
        return _point_task(self.key)


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


# ---- evaluation: parallel over every run of a generation, journaled


def _key(u: Sequence[float]) -> str:
    return hashlib.sha256(repr([round(float(x), 12) for x in u]).encode()).hexdigest()[:24]


class PointJournal:
    """Records by coordinates, appended as JSON lines to `path` (None: in memory), after a
    first line {"settings": ...} naming the search they belong to (`search_settings`;
    None: a journal written before journals recorded them)."""

    def __init__(self, path: Path | None, keep: bool, settings: dict | None = None) -> None:
        self.path, self.records, self.settings = path, {}, settings
        if path is None:
            return
        if keep:
            if not path.is_file():
                raise ParameterError(f"no journal {path}: nothing has been searched in "
                                     f"{path.parent} yet")
            self.settings = None
            for line in path.read_text().splitlines():
                try:
                    d = json.loads(line)
                except ValueError:
                    continue  # a line cut by the interruption: run it again
                if "settings" in d:
                    self.settings = d["settings"]
                else:
                    self.records[d["key"]] = Record.from_json(d)
        else:
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text(json.dumps({"settings": settings}) + "\n")

    def add(self, key: str, rec: Record) -> None:
        self.records[key] = rec
        if self.path is not None:
            with self.path.open("a") as fh:
                fh.write(json.dumps({"key": key, **rec.as_json()}) + "\n")


class Evaluator:
    """Scores lists of coordinates: journaled points are replayed, the rest run together
    on `executor` (the `Workers` of `open_workers`), longest runs first."""

    def __init__(self, base: Params, journal: PointJournal, executor: Workers,
                 targets=None, progress: bool = False, planned: int = 0,
                 region: Region = GLOBAL, objective: str = "cost",
                 robust: int = 0, feedforward: str = "calibrated") -> None:
        self.base, self.journal, self.executor = base, journal, executor
        # robust = K: each point is scored on itself and K plants about it, every
        # unmeasured value within +-5 % (the same Latin hypercube for every point, so
        # points differ only by themselves), and keeps each finding's worst margin and the
        # worst cost: what survives the plant's uncertainty, not the nominal point
        self.deviations = (robustness.sample_deviations(robust, robustness.ROBUST_SEED) if robust
                           else np.zeros((0, len(robustness.UNMEASURED))))
        self.region = region
        self.objective = OBJECTIVES[objective]  # Record -> the value DE minimises
        # targets(protocol) -> `Targets`-like (a cheap stand-in in the smoke test)
        self.targets = targets or (lambda protocol: Targets(SEARCH_DT, protocol,
                                                            feedforward))
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

    def _plants(self, params: Params) -> list[Params]:
        """The point itself, then its sampled plants (`robust`)."""
        return [params, *robustness.sampled_plants(params, self.deviations)]

    def _run(self, us: list) -> list[Record]:
        points = self._points(us)
        members = self._calibrated(
            [[(m, self.targets(p.protocol)) for m in self._plants(p.params)]
             if p is not None and p.static_error <= TABLE2_PO_RTOL else [] for p in points])
        runs = self._execute([[tg.tasks(m) for m, tg in plants or ()] for plants in members])
        out = []
        for u, p, plants, res in zip(us, points, members, runs):
            u = tuple(float(x) for x in u)
            if p is not None and p.static_error > TABLE2_PO_RTOL:  # never simulated
                out.append(Record(u, STATIC_MISS_COST * (1.0 + p.static_error), None,
                                  {"static_error": p.static_error}))
            elif p is None or plants is None or any(None in r for r in res):
                out.append(Record(u, *score(None, None, None)))
            else:
                out.append(Record(u, *worst_of([score(tg, m, r)
                                                for (m, tg), r in zip(plants, res)])))
        return out

    def _calibrated(self, members: list) -> list:
        """Each point's (plant, targets) with the controller's model fitted to the plant's
        own runs first where its targets ask for it (`Targets.calibration_tasks`), every
        point's runs together; None for a point one of whose runs or fits failed."""
        runs = self._execute([[tg.calibration_tasks(m) for m, tg in plants]
                              for plants in members])
        out = []
        for plants, res in zip(members, runs):
            mine = None
            if not any(None in r for r in res):  # no calibration run failed
                try:
                    mine = [tg.calibrated(m, r) for (m, tg), r in zip(plants, res)]
                except (ParameterError, ArithmeticError):
                    pass  # a fit refused: the point fails, as a failed run does
            out.append(mine)
        return out

    def _execute(self, groups: list[list[list]]) -> list[list[list]]:
        """The results of each point's task lists (None for a failed run), in their
        shape; every point's runs together on the workers, longest first."""
        flat = sorted(((g, j, i, t) for g, lists in enumerate(groups)
                       for j, ts in enumerate(lists) for i, t in enumerate(ts)),
                      key=lambda x: -x[3].cost)
        from wpam_mj.simulation.execution import execute  # noqa: PLC0415 (the one layer)
        done = dict(zip([k[:3] for k in flat],
                        execute([k[3] for k in flat], self.executor, failed=None)))
        return [[[done[g, j, i] for i in range(len(ts))] for j, ts in enumerate(lists)]
                for g, lists in enumerate(groups)]

    def _points(self, us: list) -> list[Point | None]:
        """Each coordinate's point with its static fit, the fits run on the workers."""
        keys = [(tuple(float(x) for x in u), self.base, self.region) for u in us]
        todo = [k for k in dict.fromkeys(keys) if k not in _POINTS]
        from wpam_mj.simulation.execution import execute  # noqa: PLC0415 (the one layer)
        fitted = execute([_StaticFit(k) for k in todo], self.executor)
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


RADIUS = 0.25  # a local search's default half-width, of each range


def search_settings(base: Params, free: Sequence[str] | None = None,
                    radius: float | None = None, seed: int | None = None,
                    popsize: int | None = None, robust: int = 0,
                    feedforward: str = "calibrated") -> dict:
    """What makes a search the one its journal holds (a resumed search must repeat them;
    the generations and the objective may change: they extend or re-rank the same
    points): seed, popsize, the local search's names and radius, the plants a robust
    search scores each point on, the controller's model, and the base point."""
    return {"seed": seed, "popsize": popsize, "free": None if free is None else list(free),
            "radius": radius, "robust": robust, "feedforward": feedforward,
            "base": {k: base.value(k) for k, _ in parameter_fields()}}


_SETTING_FLAGS = {"seed": "--seed", "popsize": "--popsize", "free": "--free",
                  "radius": "--radius", "robust": "--robust",
                  "feedforward": "--feedforward-model"}
# what a journal written before a setting existed searched with
_SETTING_BEFORE = {"robust": 0, "feedforward": "nominal"}


def check_same_search(journal: PointJournal, ours: dict, what: str,
                      keys: Sequence[str] = ("seed", "popsize", "free", "radius", "robust",
                                             "feedforward", "base")) -> None:
    """ParameterError naming the first setting of `keys` in which the search asked for
    differs from the one `journal` holds (a journal without settings is not checked)."""
    theirs = journal.settings
    if theirs is None:
        return
    for key in keys:
        a, b = theirs.get(key, _SETTING_BEFORE.get(key)), ours[key]
        if a == b:
            continue
        if key == "base":
            name = next(n for n in b if a.get(n) != b[n])
            differs = (f"parameter {name} = {a.get(name)!r} there, {b[name]!r} here "
                       "(--config)")
        else:
            differs = f"{_SETTING_FLAGS[key]} {_shown(a)} there, {_shown(b)} here"
        raise ParameterError(f"{what}: the journal {journal.path} is of another search "
                             f"({differs}); give its settings or another --out")


def _shown(value) -> str:
    """A setting as typed on the command line."""
    if value is None:
        return "not given"
    if isinstance(value, list):
        return ",".join(value)
    return f"{value:g}" if isinstance(value, float) else str(value)


def region_of(free: Sequence[str] | None, radius: float | None
              ) -> tuple[Region, float | None]:
    """The region a search varies (GLOBAL, or `local_region(free)`) and the local search's
    radius (RADIUS unless given; None for the global search, which refuses one)."""
    if free is None:
        if radius is not None:
            raise ParameterError(f"--radius {radius:g}: only a local search (--free NAMES) "
                                 "has a radius; the global search covers every range whole")
        return GLOBAL, None
    return local_region(free), check_range("radius", RADIUS if radius is None else radius,
                                           0.0, 1.0, lo_open=True)


def search(out: Path | None, *, base: Params | None = None, seed: int = 20,
           popsize: int = POPSIZE, maxiter: int = MAXITER, jobs: int = 2,
           resume: bool = False, progress: bool = True, targets=None,
           fit=None, objective: str = "cost", free: Sequence[str] | None = None,
           radius: float | None = None, robust: int = 0,
           feedforward: str = "calibrated") -> SearchResult:
    """Run DE over SPACE, every coordinate drawn from its whole range (a Latin hypercube,
    not started from any known point): `base` (default: the wpam preset) gives only the
    parameters that are not searched. Journals to `out`/journal.jsonl (None: in memory).

    popsize: DE's multiplier (population popsize * dims); maxiter: generations;
    targets: protocol -> `Targets` (default: the paper's, at SEARCH_DT); fit: the static
    screen (default `static_fit`); objective: what DE minimises (OBJECTIVES).
    free: a local search instead (`local_region`): only these dynamic readings, in a box
    of +-`radius` (of each range, default RADIUS) around `base`, whose point DE's first
    population holds. resume: replay the journal in `out` and go on, refused when it is
    of another search (`check_same_search`). robust: score each point as the worst over
    itself and this many plants sampled within +-5 % of its unmeasured values
    (`Evaluator`), so that the search optimises what survives the plant's uncertainty.
    feedforward: the controller's equilibrium model (`Targets`): "calibrated", fitted to
    each plant's own open loops first, as `wpam reproduce` runs it; or "nominal".
    """
    if objective not in OBJECTIVES:
        raise ParameterError(f"objective = {objective!r} must be one of "
                             f"{', '.join(OBJECTIVES)}")
    check_range("popsize", popsize, 1, 100)
    check_range("maxiter", maxiter, 0, 1000)
    check_range("seed", seed, 0, 2**32 - 1)
    base = base if base is not None else preset("wpam")
    region, radius = region_of(free, radius)
    region = region if fit is None else Region(region.names, fit)
    bounds, x0 = [(0.0, 1.0)] * len(region.names), None
    if free is not None:
        x0 = coordinates_of(base, region)
        bounds = [(max(0.0, z - radius), min(1.0, z + radius)) for z in x0]
    check_range("robust", robust, 0, 64)
    feedforward_fit.check_feedforward_model(feedforward)
    settings = search_settings(base, None if free is None else region.names, radius, seed,
                               popsize, int(robust), feedforward)
    path = None if out is None else Path(out) / "journal.jsonl"
    if resume and path is None:
        raise ParameterError("--resume: an in-memory search has no journal to resume")
    journal = PointJournal(path, keep=resume, settings=settings)
    if resume:
        check_same_search(journal, settings, "--resume")
    started = time.perf_counter()
    with open_workers(jobs) as ex:
        ev = Evaluator(base, journal, ex, targets, progress,
                       planned_evaluations(popsize, maxiter, len(bounds)), region, objective,
                       int(robust), feedforward)
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
    """Every record of the journal in `out` (a finished or interrupted search);
    ParameterError where there is none."""
    return list(PointJournal(Path(out) / "journal.jsonl", keep=True).records.values())
