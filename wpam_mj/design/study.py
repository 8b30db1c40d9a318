"""Design-space studies: a TOML study file in, one tidy table (a row per run) out.

A study file names the experiment, the settings shared by every run and the varied ones:

    experiment = "sine"          # static | step | sine | table2
    preset = "wpam"              # optional (default wpam); dt = 1e-3 [s] optional
    [fixed]                      # optional: settings of every run
    frequency = 0.5              # Hz
    [vary]
    method = "grid"              # grid | list | random | lhs
    [vary.values]                # grid/list: the values; random/lhs: choices
    load = [50, 100, 150]
    "controller.po_cap" = [6e4, 8e4, 1e5]
    # random/lhs: n = 1000, seed = 1, and [vary.ranges] name = [low, high] (uniform)

Inputs (SI, as in a --config file): any model parameter as `section.field`, plus `load`
[N], `controller` (open/pi/pid), `frequency` [Hz] and `amplitude` [m] (sine), `duration`
[s] (step: the staircase's length, default 110), `po_down` [Pa] (static, table2).

Runs are numbered in sampling order (grid: the last name varies fastest; random and
Latin-hypercube samples come from numpy's PCG64 seeded with `seed`, through
scipy.stats.qmc for the hypercube), so a study file always means the same runs. They run
in batches (one task per batch, each building its parameter set once) on any
`concurrent.futures.Executor` (`wpam_mj.infra.executors`). Every finished batch is written at
once as its own part file, so an interrupted study resumes where it stopped; the table is
then assembled from the part files in run order: the same bytes whatever the executor,
the number of jobs or the interruptions. A run that diverges (SimulationDiverged) or
whose inputs are infeasible (ParameterError, e.g. a Po cap below the feedforward Po) is
a row with its flag set and NaN metrics, not a failed study.

Table columns are in display units, named with them (`load_n`, `controller.po_cap_mpa`).
"""

from __future__ import annotations

import csv
import dataclasses
import hashlib
import io
import itertools
import json
import math
import re
import sys
from concurrent.futures import FIRST_COMPLETED, Future, wait
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable, Mapping, Sequence

import numpy as np
from tqdm import tqdm

from wpam_mj.experiments.analysis import frequency_response, loop_area, steady_state_means
from wpam_mj.infra.budget import MAX_RUN_S
from wpam_mj.control.controllers import CONTROLS, check_control
from wpam_mj.infra.executors import Workers
from wpam_mj.experiments.feasibility import MOVE_MIN_MM, check_liftable, load_moved
from wpam_mj.experiments.drives import STATIC_RAMP_S, SineSpec, check_po, sine_run, step_run
from wpam_mj.simulation.model import check_dt, check_load
from wpam_mj.paper import PO_DOWN_STATIC_MPA, STEP_HOLD_S, STEP_LEVELS_MM
from wpam_mj.physics.params import (MM, MPA, PRESETS, ParameterError, Params, check_range,
                                    load_toml, preset)
from wpam_mj.simulation.results import write_atomic, write_text_atomic
from wpam_mj.simulation.simulate import SimulationDiverged
from wpam_mj.experiments.studies import PLATEAU_SETTLE_S, StaticTask, plateau_segments, table2_batch
from wpam_mj.experiments.responses import LOOP_METHOD

EXPERIMENTS = ("static", "step", "sine", "table2")
METHODS = ("grid", "list", "random", "lhs")
MAX_RUNS = 1_000_000  # our choice: a bound that catches a runaway grid before it starts
RECORD_DT_S = 0.01  # every run records at this period (`wpam_mj.simulation.simulate.simulate`)
STEP_DURATION_S = len(STEP_LEVELS_MM) * STEP_HOLD_S  # paper §4.1 staircase, 110 s
STATIC_DURATION_S = 2 * STATIC_RAMP_S + 2.0  # `experiments.static_loop`: ramps + 1 s dwells
# Parameter sections of the config file (braid, muscle, pneumatics, controller)
_SECTIONS = {f.name: type(getattr(Params(), f.name)) for f in dataclasses.fields(Params)
             if f.name != "preset"}
# Batches: at least this many tasks per worker slot (so the last tasks balance), at most
# this many physics steps per task (so progress and part files come every few seconds).
TASKS_PER_SLOT = 8
MAX_TASK_STEPS = 1_000_000

# Run inputs other than model parameters: (default [SI], unit, experiments that take it).
_RUN_INPUTS: dict[str, tuple[Any, str, tuple[str, ...]]] = {
    "load": (100.0, "N", EXPERIMENTS),
    "controller": ("pi", "", ("step", "sine")),
    "frequency": (0.5, "Hz", ("sine",)),
    "amplitude": (SineSpec(1.0).amplitude, "m", ("sine",)),
    "duration": (STEP_DURATION_S, "s", ("step",)),
    "po_down": (None, "Pa", ("static", "table2")),  # None: per experiment
}
_PO_DOWN_DEFAULT = {"static": 0.0, "table2": PO_DOWN_STATIC_MPA * MPA}
_DISPLAY_UNITS = {"Pa": ("MPa", MPA), "m": ("mm", MM)}  # display unit, SI per display unit

# Metric columns per experiment: (column, axis label).
_METRICS = {
    "static": (("loop_area_mpa_mm", "loop area [MPa mm]"), ("po_max_mpa", "max Po [MPa]")),
    "step": (("loop_area_mpa_mm", "loop area of plateau means [MPa mm]"),
             ("plateau_error_max_mm", "worst plateau error [mm]"),
             ("plateau_error_rms_mm", "RMS plateau error [mm]"),
             ("po_max_mpa", "max Po [MPa]")),
    "sine": (("gain", "gain [1]"), ("phase_lag_deg", "phase lag [deg]"),
             ("po_max_mpa", "max Po (regulator gauge) [MPa]")),
    "table2": (("open_po", "open loop, Po while Pi falls / Po = 0 area [1]"),
               ("feedback", "PI feedback / open-loop Po = 0 area [1]"),
               ("loop_area_mpa_mm", "PI loop area of plateau means [MPa mm]"),
               ("plateau_error_max_mm", "worst PI plateau error [mm]"),
               ("po_max_mpa", "max Po, PI run [MPa]")),
}
_FLAGS = ("diverged", "infeasible")


def metric_labels(experiment: str) -> tuple[tuple[str, str], ...]:
    """(column, axis label with unit) of each metric of an experiment."""
    return _METRICS[experiment]


# ------------------------------------------------------------------ the study file


@dataclass(frozen=True)
class Column:
    """One input column: spec name, table column, SI per display unit, display unit."""

    name: str
    column: str
    unit: float
    shown: str

    @property
    def label(self) -> str:
        """Axis label: "controller.po_cap [MPa]"."""
        return self.name if self.shown in ("", "1") else f"{self.name} [{self.shown}]"

    def describe(self, value: Any) -> str:
        """Legend text of one value: "load = 50 N"."""
        text = value if isinstance(value, str) else f"{value:g}"
        return f"{self.name} = {text}" + ("" if self.shown in ("", "1") else f" {self.shown}")

    def display(self, value: Any) -> Any:
        # a division, so that round SI values stay round: 8e4 Pa / 1e6 = 0.08 MPa
        return value if isinstance(value, str) else value / self.unit


def _unit_suffix(unit: str) -> str:
    """A unit as a column-name suffix: "N s/m" -> "n_s_per_m", "1" -> ""."""
    if unit in ("", "1"):
        return ""
    return "_" + re.sub(r"[^a-z0-9]+", "_", unit.lower().replace("/", " per ")
                        .replace("^", "")).strip("_")


def _param_field(name: str) -> dataclasses.Field:
    section, _, key = name.partition(".")
    fields = {f.name: f for f in dataclasses.fields(_SECTIONS[section])} \
        if section in _SECTIONS else {}
    if key not in fields:
        raise ParameterError(f"unknown study input {name!r}; valid: "
                             + ", ".join(_RUN_INPUTS) + ", or section.field of "
                             + ", ".join(_SECTIONS))
    return fields[key]


def input_column(name: str) -> Column:
    """The table column of a study input (display units)."""
    unit = _RUN_INPUTS[name][1] if name in _RUN_INPUTS else \
        _param_field(name).metadata["unit"]
    shown, per = _DISPLAY_UNITS.get(unit, (unit, 1.0))
    return Column(name, name + _unit_suffix(shown), per, shown)


@dataclass(frozen=True)
class StudySpec:
    """A validated study file. values/ranges map input names to values [SI]."""

    experiment: str
    preset: str
    dt: float
    fixed: Mapping[str, Any]
    method: str
    values: Mapping[str, tuple]
    ranges: Mapping[str, tuple[float, float]]
    n: int
    seed: int
    batch_size: int | None

    @property
    def varied(self) -> tuple[str, ...]:
        return tuple(self.values) + tuple(self.ranges)

    @property
    def inputs(self) -> tuple[str, ...]:
        """Every input of a run, in table order: varied, fixed, then the experiment's
        remaining run inputs at their defaults."""
        names = dict.fromkeys((*self.varied, *self.fixed))
        names.update(dict.fromkeys(k for k, v in _RUN_INPUTS.items()
                                   if self.experiment in v[2]))
        return tuple(names)

    @property
    def columns(self) -> tuple[str, ...]:
        return ("run", *(input_column(n).column for n in self.inputs),
                *(m for m, _ in _METRICS[self.experiment]), *_FLAGS, "error")

    def digest(self) -> str:
        """A fingerprint of everything that defines the runs (for --resume; the batch
        size does not change any result)."""
        text = json.dumps({**dataclasses.asdict(self), "batch_size": None}, sort_keys=True,
                          default=list)
        return hashlib.sha256(text.encode()).hexdigest()[:16]


def _flatten(table: Mapping[str, Any], where: str) -> dict[str, Any]:
    """{"controller": {"po_cap": v}} -> {"controller.po_cap": v} (TOML dotted keys)."""
    out: dict[str, Any] = {}
    for key, value in table.items():
        if isinstance(value, Mapping):
            if key not in _SECTIONS:
                raise ParameterError(f"{where}: unknown section {key!r}; valid: "
                                     + ", ".join(_SECTIONS))
            out.update({f"{key}.{k}": v for k, v in value.items()})
        else:
            out[key] = value
    return out


def _check_value(name: str, value: Any, base: Params) -> Any:
    """One input value [SI], checked against its allowed range; returns it as used."""
    if name == "controller":
        if not isinstance(value, str):
            raise ParameterError(f"controller = {value!r} must be one of "
                                 + ", ".join(CONTROLS))
        return check_control(value)
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ParameterError(f"{name} = {value!r} is not a number")
    if name == "load":
        return check_load(value)
    if name == "frequency":  # SineSpec: its range, and a run of bounded length
        return SineSpec(value).freq
    if name == "amplitude":
        return SineSpec(1.0, amplitude=value).amplitude
    if name == "duration":
        return check_range("duration", value, 1.0, MAX_RUN_S, "s")
    if name == "po_down":
        return check_po("po_down", value, base)
    md = _param_field(name).metadata
    return check_range(name, value, md["lo"], md["hi"], md["unit"], lo_open=md["lo_open"])


def _dt(value: Any) -> float:
    """The study's physics step [s]: what `--dt` accepts (it must divide the recording
    period), so that a study file cannot ask for a run the command line refuses."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ParameterError(f"dt = {value!r} is not a number; give seconds, e.g. 1e-3")
    return check_dt(float(value), divides=RECORD_DT_S, name="dt")


def _allowed(name: str, experiment: str) -> None:
    if name in _RUN_INPUTS and experiment not in _RUN_INPUTS[name][2]:
        users = ", ".join(_RUN_INPUTS[name][2])
        raise ParameterError(f"{name} is not an input of the {experiment} experiment "
                             f"(only of {users})")
    if name not in _RUN_INPUTS:
        _param_field(name)


def _int(table: Mapping, key: str, default: int | None, lo: int, hi: int) -> int | None:
    value = table.get(key, default)
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= hi:
        raise ParameterError(f"{key} = {value!r} must be an integer in [{lo}, {hi}]")
    return value


_TOP_KEYS = {"experiment", "preset", "dt", "fixed", "vary", "batch_size"}
_VARY_KEYS = {"method", "values", "ranges", "n", "seed"}


def parse_spec(data: Mapping[str, Any], where: str = "study") -> StudySpec:
    """Validate a study read from TOML (see the module docstring)."""
    for keys, table, name in ((_TOP_KEYS, data, where),
                              (_VARY_KEYS, data.get("vary", {}), f"{where} [vary]")):
        unknown = set(table) - keys
        if unknown:
            raise ParameterError(f"{name}: unknown key {sorted(unknown)[0]!r}; valid: "
                                 + ", ".join(sorted(keys)))
    experiment = data.get("experiment")
    if experiment not in EXPERIMENTS:
        raise ParameterError(f"{where}: experiment = {experiment!r}; valid: "
                             + ", ".join(EXPERIMENTS))
    name = data.get("preset", "wpam")
    if name not in PRESETS:
        raise ParameterError(f"{where}: preset = {name!r}; valid: " + ", ".join(PRESETS))
    base = preset(name)
    dt = _dt(data.get("dt", 1e-3))
    vary = data.get("vary", {})
    method = vary.get("method", "grid")
    if method not in METHODS:
        raise ParameterError(f"{where}: vary.method = {method!r}; valid: " + ", ".join(METHODS))
    fixed = _flatten(data.get("fixed", {}), f"{where} [fixed]")
    values = _flatten(vary.get("values", {}), f"{where} [vary.values]")
    ranges = _flatten(vary.get("ranges", {}), f"{where} [vary.ranges]")
    sampled = method in ("random", "lhs")
    if ranges and not sampled:
        raise ParameterError(f"{where}: [vary.ranges] needs method random or lhs, "
                             f"not {method}")
    for k in fixed:
        _allowed(k, experiment)
        fixed[k] = _check_value(k, fixed[k], base)
    for k, vals in values.items():
        _allowed(k, experiment)
        if not isinstance(vals, list) or not vals:
            raise ParameterError(f"{where}: vary.values.{k} must be a non-empty list")
        values[k] = tuple(_check_value(k, v, base) for v in vals)
    for k, span in ranges.items():
        _allowed(k, experiment)
        if k == "controller" or not isinstance(span, list) or len(span) != 2:
            raise ParameterError(f"{where}: vary.ranges.{k} must be [low, high] numbers")
        lo, hi = (_check_value(k, v, base) for v in span)
        if not lo < hi:
            raise ParameterError(f"{where}: vary.ranges.{k} = {span}: low must be below high")
        ranges[k] = (lo, hi)
    both = (set(values) & set(ranges)) | (set(fixed) & (set(values) | set(ranges)))
    if both:
        raise ParameterError(f"{where}: {sorted(both)[0]} is given twice")
    if not values and not ranges:
        raise ParameterError(f"{where}: nothing varies; give [vary.values] or [vary.ranges]")
    if method == "list" and len({len(v) for v in values.values()}) > 1:
        raise ParameterError(f"{where}: method list needs value lists of one length; got "
                             + ", ".join(f"{k}: {len(v)}" for k, v in values.items()))
    n = _int(vary, "n", None, 1, MAX_RUNS) if sampled else None
    if sampled and n is None:
        raise ParameterError(f"{where}: method {method} needs vary.n, the number of runs")
    return StudySpec(experiment=experiment, preset=name, dt=dt, fixed=fixed, method=method,
                     values=values, ranges=ranges, n=n or 0,
                     seed=_int(vary, "seed", 0, 0, 2**63 - 1) if sampled else 0,
                     batch_size=_int(data, "batch_size", None, 1, MAX_RUNS))


def load_spec(path: str | Path) -> StudySpec:
    """Read and validate a study file."""
    data = load_toml(path, "study file")  # its errors name the file
    try:
        return parse_spec(data, str(path))
    except ParameterError as err:
        msg = str(err)
        raise ParameterError(msg if msg.startswith(str(path)) else f"{path}: {msg}") from None


# ------------------------------------------------------------------ sampling


def sample(spec: StudySpec) -> list[dict[str, Any]]:
    """The varied inputs of every run, in run order (deterministic)."""
    names = list(spec.values)
    if spec.method == "grid":
        count = math.prod(len(v) for v in spec.values.values())
        if count > MAX_RUNS:
            raise ParameterError(f"the grid has {count} runs; at most {MAX_RUNS} allowed")
        return [dict(zip(names, combo)) for combo in itertools.product(*spec.values.values())]
    if spec.method == "list":
        return [dict(zip(names, combo)) for combo in zip(*spec.values.values())]
    # random / lhs: one uniform [0, 1) coordinate per input, mapped onto its range
    # (continuous) or its list of choices (equal chances)
    rng = np.random.default_rng(spec.seed)
    dims = len(spec.values) + len(spec.ranges)
    if spec.method == "lhs":
        from scipy.stats import qmc  # noqa: PLC0415 (scipy.stats: slow import)
        u = qmc.LatinHypercube(d=dims, seed=rng).random(spec.n)
    else:
        u = rng.random((spec.n, dims))
    runs = []
    for row in u:
        run = {k: v[min(int(c * len(v)), len(v) - 1)]
               for (k, v), c in zip(spec.values.items(), row)}
        run.update({k: lo + float(c) * (hi - lo)
                    for (k, (lo, hi)), c in zip(spec.ranges.items(), row[len(spec.values):])})
        runs.append(run)
    return runs


# ------------------------------------------------------------------ one run


def _params_for(base: Params, inputs: Mapping[str, Any]) -> Params:
    """`base` with the inputs that name a parameter ("section.field") applied."""
    return base.with_values({n: v for n, v in inputs.items() if "." in n})


def _step_metrics(result, hold: float) -> dict[str, float]:
    """Plateau means (last half of each plateau, as `studies.step_study`) and their area."""
    seg = plateau_segments(STEP_LEVELS_MM, hold)
    settle = hold * PLATEAU_SETTLE_S / STEP_HOLD_S
    x = steady_state_means(result.time, result.x, seg, settle)
    pi = steady_state_means(result.time, result.pi, seg, settle)
    err = x - np.asarray(STEP_LEVELS_MM, dtype=float) * MM
    return {"loop_area_mpa_mm": loop_area(pi, x, method=LOOP_METHOD) / (MPA * MM),
            "plateau_error_max_mm": float(np.max(np.abs(err))) / MM,
            "plateau_error_rms_mm": float(np.sqrt(np.mean(err ** 2))) / MM,
            "po_max_mpa": float(result.po_reg.max()) / MPA}


def _sine_metrics(result, spec: SineSpec) -> dict[str, float]:
    """Gain and lag of the analysed cycles (`analysis.frequency_response`) and the highest
    regulator-gauge Po over them (as `studies.SweepPoint.po_max`)."""
    fr = frequency_response(result.time, result.x_ref, result.x, spec.freq,
                            settle_cycles=spec.settle_cycles, n_cycles=spec.cycles)
    window = spec.analysed(result.time)
    return {"gain": fr.gain, "phase_lag_deg": fr.phase_lag_deg,
            "po_max_mpa": float(result.po_reg[window].max()) / MPA}


def _moved(*results):
    """The results, or ParameterError when the load never moved in one of them (its
    metrics would mean nothing: a gain of 0, a loop of no area)."""
    for result in results:
        if not load_moved(result):
            raise ParameterError(f"the load never moved (x spanned < {MOVE_MIN_MM:g} mm); "
                                 "this run's metrics mean nothing")
    return results[0]


def run_metrics(experiment: str, params: Params, inputs: Mapping[str, Any],
                dt: float) -> dict[str, float]:
    """Simulate one run and reduce it to the experiment's metrics (display units).
    ParameterError for a load this parameter set cannot lift or one that never moved."""
    load = inputs["load"]
    check_liftable(params, (load,), "load")
    if experiment == "static":
        loop = StaticTask(params, load, check_po("po_down", inputs["po_down"], params),
                          dt).run()
        return {"loop_area_mpa_mm": loop.area_mpa_mm,
                "po_max_mpa": float(_moved(loop.result).po_reg.max()) / MPA}
    if experiment == "step":
        hold = inputs["duration"] / len(STEP_LEVELS_MM)
        r = step_run(params, load, inputs["controller"], hold=hold, dt=dt)
        return _step_metrics(_moved(r), hold)
    if experiment == "sine":
        spec = SineSpec(inputs["frequency"], amplitude=inputs["amplitude"])
        r = sine_run(params, load, inputs["controller"], spec, dt=dt)
        return _sine_metrics(_moved(r), spec)
    batch = table2_batch(params, loads=(load,), po_down=inputs["po_down"], dt=dt)
    t2 = batch.assemble([task.run() for task in batch.tasks])
    _moved(t2.feedback_runs[0].result, *(lp.result for lp in (*t2.open_loops, *t2.po_loops)))
    return {"open_po": t2.open_po[load], "feedback": t2.feedback[load],
            **_step_metrics(t2.feedback_runs[0].result, STEP_HOLD_S)}


@dataclass(frozen=True)
class RunBatch:
    """A task of consecutive runs; `run()` returns their table rows (display units)."""

    base: Params  # the preset with the study's fixed parameters
    experiment: str
    dt: float
    varied: tuple[str, ...]  # the inputs that differ from run to run
    runs: tuple[tuple[int, Mapping[str, Any]], ...]  # (run number, inputs [SI])

    def run(self) -> list[dict[str, Any]]:
        return [self._row(i, inputs) for i, inputs in self.runs]

    def _row(self, index: int, inputs: Mapping[str, Any]) -> dict[str, Any]:
        row: dict[str, Any] = {"run": index}
        row.update({input_column(k).column: input_column(k).display(v)
                    for k, v in inputs.items()})
        metrics = {m: math.nan for m, _ in _METRICS[self.experiment]}
        flags = dict.fromkeys(_FLAGS, False)
        error = ""
        try:
            params = _params_for(self.base, {k: inputs[k] for k in self.varied})
            metrics.update(run_metrics(self.experiment, params, inputs, self.dt))
        except SimulationDiverged as err:
            flags["diverged"], error = True, str(err)
        except ParameterError as err:
            flags["infeasible"], error = True, str(err)
        return {**row, **metrics, **flags, "error": " ".join(error.split())}


def _run_batch(batch: RunBatch) -> list[dict[str, Any]]:
    """Worker entry point (module level, so that every executor can pickle it)."""
    return batch.run()


# ------------------------------------------------------------------ the table on disk

PARTS = "parts"  # folder of finished batches in the output folder
TABLE = "study"  # study.csv, study.parquet


def _format(value: Any) -> str:
    """CSV text that reads back to the same value (repr of a float is exact)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    return repr(value) if isinstance(value, float) else str(value)


def _csv_text(columns: Sequence[str], rows: Iterable[Mapping[str, Any]]) -> str:
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(columns)
    writer.writerows([_format(row[c]) for c in columns] for row in rows)
    return buf.getvalue()


def _column_kinds(spec: StudySpec) -> dict[str, type]:
    kinds: dict[str, type] = {c: float for c in spec.columns}
    kinds.update(run=int, error=str, **dict.fromkeys(_FLAGS, bool))
    kinds[input_column("controller").column] = str
    return kinds


def _read_part(path: Path, kinds: Mapping[str, type]) -> list[dict[str, Any]]:
    parse = {int: int, float: float, str: str, bool: lambda s: s == "true"}
    with open(path, newline="") as fh:
        return [{k: parse[kinds[k]](v) for k, v in row.items()} for row in csv.DictReader(fh)]


def _start_parts(out: Path, spec: StudySpec, resume: bool) -> Path:
    """The part folder, emptied unless resuming the same study (checked by digest)."""
    parts = out / PARTS
    stamp = parts / "study.json"
    if resume and stamp.exists():
        if json.loads(stamp.read_text()).get("digest") != spec.digest():
            raise ParameterError(f"--resume: {out} holds the parts of a different study "
                                 "(the study file changed); use another --out")
        return parts
    parts.mkdir(parents=True, exist_ok=True)
    for old in parts.glob("runs_*.csv"):
        old.unlink()
    write_text_atomic(stamp, json.dumps({"digest": spec.digest()}) + "\n")
    return parts


def _finished(parts: Path, kinds: Mapping[str, type]) -> dict[int, dict[str, Any]]:
    rows: dict[int, dict[str, Any]] = {}
    for path in sorted(parts.glob("runs_*.csv")):
        rows.update((row["run"], row) for row in _read_part(path, kinds))
    return rows


def _write_tables(out: Path, spec: StudySpec, rows: list[dict[str, Any]]) -> list[Path]:
    columns = spec.columns
    written = [write_text_atomic(out / f"{TABLE}.csv", _csv_text(columns, rows))]
    try:
        import pyarrow as pa  # noqa: PLC0415 (optional: pip install ".[parquet]")
        import pyarrow.parquet as pq  # noqa: PLC0415
    except ImportError:
        return written
    table = pa.table({c: [row[c] for row in rows] for c in columns})
    written.append(write_atomic(out / f"{TABLE}.parquet",
                                lambda p: pq.write_table(table, p)))
    return written


# ------------------------------------------------------------------ running a study


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
        return SineSpec(extreme("frequency", min, _RUN_INPUTS["frequency"][0])).duration
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
    base = _params_for(preset(spec.preset), spec.fixed)  # fixed parameters: once
    defaults = {k: v[0] for k, v in _RUN_INPUTS.items() if spec.experiment in v[2]}
    if "po_down" in defaults:
        defaults["po_down"] = _PO_DOWN_DEFAULT[spec.experiment]
    inputs = [{**run, **{k: v for k, v in spec.fixed.items()},
               **{k: v for k, v in defaults.items() if k not in run and k not in spec.fixed}}
              for run in sample(spec)]
    order = {k: i for i, k in enumerate(spec.inputs)}
    inputs = [dict(sorted(r.items(), key=lambda kv: order[kv[0]])) for r in inputs]
    kinds = _column_kinds(spec)
    parts = _start_parts(out, spec, resume)
    done = _finished(parts, kinds)
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
                              _csv_text(columns, rows))
            bar.update(len(rows))

        if workers.executor is None:
            for b in batches:
                finish(b, b.run())
        else:
            _run_on(workers, batches, finish)
    rows = _finished(parts, kinds)
    table = [rows[i] for i in range(len(inputs))]
    return StudyResult(rows=table, files=_write_tables(out, spec, table),
                       ran=sum(len(b.runs) for b in batches), reused=len(done))


def _run_on(workers: Workers, batches: Sequence[RunBatch], finish) -> None:
    """Submit every batch; hand each result to `finish` as it arrives. On any failure
    or interruption, cancel what has not started (finished part files stay)."""
    pending: dict[Future, RunBatch] = {workers.executor.submit(_run_batch, b): b
                                       for b in batches}
    try:
        while pending:
            done, _ = wait(pending, return_when=FIRST_COMPLETED)
            for fut in sorted(done, key=lambda f: pending[f].runs[0][0]):
                finish(pending.pop(fut), fut.result())
    finally:
        for fut in pending:
            fut.cancel()
