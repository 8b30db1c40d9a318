"""Running a design-space study: a study file (`study_spec`) in, one tidy table (a row
per run, `study_table`) out. The runs (`sampling`) run in batches on the execution layer
(`wpam_mj.simulation.execution`: here on batch threads, or each batch shipped to a Dask
worker); each run reduced to its metrics (`metrics`). A run that
diverges (SimulationDiverged) or whose inputs are infeasible (ParameterError, e.g. a Po
cap below the feedforward Po) is a row with its flag set and NaN metrics, not a failed
study. The table is the same bytes whatever the executor, the number of jobs or the
interruptions.
"""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Sequence

from tqdm import tqdm

from wpam_mj.design.metrics import MetricsTask, params_for
from wpam_mj.design.sampling import sample
from wpam_mj.design.study_spec import (FLAGS, METRICS, PO_DOWN_DEFAULT, RUN_INPUTS,
                                       STATIC_DURATION_S, STEP_DURATION_S, StudySpec,
                                       input_column)
from wpam_mj.design.study_table import column_kinds, finished_rows, start_parts, write_tables
from wpam_mj.experiments.drives import SineSpec
from wpam_mj.infra.pool import Workers
from wpam_mj.infra.files import csv_text, write_text_atomic
from wpam_mj.physics.params import Params, preset
from wpam_mj.errors import ParameterError
from wpam_mj.simulation.execution import Batch, Failed, execute
from wpam_mj.simulation.simulate import SimulationDiverged

# Batches: at least this many tasks per worker slot (so the last tasks balance), at most
# this many physics steps per task (so progress and part files come every few seconds).
TASKS_PER_SLOT = 8
MAX_TASK_STEPS = 1_000_000


@dataclass(frozen=True)
class RunBatch:
    """Consecutive runs of a study: `tasks()` for the execution layer, whose outcomes
    `rows` turns into their table rows (display units)."""

    base: Params  # the preset with the study's fixed parameters
    experiment: str
    dt: float
    varied: tuple[str, ...]  # the inputs that differ from run to run
    runs: tuple[tuple[int, Mapping[str, Any]], ...]  # (run number, inputs [SI])

    def tasks(self) -> list[MetricsTask]:
        return [MetricsTask(self.experiment, self.base, inputs, self.dt, self.varied)
                for _, inputs in self.runs]

    def rows(self, outcomes: Sequence) -> list[dict[str, Any]]:
        return [self._row(i, inputs, o) for (i, inputs), o in zip(self.runs, outcomes)]

    def _row(self, index: int, inputs: Mapping[str, Any], outcome) -> dict[str, Any]:
        row: dict[str, Any] = {"run": index}
        row.update({input_column(k).column: input_column(k).display(v)
                    for k, v in inputs.items()})
        metrics = {m: math.nan for m, _ in METRICS[self.experiment]}
        flags = dict.fromkeys(FLAGS, False)
        error = ""
        if not isinstance(outcome, Failed):
            metrics.update(outcome)
        elif isinstance(outcome.error, SimulationDiverged):
            flags["diverged"], error = True, str(outcome.error)
        elif isinstance(outcome.error, ParameterError):
            flags["infeasible"], error = True, str(outcome.error)
        else:
            raise outcome.error  # undefined arithmetic is a fault, not a row
        return {**row, **metrics, **flags, "error": " ".join(error.split())}


@dataclass(frozen=True)
class StudyResult:
    """Where the table went, and how many runs this call simulated."""

    rows: list[dict[str, Any]]
    files: list[Path]
    ran: int
    reused: int


def batch_size(spec: StudySpec, runs: int, slots: int) -> int:
    """Runs per task: the study's `batch_size`, else enough tasks for every worker slot
    to balance (TASKS_PER_SLOT) and no task longer than MAX_TASK_STEPS physics steps."""
    if spec.batch_size is not None:
        return spec.batch_size
    by_steps = max(1, int(MAX_TASK_STEPS * spec.dt / _longest_run_s(spec)))
    by_balance = max(1, math.ceil(runs / (TASKS_PER_SLOT * slots)))
    return min(by_steps, by_balance)


def _longest_run_s(spec: StudySpec) -> float:
    """Simulated time [s] of the study's longest run."""
    def extreme(name: str, pick, default: float) -> float:
        given = spec.values.get(name) or spec.ranges.get(name)
        return pick(given) if given else spec.fixed.get(name, default)
    if spec.experiment == "step":
        return extreme("duration", max, STEP_DURATION_S)
    if spec.experiment == "sine":
        return SineSpec(extreme("frequency", min, RUN_INPUTS["frequency"][0])).duration
    if spec.experiment == "static":
        return STATIC_DURATION_S
    return 2 * STATIC_DURATION_S + STEP_DURATION_S  # table2: two ramps and a staircase


def run_study(spec: StudySpec, out: str | Path, workers: Workers, *, resume: bool = False,
              progress: bool = False) -> StudyResult:
    """Run every run of `spec` not yet finished in `out` on `workers`; write the table.

    Part files (out/parts/runs_FIRST-LAST.csv) are written whole as each batch finishes;
    the table (out/study.csv, and out/study.parquet when pyarrow is installed) is written
    from them at the end, in run order.
    """
    out = Path(out)
    base = params_for(preset(spec.preset), spec.fixed)  # fixed parameters: once
    defaults = {k: v[0] for k, v in RUN_INPUTS.items() if spec.experiment in v[2]}
    if "po_down" in defaults:
        defaults["po_down"] = PO_DOWN_DEFAULT[spec.experiment]
    inputs = [{**run, **{k: v for k, v in spec.fixed.items()},
               **{k: v for k, v in defaults.items() if k not in run and k not in spec.fixed}}
              for run in sample(spec)]
    order = {k: i for i, k in enumerate(spec.inputs)}
    inputs = [dict(sorted(r.items(), key=lambda kv: order[kv[0]])) for r in inputs]
    kinds = column_kinds(spec)
    parts = start_parts(out, spec, resume)
    done = finished_rows(parts, kinds)
    todo = [(i, r) for i, r in enumerate(inputs) if i not in done]
    size = batch_size(spec, len(todo), workers.slots)
    batches = [RunBatch(base, spec.experiment, spec.dt, spec.varied, tuple(todo[s:s + size]))
               for s in range(0, len(todo), size)]
    columns = spec.columns
    with tqdm(total=len(inputs), initial=len(done), desc="study", unit="run",
              file=sys.stderr, disable=not progress, smoothing=0.1) as bar:
        def finish(batch: RunBatch, rows: list[dict[str, Any]]) -> None:
            first, last = batch.runs[0][0], batch.runs[-1][0]
            write_text_atomic(parts / f"runs_{first:07d}-{last:07d}.csv",
                              csv_text(rows, columns))
            bar.update(len(rows))

        execute([Batch(b.tasks(), b.rows) for b in batches], workers, failed=Failed,
                each=lambda i, rows: finish(batches[i], rows))
    rows = finished_rows(parts, kinds)
    table = [rows[i] for i in range(len(inputs))]
    return StudyResult(rows=table, files=write_tables(out, spec, table),
                       ran=sum(len(b.runs) for b in batches), reused=len(done))
