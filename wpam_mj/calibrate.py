"""Calibrate the parameters the paper does not give, against the paper's own results.

Two stages, alternated (`calibrate`), each a bounded least-squares fit on the simulator
itself (no surrogate) with the engine of `wpam fit` (`wpam_mj.fitting`: bounds from the
parameters' plausible ranges, scaled coordinates, parallel Jacobian columns):

  1. static:  braid angle, Kf, mu, F_f0, A_ax  ->  Table 2, "Po = 0.04 MPa" row
     (open-loop loop areas normalized by the Po = 0 loops, paper Figs. 8-9);
  2. dynamic: Pi/Po line conductances and the Pi feedforward protocol (the Po it assumes,
     its share of the friction band)  ->  the qualitative frequency-response findings
     of §4.2 (Fig. 17) and convergence of the step runs (Fig. 14), as hinge residuals of
     the findings' margins in `wpam_mj.paper` (zero when a finding holds with headroom),
     the same margins `wpam reproduce` checks.

How much each residual counts is set in one place, `WEIGHTS`. The analysis is the same
for every run (`wpam_mj.analysis`); only model parameters move. The fitted values go to a
TOML file (default `models/wpam/calibrated.toml`) that `wpam_mj.params.preset` applies,
so every command uses them.
"""

from __future__ import annotations

import json
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from contextlib import nullcontext
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from wpam_mj import fitting, paper
from wpam_mj.experiments import STATIC_TOP_MM, static_top_pressure
from wpam_mj.muscle import MuscleModel
from wpam_mj.params import CALIBRATION_FILE, MM, MPA, Params, ParameterError, preset
from wpam_mj.results import write_text_atomic
from wpam_mj.studies import StaticTask, StepTask, sweep_batch

PO_DOWN = paper.PO_DOWN_STATIC_MPA * MPA  # paper Fig. 9

STATIC_FIT = ("braid.braid_angle", "muscle.output_coeff", "muscle.friction_coeff",
              "muscle.friction_const", "muscle.axial_area")
DYNAMIC_FIT = ("pneumatics.inner_conductance", "pneumatics.outer_conductance",
               "controller.po_feedforward", "controller.feedforward_friction")


@dataclass(frozen=True)
class Weights:
    """How much each calibration residual counts (the one place to tune them)."""

    table2_wall_from: float = 0.12  # Table 2 relative error where a steep wall starts ...
    table2_wall: float = 10.0  # ... of this slope, so no cell is sacrificed to the others
    pressure_share: float = 0.95  # the 150 N ramp top and feedforward may use this share
    pressure_wall: float = 10.0  # of p_max; beyond it a wall of this slope
    step_error_mm: float = 0.4  # every PI plateau settles within this [mm] ...
    step_wall: float = 1.0  # ... beyond it, this residual per mm


WEIGHTS = Weights()


# ---- residuals ----


@dataclass(frozen=True)
class StaticStage:
    """`fitting.ResidualModel` of Table 2's "Po = 0.04" row: relative errors of the three
    cells, walls past `WEIGHTS.table2_wall_from`, and walls if 150 N at 50 mm would need
    more than `WEIGHTS.pressure_share` of the regulator's p_max (ramp top, feedforward)."""

    dt: float = 1e-3

    def tasks(self, params: Params) -> list:
        return [StaticTask(params, load, po, self.dt) for load in paper.LOADS_N
                for po in (0.0, PO_DOWN)]

    def residuals(self, params: Params, loops: list) -> np.ndarray:
        w = WEIGHTS
        ratios = [p.area / o.area for o, p in zip(loops[::2], loops[1::2])]
        target = [paper.TABLE2["open_po"][load] for load in paper.LOADS_N]
        rel = [(r - t) / t for r, t in zip(ratios, target)]
        res = rel + [w.table2_wall * max(0.0, abs(e) - w.table2_wall_from) for e in rel]
        p_max = params.pneumatics.p_max
        muscle = MuscleModel.from_params(params)
        worst = paper.LOADS_N[-1]
        need_ramp = static_top_pressure(params, worst) / p_max
        need_ff = muscle.equilibrium_pressure(STATIC_TOP_MM * MM, worst,
                                              params.controller.po_feedforward) / p_max
        res += [w.pressure_wall * max(0.0, need - w.pressure_share)
                for need in (need_ramp, need_ff)]
        return np.array(res)


@dataclass(frozen=True)
class DynamicStage:
    """`fitting.ResidualModel` of the §4.2 findings (`wpam_mj.paper.residuals` of the
    margins `reproduce` checks) and of step convergence (Fig. 14); 0 where they hold."""

    dt: float = 1e-3

    def _sweep(self, params: Params):
        return sweep_batch(params, paper.LOADS_N, paper.SWEEP_FREQS_HZ,
                           paper.SWEEP_CONTROLLERS, keep=(), dt=self.dt)

    def tasks(self, params: Params) -> list:
        return [*self._sweep(params).tasks,
                *(StepTask(params, load, "pi", self.dt) for load in paper.LOADS_N)]

    def residuals(self, params: Params, results: list) -> np.ndarray:
        sweep = self._sweep(params)
        n = len(sweep.tasks)
        findings = paper.residuals(paper.check_all(paper.SWEEP_FINDINGS,
                                                   sweep.assemble(results[:n]),
                                                   params.controller.po_cap))
        w = WEIGHTS
        step = [w.step_wall * max(0.0, s.worst_error() / MM - w.step_error_mm)
                for s in results[n:]]
        return np.concatenate([findings, step])


# ---- search ----

@dataclass(frozen=True)
class CalibrationResult:
    params: Params
    fitted: dict[str, float]
    static_residuals: np.ndarray
    dynamic_residuals: np.ndarray

    def table(self) -> str:
        lines = ["fitted parameter                      value"]
        lines += [f"  {k:<34s} {v:.6g}" for k, v in self.fitted.items()]
        lines.append("Table 2 'Po = 0.04' relative errors (50/100/150 N): "
                     + ", ".join(f"{r:+.3f}" for r in self.static_residuals[:3]))
        lines.append(f"dynamic hinge residual norm: {np.linalg.norm(self.dynamic_residuals):.4f}"
                     f" ({np.count_nonzero(self.dynamic_residuals)} of "
                     f"{self.dynamic_residuals.size} findings violated)")
        return "\n".join(lines)

    def toml(self) -> str:
        sections: dict[str, dict[str, float]] = {}
        for key, v in self.fitted.items():
            s, n = key.split(".")
            sections.setdefault(s, {})[n] = v
        out = ["# Fitted by `wpam calibrate` (wpam_mj/calibrate.py); SI units.", ""]
        for s, values in sections.items():
            out.append(f"[{s}]")
            out += [f"{n} = {v!r}" for n, v in values.items()]
            out.append("")
        return "\n".join(out)


def checkpoint_path(out: Path) -> Path:
    """Where `calibrate` keeps the parameters after each finished stage of a fit to `out`."""
    return out.with_name(f".{out.name}.checkpoint.json")


def _stage_checkpoint(path: Path, done: int, params: Params) -> None:
    values = {n: fitting.FreeParameter.of(n).value(params) for n in (*STATIC_FIT, *DYNAMIC_FIT)}
    write_text_atomic(path, json.dumps({"stages_done": done, "values": values}, indent=1))


def _resume(path: Path, params: Params) -> tuple[int, Params]:
    try:
        saved = json.loads(path.read_text())
        done, values = int(saved["stages_done"]), dict(saved["values"])
    except (OSError, ValueError, KeyError, TypeError):
        raise ParameterError(f"--resume: no readable checkpoint {path}") from None
    return done, params.with_values(values)


def calibrate(*, out: Path | None = CALIBRATION_FILE, jobs: int = 2, dt: float = 1e-3,
              progress: bool = True, rounds: int = 2, max_nfev: int = 30,
              start: Params | None = None, resume: bool = False) -> CalibrationResult:
    """Alternate the static and dynamic stages `rounds` times, then refit the static stage
    (the conductances shift the static loops a little); write the TOML to `out` (None: do
    not write). Every stage shares one process pool of `jobs` workers.

    After each stage the parameters are kept in `checkpoint_path(out)`; an interrupted fit
    loses the stage it was in, and `resume=True` continues after the last finished one
    (the same result as an uninterrupted fit: each stage is deterministic from its start).
    With progress, each stage prints its number, the time so far and an estimate of the
    time left (the mean stage time so far times the stages left)."""
    params = start if start is not None else preset("wpam")
    stages = [(StaticStage(dt), STATIC_FIT), (DynamicStage(dt), DYNAMIC_FIT)] * rounds
    stages.append((StaticStage(dt), STATIC_FIT))
    ckpt = None if out is None else checkpoint_path(Path(out))
    done = 0
    if resume:
        if ckpt is None:
            raise ParameterError("--resume needs an output file to resume")
        done, params = _resume(ckpt, params)
    started = time.perf_counter()
    with ProcessPoolExecutor(jobs) if jobs > 1 else nullcontext() as ex:
        for k, (stage, names) in enumerate(stages[done:], start=done):
            if progress:
                ran = k - done
                spent = time.perf_counter() - started
                left = f"{spent / ran * (len(stages) - k) / 60:.1f} min left" if ran else \
                    "time left after the first stage"
                print(f"[calibrate] stage {k + 1}/{len(stages)} "
                      f"({type(stage).__name__[:-5].lower()}), {spent / 60:.1f} min so far, "
                      f"{left}", file=sys.stderr, flush=True)
            free = [fitting.FreeParameter.of(n) for n in names]
            params = fitting.fit(stage, params, free, executor=ex, max_nfev=max_nfev,
                                 progress=progress).params
            if ckpt is not None:
                _stage_checkpoint(ckpt, k + 1, params)
        s_res, d_res = fitting.evaluate(StaticStage(dt), [params], ex)[0], \
            fitting.evaluate(DynamicStage(dt), [params], ex)[0]
    if s_res is None or d_res is None:
        raise ParameterError("the simulation fails at the calibrated parameters")
    fitted = {n: fitting.FreeParameter.of(n).value(params)
              for n in (*STATIC_FIT, *DYNAMIC_FIT)}
    result = CalibrationResult(params, fitted, s_res, d_res)
    if out is not None:
        write_text_atomic(out, result.toml())
        ckpt.unlink(missing_ok=True)
    return result
