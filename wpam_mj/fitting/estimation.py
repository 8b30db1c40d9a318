"""The fitting engine: bounded least squares on the simulator, with uncertainty.

Shared by `wpam fit` (measured time series, `wpam_mj.fitting.measured_fit`) and `wpam calibrate`
(the paper's published numbers, `wpam_mj.reproduction.calibrate`). A problem is a `ResidualModel`:
`tasks(params)` lists independent simulator runs (picklable objects with `.run()` and
optionally `.cost`), `residuals(params, results)` turns their results into one residual
vector. The engine

  * names free parameters "section.field" (`FreeParameter`) with bounds from the
    parameter's plausible range (`wpam_mj.physics.params.plausible_range`) unless overridden;
  * searches in scaled coordinates z in [0, 1]: log-scaled for positive parameters whose
    range spans a decade or more (conductances), linear otherwise, so that every
    coordinate moves the model by comparable amounts;
  * minimises 1/2 |r|^2 with scipy.optimize.least_squares (bounds 0 <= z <= 1; the
    "dogbox" trust region by default: on the 7-parameter recovery from static ramps it
    reached a given cost in 10 iterations where "trf" took 17, the coupled friction,
    force-scale and line-conductance parameters forming a curved valley), whose
    forward-difference Jacobian it computes itself so that the n perturbed parameter sets
    run at once on an executor;
  * reports each estimate with a 1-sigma uncertainty from the Jacobian at the optimum,
    cov = s^2 (J^T J)^-1 with s^2 = |r|^2 / (m - n) (Gauss-Newton linearisation; e.g.
    Seber & Wild, Nonlinear Regression, 1989, §2.1), and says when a parameter sits at a
    bound or is not identifiable from these data.

Finite differences and stick-slip: the simulated trajectories change by small steps
where a stick or slip moves by one physics step, so the difference step `DIFF_STEP` is
large enough (1e-3 of each scaled range) to see the trend rather than those steps.

Deterministic: the simulator and the search are, and results arrive in task order
whatever the executor, so the same data give the same fit.
"""

from __future__ import annotations

import hashlib
import json
import math
import sys
import time
from concurrent.futures import Executor
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Protocol, Sequence

import numpy as np
from scipy.optimize import least_squares

from wpam_mj.simulation.execution import execute
from wpam_mj.physics.params import Params, describe_with_ranges, fitted_parameters, plausible_range
from wpam_mj.errors import ParameterError
from wpam_mj.infra.pool import Workers, open_workers
from wpam_mj.infra.files import write_text_atomic

DIFF_STEP = 1e-3  # forward-difference step in scaled coordinates (see the module doc)
LOG_SPAN = 10.0  # hi / lo from which a positive parameter is searched in log scale
FAILED_RESIDUAL = 1e3  # residual of every entry when a trial's simulation fails
# A parameter whose 1-sigma spans more than this fraction of its scaled range is
# reported as not identifiable from the data.
UNIDENTIFIABLE_SIGMA_Z = 0.5
BOUND_TOL_Z = 1e-3  # closer than this to a bound (scaled): "at bound"


@dataclass(frozen=True)
class FreeParameter:
    """A fitted parameter "section.field" with bounds [lo, hi] in SI; `log`: searched
    as log(value)."""

    name: str
    lo: float
    hi: float
    log: bool

    @classmethod
    def of(cls, name: str, bounds: tuple[float, float] | None = None) -> "FreeParameter":
        """`name` with `bounds` (default: its plausible range); log scale when the range
        is positive and spans at least a factor LOG_SPAN."""
        _check_name(name)
        lo, hi = plausible_range(name) if bounds is None else (float(bounds[0]),
                                                               float(bounds[1]))
        if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
            raise ParameterError(f"bounds of {name} = ({lo:g}, {hi:g}) must be finite with "
                                 "low < high")
        return cls(name, lo, hi, log=lo > 0.0 and hi / lo >= LOG_SPAN)

    def _f(self, v):
        return np.log(v) if self.log else v

    def to_z(self, value: float) -> float:
        """Scaled coordinate of `value`, clipped to [0, 1]."""
        z = (self._f(value) - self._f(self.lo)) / (self._f(self.hi) - self._f(self.lo))
        return float(min(max(z, 0.0), 1.0))

    def from_z(self, z: float) -> float:
        z = min(max(float(z), 0.0), 1.0)
        if self.log:
            return math.exp(math.log(self.lo) + z * (math.log(self.hi) - math.log(self.lo)))
        return self.lo + z * (self.hi - self.lo)

    def dvalue_dz(self, z: float) -> float:
        """d value / d z at z (turns a scaled sigma into an SI one)."""
        if self.log:
            return self.from_z(z) * (math.log(self.hi) - math.log(self.lo))
        return self.hi - self.lo

    def value(self, params: Params) -> float:
        return float(params.value(self.name))


def _check_name(name: str) -> None:
    """Raise ParameterError listing the valid names unless `name` is "section.field"."""
    names = [row[0] for row in describe_with_ranges(Params())]
    if name not in names:
        raise ParameterError(f"unknown parameter {name!r}; valid names: {', '.join(names)}")


def default_free() -> tuple[str, ...]:
    """The plant parameters with a plausible range that are not measured directly: those
    the paper does not give (`wpam_mj.physics.params.fitted_parameters`: damping and the
    regulators' lag and dead time are measurable on a rig, so they stay fixed unless freed;
    the controller's readings are left out, as a replay cannot see them)."""
    return fitted_parameters()


def with_values(params: Params, free: Sequence[FreeParameter],
                values: Sequence[float]) -> Params:
    """`params` with each free parameter set to its value [SI]."""
    return params.with_values({p.name: float(v) for p, v in zip(free, values)})


class ResidualModel(Protocol):
    """A fitting problem (see the module docstring)."""

    def tasks(self, params: Params) -> Sequence: ...

    def residuals(self, params: Params, results: list) -> np.ndarray: ...


class ResidualJournal:
    """Residual vectors by parameter set, kept in a JSON file (`path`; None: in memory)
    after every evaluation. A deterministic search interrupted and run again with the
    journal replays what it had done without running it, so it loses at most the
    evaluation in progress. keep=False starts a new journal."""

    def __init__(self, path: Path | None = None, keep: bool = False) -> None:
        self.path = path
        self.entries: dict[str, list[float] | None] = {}
        if keep and path is not None and path.exists():
            try:
                self.entries = dict(json.loads(path.read_text()))
            except (OSError, ValueError, TypeError):
                raise ParameterError(f"{path}: not a readable journal") from None

    @staticmethod
    def key(params: Params) -> str:
        return hashlib.sha256(repr(params).encode()).hexdigest()

    def __contains__(self, params: Params) -> bool:
        return self.key(params) in self.entries

    def get(self, params: Params) -> np.ndarray | None:
        r = self.entries[self.key(params)]
        return None if r is None else np.array(r, dtype=float)

    def record(self, done: dict[str, np.ndarray | None]) -> None:
        if not done:
            return
        self.entries.update({k: None if r is None else [float(v) for v in r]
                             for k, r in done.items()})
        if self.path is not None:
            write_text_atomic(self.path, json.dumps(self.entries))

    @property
    def size(self) -> int:
        return len(self.entries)

    def remove(self) -> None:
        if self.path is not None:
            self.path.unlink(missing_ok=True)


def evaluate(model: ResidualModel, trials: Sequence[Params],
             executor: Workers | Executor | None = None,
             journal: ResidualJournal | None = None) -> list[np.ndarray | None]:
    """Residual vectors of `model` at each parameter set (None where its simulation
    failed or its parameters are invalid). All tasks of all trials run at once on the
    execution layer (`wpam_mj.simulation.execution.execute`: the simulations on batch
    threads here, or shipped to `executor`'s workers; None: here, one batch thread).
    Sets found in the `journal` are not run again; the others are recorded in it."""
    if journal is not None:
        todo = [p for p in trials if p not in journal]
        journal.record({ResidualJournal.key(p): r for p, r in zip(todo, evaluate(model, todo,
                                                                           executor))})
        return [journal.get(p) for p in trials]
    groups: list[list | None] = []
    for p in trials:
        try:
            groups.append(list(model.tasks(p)))
        except ParameterError:
            groups.append(None)
    flat = [(g, i, t) for g, tasks in enumerate(groups) if tasks is not None
            for i, t in enumerate(tasks)]
    outcome = dict(zip([(g, i) for g, i, _ in flat],
                       execute([t for _, _, t in flat], executor, failed=_FAILED)))
    out: list[np.ndarray | None] = []
    for g, tasks in enumerate(groups):
        results = None if tasks is None else [outcome[g, i] for i in range(len(tasks))]
        if results is None or any(r is _FAILED for r in results):
            out.append(None)
            continue
        try:
            out.append(np.asarray(model.residuals(trials[g], results), dtype=float))
        except (ParameterError, ArithmeticError):
            out.append(None)
    return out


_FAILED = object()  # a task whose simulation diverged or whose parameters were refused


@dataclass(frozen=True)
class Estimate:
    """One fitted parameter: value and 1-sigma [SI], bounds, and what limits it."""

    name: str
    value: float
    sigma: float
    lo: float
    hi: float
    at_bound: bool
    identifiable: bool

    @property
    def note(self) -> str:
        if self.at_bound:
            return "at bound"
        return "" if self.identifiable else "not identifiable from these data"

    def as_json(self) -> dict:
        return {"name": self.name, "value": self.value, "sigma": self.sigma,
                "bounds": [self.lo, self.hi], "at_bound": self.at_bound,
                "identifiable": self.identifiable}


@dataclass(frozen=True)
class FitResult:
    """The optimum: `params` (start with the free parameters fitted), `estimates`,
    `residuals` at the optimum, `correlation` of the estimates (n x n), evaluation
    counts and scipy's termination message."""

    params: Params
    estimates: tuple[Estimate, ...]
    residuals: np.ndarray
    correlation: np.ndarray
    nfev: int
    njev: int
    message: str

    @property
    def rms(self) -> float:
        return float(np.sqrt(np.mean(self.residuals ** 2)))

    def table(self, unit_of: Callable[[str], str] = lambda name: "") -> str:
        lines = [f"{'parameter':<30} {'value':>12} {'1-sigma':>11}  unit"]
        for e in self.estimates:
            rel = f"({abs(e.sigma / e.value):.1%})" if e.value else ""
            lines.append(f"{e.name:<30} {e.value:>12.5g} {e.sigma:>11.3g}  "
                         f"{unit_of(e.name):<11} {rel} {e.note}".rstrip())
        return "\n".join(lines)


class _Objective:
    """Residuals and their forward-difference Jacobian in scaled coordinates, with the
    perturbed evaluations of each Jacobian run together on the executor."""

    def __init__(self, model, start, free, executor, diff_step, progress, journal,
                 max_nfev) -> None:
        self.model, self.start, self.free = model, start, free
        self.executor, self.diff_step, self.progress = executor, diff_step, progress
        self.journal = journal
        self.cache: dict[bytes, np.ndarray] = {}
        self.size: int | None = None
        self.best = math.inf
        self.nfev, self.max_nfev, self.started = 0, max_nfev, time.perf_counter()

    def params(self, z: np.ndarray) -> Params:
        return with_values(self.start, self.free, [p.from_z(zi) for p, zi in zip(self.free, z)])

    def _many(self, zs: list[np.ndarray]) -> list[np.ndarray]:
        """Residuals at each z; keeps only this call's (scipy asks for the Jacobian at
        the point it just evaluated, so the base point is never run twice)."""
        todo = [z for z in zs if z.tobytes() not in self.cache]
        for z, r in zip(todo, evaluate(self.model, [self.params(z) for z in todo],
                                       self.executor, self.journal)):
            if r is None:
                if self.size is None:
                    raise ParameterError("the simulation fails at the start values; "
                                         "check the start parameters and the data")
                r = np.full(self.size, FAILED_RESIDUAL)
            self.size = r.size
            self.cache[z.tobytes()] = r
        self.cache = {z.tobytes(): self.cache[z.tobytes()] for z in zs}
        return [self.cache[z.tobytes()] for z in zs]

    def fun(self, z: np.ndarray) -> np.ndarray:
        r = self._many([np.asarray(z, dtype=float)])[0]
        cost = 0.5 * float(r @ r)
        self.nfev += 1
        if not self.progress:
            return r
        spent = time.perf_counter() - self.started
        left = spent / self.nfev * (self.max_nfev - self.nfev)
        print(f"fit: step {self.nfev}/{self.max_nfev}: cost {cost:.6g}, "
              f"{spent / 60:.1f} min so far, at most {left / 60:.1f} min left",
              file=sys.stderr, flush=True)
        if cost < self.best:
            self.best = cost
            shown = ", ".join(f"{p.name.split('.')[1]}={p.from_z(zi):.4g}"
                              for p, zi in zip(self.free, z))
            print(f"fit: best so far: {shown}", file=sys.stderr, flush=True)
        return r

    def jac(self, z: np.ndarray) -> np.ndarray:
        z = np.asarray(z, dtype=float)
        steps = []
        for i in range(len(z)):
            h = self.diff_step if z[i] + self.diff_step <= 1.0 else -self.diff_step
            zi = z.copy()
            zi[i] += h
            steps.append((zi, h))
        base, *cols = self._many([z] + [zi for zi, _ in steps])
        return np.column_stack([(c - base) / h for c, (_, h) in zip(cols, steps)])


def fit(model: ResidualModel, start: Params, free: Sequence[FreeParameter], *,
        jobs: int = 1, executor: Workers | Executor | None = None,
        diff_step: float = DIFF_STEP,
        max_nfev: int = 60, xtol: float = 1e-4, ftol: float = 1e-6,
        method: str = "dogbox", progress: bool = False,
        journal: ResidualJournal | None = None) -> FitResult:
    """Fit the `free` parameters of `start` to `model`'s residuals (module docstring).
    A start value outside its bounds starts at the nearest bound.

    Args:
      jobs: this machine's cores used when no `executor` is given (1: one batch thread).
      executor: the `Workers` of `infra.pool.open_workers`, or any
        concurrent.futures.Executor (e.g. dask.distributed's); not shut down.
      diff_step: forward-difference step in scaled coordinates.
      max_nfev: most residual evaluations of the search (Jacobians not counted).
      xtol, ftol: scipy's termination tolerances (xtol on the scaled coordinates).
      method: scipy's bounded method, "dogbox" or "trf".
      journal: keeps every evaluation (`ResidualJournal`): a fit interrupted and run again with
        the same journal replays its steps instead of running them.
    """
    if not free:
        raise ParameterError("no free parameters to fit")
    names = [p.name for p in free]
    if len(set(names)) != len(names):
        raise ParameterError(f"a parameter is freed twice: {', '.join(names)}")
    with open_workers(jobs if executor is None else executor) as ex:
        obj = _Objective(model, start, free, ex, diff_step, progress, journal, max_nfev)
        z0 = np.array([p.to_z(p.value(start)) for p in free])
        res = least_squares(obj.fun, z0, jac=obj.jac, bounds=(0.0, 1.0), method=method,
                            x_scale=1.0, max_nfev=max_nfev, xtol=xtol, ftol=ftol,
                            gtol=1e-10)
    return _result(obj, free, res)


def _result(obj: _Objective, free: Sequence[FreeParameter], res) -> FitResult:
    z, r, J = res.x, res.fun, np.atleast_2d(res.jac)
    m, n = J.shape
    s2 = float(r @ r) / max(m - n, 1)
    cov = s2 * np.linalg.pinv(J.T @ J, rcond=1e-12)
    sigma_z = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    col_norm = np.linalg.norm(J, axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov / np.outer(sigma_z, sigma_z)
    corr = np.where(np.isfinite(corr), corr, 0.0)
    estimates = []
    for i, p in enumerate(free):
        at_bound = bool(res.active_mask[i] != 0 or z[i] < BOUND_TOL_Z
                        or z[i] > 1.0 - BOUND_TOL_Z)
        identifiable = bool(col_norm[i] > 0.0 and sigma_z[i] < UNIDENTIFIABLE_SIGMA_Z)
        estimates.append(Estimate(p.name, p.from_z(z[i]), sigma_z[i] * p.dvalue_dz(z[i]),
                                  p.lo, p.hi, at_bound, identifiable))
    return FitResult(params=obj.params(z), estimates=tuple(estimates), residuals=r,
                     correlation=corr, nfev=int(res.nfev), njev=int(res.njev or 0),
                     message=str(res.message))
