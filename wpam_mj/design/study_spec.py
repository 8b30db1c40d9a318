"""A design-space study's file and its table's columns: the format, read and validated.

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
[s] (step: the staircase's length, default 110, at least MIN_STEP_DURATION_S), `po_down`
[Pa] (static, table2).

Runs are numbered in sampling order (grid: the last name varies fastest; random and
Latin-hypercube samples come from numpy's PCG64 seeded with `seed`, through
scipy.stats.qmc for the hypercube), so a study file always means the same runs. They run
in batches (one task per batch, each building its parameter set once) on any
`concurrent.futures.Executor` (`wpam_mj.infra.pool`). Every finished batch is written at
once as its own part file, so an interrupted study resumes where it stopped; the table is
then assembled from the part files in run order: the same bytes whatever the executor,
the number of jobs or the interruptions. A run that diverges (SimulationDiverged) or
whose inputs are infeasible (ParameterError, e.g. a Po cap below the feedforward Po) is
a row with its flag set and NaN metrics, not a failed study.

Table columns are in display units, named with them (`load_n`, `controller.po_cap_mpa`).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

from wpam_mj.control.controllers import CONTROLS, check_control
from wpam_mj.experiments.drives import STATIC_RAMP_S, SineSpec, check_po
from wpam_mj.infra.budget import MAX_RUN_S
from wpam_mj.paper import PO_DOWN_STATIC_MPA, STEP_HOLD_S, STEP_LEVELS_MM
from wpam_mj.physics.params import PRESETS, Params, preset
from wpam_mj.errors import ParameterError, check_range, load_toml
from wpam_mj.units import MM, MPA
from wpam_mj.simulation.context import check_dt, check_load

EXPERIMENTS = ("static", "step", "sine", "table2")
METHODS = ("grid", "list", "random", "lhs")
MAX_RUNS = 1_000_000  # our choice: a bound that catches a runaway grid before it starts
RECORD_DT_S = 0.01  # every run records at this period (`wpam_mj.simulation.simulate.simulate`)
STEP_DURATION_S = len(STEP_LEVELS_MM) * STEP_HOLD_S  # paper §4.1 staircase, 110 s
# Our choice: the shortest plateau on which the shipped plant's PI and PID staircases are
# at rest over the averaged last half (x within 0.2 mm peak to peak at 50-150 N; 2.5 s
# plateaus leave PI swinging 1.9 mm): shorter staircases have no settled plateau means.
MIN_STEP_HOLD_S = 3.0
MIN_STEP_DURATION_S = len(STEP_LEVELS_MM) * MIN_STEP_HOLD_S  # 33 s
STATIC_DURATION_S = 2 * STATIC_RAMP_S + 2.0  # `experiments.static_loop`: ramps + 1 s dwells
# Parameter sections of the config file (braid, muscle, pneumatics, controller)
SECTIONS = {f.name: type(getattr(Params(), f.name)) for f in dataclasses.fields(Params)
             if f.name != "preset"}

# Run inputs other than model parameters: (default [SI], unit, experiments that take it).
RUN_INPUTS: dict[str, tuple[Any, str, tuple[str, ...]]] = {
    "load": (100.0, "N", EXPERIMENTS),
    "controller": ("pi", "", ("step", "sine")),
    "frequency": (0.5, "Hz", ("sine",)),
    "amplitude": (SineSpec(1.0).amplitude, "m", ("sine",)),
    "duration": (STEP_DURATION_S, "s", ("step",)),
    "po_down": (None, "Pa", ("static", "table2")),  # None: per experiment
}
PO_DOWN_DEFAULT = {"static": 0.0, "table2": PO_DOWN_STATIC_MPA * MPA}
_DISPLAY_UNITS = {"Pa": ("MPa", MPA), "m": ("mm", MM)}  # display unit, SI per display unit

# Metric columns per experiment: (column, axis label).
METRICS = {
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
FLAGS = ("diverged", "infeasible")


def metric_labels(experiment: str) -> tuple[tuple[str, str], ...]:
    """(column, axis label with unit) of each metric of an experiment."""
    return METRICS[experiment]


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
    fields = {f.name: f for f in dataclasses.fields(SECTIONS[section])} \
        if section in SECTIONS else {}
    if key not in fields:
        raise ParameterError(f"unknown study input {name!r}; valid: "
                             + ", ".join(RUN_INPUTS) + ", or section.field of "
                             + ", ".join(SECTIONS))
    return fields[key]


def input_column(name: str) -> Column:
    """The table column of a study input (display units)."""
    unit = RUN_INPUTS[name][1] if name in RUN_INPUTS else \
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
        names.update(dict.fromkeys(k for k, v in RUN_INPUTS.items()
                                   if self.experiment in v[2]))
        return tuple(names)

    @property
    def columns(self) -> tuple[str, ...]:
        return ("run", *(input_column(n).column for n in self.inputs),
                *(m for m, _ in METRICS[self.experiment]), *FLAGS, "error")

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
            if key not in SECTIONS:
                raise ParameterError(f"{where}: unknown section {key!r}; valid: "
                                     + ", ".join(SECTIONS))
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
        return _step_duration(value)
    if name == "po_down":
        return check_po("po_down", value, base)
    md = _param_field(name).metadata
    return check_range(name, value, md["lo"], md["hi"], md["unit"], lo_open=md["lo_open"])


def _step_duration(value: float) -> float:
    """A step run's length [s]: long enough that its plateaus settle (MIN_STEP_HOLD_S each),
    short enough for one run (MAX_RUN_S)."""
    n = len(STEP_LEVELS_MM)
    if value < MIN_STEP_DURATION_S:
        raise ParameterError(
            f"duration = {value:g} s: its {n} plateaus of {value / n:.3g} s are too short to "
            f"settle on; the step protocol holds from {MIN_STEP_DURATION_S:g} s "
            f"({MIN_STEP_HOLD_S:g} s plateaus; the paper's: {STEP_DURATION_S:g} s)")
    return check_range("duration", value, MIN_STEP_DURATION_S, MAX_RUN_S, "s")


def _dt(value: Any) -> float:
    """The study's physics step [s]: what `--dt` accepts (it must divide the recording
    period), so that a study file cannot ask for a run the command line refuses."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ParameterError(f"dt = {value!r} is not a number; give seconds, e.g. 1e-3")
    return check_dt(float(value), divides=RECORD_DT_S, name="dt")


def _allowed(name: str, experiment: str) -> None:
    if name in RUN_INPUTS and experiment not in RUN_INPUTS[name][2]:
        users = ", ".join(RUN_INPUTS[name][2])
        raise ParameterError(f"{name} is not an input of the {experiment} experiment "
                             f"(only of {users})")
    if name not in RUN_INPUTS:
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
