"""`reproduce`: every experiment of the paper into one folder, with a Markdown report.

Also the output formats shared with the CLI: file names, summary CSV/JSON texts and the
checks of the paper's qualitative findings (each PASS/FAIL with its numbers).
"""

from __future__ import annotations

import csv
import io
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from wpam_mj import paper, plots
from wpam_mj.paper import Check
from wpam_mj.params import CALIBRATION_FILE, MM, MPA, Params, describe, preset
from wpam_mj.results import write_text_atomic
from wpam_mj.studies import (StaticLoop,
                             StaticTask, StepRun, StepTask, SweepResult, Table2Result, Batch,
                             TaskPool, figure_run_key, submit_batches, sweep_batch, table2_batch)

PRESET_COMPARE_LOAD_N = 100.0  # our choice for Fig. 3 (the paper's load is not given)


# ------------------------------------------------------------------ names and tables


def _mpa(po: float) -> str:
    return f"{po / MPA:g}"


def static_csv_name(loop: StaticLoop) -> str:
    po = "" if loop.po_down == 0.0 else f"_po{_mpa(loop.po_down)}MPa"
    return f"static_{loop.preset}_{loop.load:g}N{po}.csv"


def step_csv_name(run: StepRun) -> str:
    return f"step_{run.preset}_{run.load:g}N_{run.control}.csv"


def sine_csv_name(key: tuple[float, float, str]) -> str:
    load, freq, ctrl = key
    return f"sine_{load:g}N_{freq:g}Hz_{ctrl}.csv"


def _csv(rows: Sequence[Sequence]) -> str:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    for row in rows:
        w.writerow([f"{v:.6g}" if isinstance(v, float) else v for v in row])
    return buf.getvalue()


def table2_csv_text(t2: Table2Result) -> str:
    rows = t2.rows()
    return _csv([list(rows[0])] + [list(r.values()) for r in rows])


def write_table2(out: Path, t2: Table2Result) -> list[Path]:
    """table2.json and table2.csv in `out`."""
    return [write_text_atomic(out / "table2.json", json.dumps(t2.as_json(), indent=2) + "\n"),
            write_text_atomic(out / "table2.csv", table2_csv_text(t2))]


def table2_text(t2: Table2Result) -> str:
    """Our Table 2 beside the paper's, as plain text."""
    ref = t2.paper()
    head = f"{'condition':<34}" + "".join(f"{f'{v:g} N':>20}" for v in t2.loads)
    sub = f"{'':<34}" + "".join(f"{'ours':>10}{'paper':>10}" for _ in t2.loads)
    lines = ["Table 2: hysteresis-loop area / open-loop (Po = 0) area", head, sub]

    def row(name: str, ours: dict, key: str) -> str:
        cells = "".join(f"{ours[v]:>10.4f}{_fmt(ref[key].get(v)):>10}" for v in t2.loads)
        return f"{name:<34}{cells}"

    lines.append(row("open loop, no Po", {v: 1.0 for v in t2.loads}, "open"))
    lines.append(row(f"open loop, Po = {_mpa(t2.po_down)} MPa", t2.open_po, "open_po"))
    lines.append(row("feedback control (PI)", t2.feedback, "feedback"))
    lines.append("open-loop (Po = 0) areas [MPa mm]: " + ", ".join(
        f"{o.load:g} N: {o.area_mpa_mm:.4g}" for o in t2.open_loops))
    return "\n".join(lines)


def _fmt(v: float | None, spec: str = ".4f") -> str:
    return "-" if v is None or (isinstance(v, float) and math.isnan(v)) else format(v, spec)


SWEEP_COLUMNS = ("load_n", "freq_hz", "controller", "gain", "phase_lag_deg", "po_max_mpa")


def sweep_csv_text(sw: SweepResult) -> str:
    return _csv([SWEEP_COLUMNS] + [[p.as_json()[k] for k in SWEEP_COLUMNS]
                                   for p in sw.points])


def write_sweep(out: Path, sw: SweepResult) -> list[Path]:
    """sweep.json and sweep.csv in `out`."""
    return [write_text_atomic(out / "sweep.json", json.dumps(sw.as_json(), indent=2) + "\n"),
            write_text_atomic(out / "sweep.csv", sweep_csv_text(sw))]


def sweep_text(sw: SweepResult) -> str:
    lines = [f"{'load [N]':>9}{'freq [Hz]':>10}{'ctrl':>6}{'gain':>8}{'lag [deg]':>11}"
             f"{'Po max [MPa]':>14}"]
    for p in sw.points:
        lines.append(f"{p.load:>9g}{p.freq:>10g}{p.controller:>6}{p.gain:>8.3f}"
                     f"{p.phase_lag_deg:>11.1f}{p.po_max / MPA:>14.4f}")
    return "\n".join(lines)


def step_text(run: StepRun) -> str:
    lines = [f"plateau means over the last {run.settle:g} s ({run.load:g} N, {run.control}):",
             f"{'target [mm]':>12}{'x [mm]':>10}{'error [mm]':>12}{'Pi [MPa]':>10}"
             f"{'Po [MPa]':>10}"]
    for tg, x, pi, po in zip(run.target, run.x_mean, run.pi_mean, run.po_mean):
        lines.append(f"{tg / MM:>12g}{x / MM:>10.3f}{(x - tg) / MM:>12.3f}{pi / MPA:>10.4f}"
                     f"{po / MPA:>10.4f}")
    return "\n".join(lines)


def params_markdown(params: Params) -> str:
    lines = ["| parameter | value | unit | source |", "|---|---|---|---|"]
    for name, value, unit, source in describe(params):
        lines.append(f"| `{name}` | {value:.6g} | {unit} | {source} |")
    return "\n".join(lines)


# ------------------------------------------------------------------ checks


def sweep_checks(sw: SweepResult, po_cap: float) -> list[Check]:
    """The paper's frequency-response findings (§4.2) on a sweep (po_cap [Pa])."""
    return paper.check_all(paper.SWEEP_FINDINGS, sw, po_cap)


def table2_checks(t2: Table2Result) -> list[Check]:
    """The Table 2 targets: Po row within 15 % of the paper, feedback row < 0.02 and rising."""
    return paper.check_all(paper.TABLE2_FINDINGS, t2, math.nan)


def checks_markdown(checks: Sequence[Check]) -> str:
    lines = ["| finding (paper) | result | our numbers |", "|---|---|---|"]
    for c in checks:
        lines.append(f"| {c.finding} | **{c.verdict}** | {c.detail} |")
    return "\n".join(lines)


def checks_text(checks: Sequence[Check]) -> str:
    return "\n".join(f"[{c.verdict}] {c.finding}: {c.detail}" for c in checks)


# ------------------------------------------------------------------ reproduce


class _CsvTask:
    """Write one run's CSV (a pool task)."""

    cost = 1.0

    def __init__(self, path: Path, result) -> None:
        self.path, self.result = path, result

    def run(self) -> Path:
        return self.result.to_csv(self.path)


class _FigureTask:
    """Build one figure with `wpam_mj.plots.<builder>` and save it (a pool task)."""

    cost = 3.0

    def __init__(self, path: Path, builder: str, args: tuple, kwargs: dict) -> None:
        self.path, self.builder, self.args, self.kwargs = path, builder, args, kwargs

    def run(self) -> Path:
        return plots.save_figure(getattr(plots, self.builder)(*self.args, **self.kwargs),
                                 self.path)


@dataclass(frozen=True)
class Reproduction:
    report: Path
    table2: Table2Result
    sweep: SweepResult
    checks: tuple[Check, ...]


def reproduce(out_dir: str | Path, params: Params, *, dt: float = 1e-3, jobs: int = 1,
              progress: bool = False, compare: Sequence[Params] | None = None) -> Reproduction:
    """Run every experiment and write CSV/PNG/JSON and `report.md` into `out_dir`.

    Args:
      params: the W-PAM parameters (all experiments).
      compare: muscle types for the Fig. 3 comparison at 100 N; default: the mckibben
        and rlam presets beside `params`.
      dt: physics step [s]; jobs: process-pool size.
    """
    out = Path(out_dir)
    data = out / "data"
    compare = list(compare) if compare is not None else [preset("mckibben"), preset("rlam"),
                                                          params]
    extra = ([StepTask(params, 100.0, "open", dt)]
             + [StaticTask(p, PRESET_COMPARE_LOAD_N, 0.0, dt) for p in compare if p != params])

    def csv_tasks(runs, file_name) -> list[_CsvTask]:
        return [_CsvTask(data / file_name(run), run.result) for run in runs]

    def figure_tasks(figs: dict) -> list[_FigureTask]:
        return [_FigureTask(out / name, *spec) for name, spec in figs.items()]

    # One pool for everything: the runs of all studies longest first, then each study's
    # CSVs and figures as soon as its runs are in (they queue behind the remaining runs).
    with TaskPool(jobs, progress=progress, desc="reproduce") as pool:
        table2_response, extra_response, sweep_response = submit_batches(pool, [
            table2_batch(params, dt=dt), Batch(extra, list), sweep_batch(params, dt=dt)])
        t2 = table2_response()
        outputs = pool.submit(
            csv_tasks((*t2.open_loops, *t2.po_loops), static_csv_name)
            + csv_tasks(t2.feedback_runs, step_csv_name)
            + figure_tasks({
                "fig08_static_po0.png": ("static_figure", (t2.open_loops,), {}),
                "fig09_static_po.png": ("static_figure", (t2.po_loops,), {}),
                "fig14_15_step_pi.png": ("step_figure", ([r.result for r in t2.feedback_runs],),
                                         dict(title="PI on Po at each load (cf. Figs. 14-15)")),
                "fig16_closed_loop_static.png": ("closed_loop_static_figure",
                                                 (t2.feedback_runs, params), {}),
                "table2.png": ("table2_figure", (t2,), {})}))
        write_table2(out, t2)

        open_step, *preset_runs = extra_response()
        own_loop = t2.open_loops[t2.loads.index(PRESET_COMPARE_LOAD_N)]
        ran = iter(preset_runs)
        preset_loops = [own_loop if p == params else next(ran) for p in compare]
        pi_100 = t2.feedback_runs[t2.loads.index(100.0)]
        outputs += pool.submit(
            csv_tasks([r for r in preset_loops if r is not own_loop], static_csv_name)
            + csv_tasks([open_step], step_csv_name)
            + figure_tasks({
                "fig03_presets.png": ("static_figure", (preset_loops,), dict(
                    title="Muscle types, open loop, Po = 0 (cf. paper Fig. 3)")),
                "fig12_13_step_100N.png": ("step_figure", ([open_step.result, pi_100.result],),
                                           dict(title="Step response at 100 N: open loop vs "
                                                      "PI on Po (cf. Figs. 12-13)"))}))

        sw = sweep_response()
        fig_key = figure_run_key(paper.LOADS_N, paper.SWEEP_FREQS_HZ,
                                 paper.SWEEP_CONTROLLERS)
        outputs += pool.submit(
            [_CsvTask(data / sine_csv_name(fig_key), sw.series[fig_key])]
            + figure_tasks({
                "fig17_frequency_response.png": ("sweep_figure", (sw,), {}),
                "fig18_19_sine.png": ("sine_figure", (sw.series[fig_key], fig_key[1],
                                                      params.controller.po_cap), {})}))
        write_sweep(out, sw)
        checks = (*table2_checks(t2), *sweep_checks(sw, params.controller.po_cap))
        write_text_atomic(out / "checks.json", json.dumps(
            [{"finding": c.finding, "passed": c.passed, "detail": c.detail} for c in checks],
            indent=2) + "\n")
        pool.results(outputs)
    text = _report_markdown(params, dt, t2, sw, open_step, preset_loops, checks)
    report = write_text_atomic(out / "report.md", text)
    return Reproduction(report=report, table2=t2, sweep=sw, checks=tuple(checks))


def _report_markdown(params: Params, dt: float, t2: Table2Result, sw: SweepResult,
                     open_step: StepRun, preset_loops: Sequence[StaticLoop],
                     checks: Sequence[Check]) -> str:
    ref = t2.paper()
    calib = (f"`{CALIBRATION_FILE.name}` present" if CALIBRATION_FILE.exists() else
             "no calibration file: built-in defaults")
    n_pass = sum(c.passed is True for c in checks)
    md = [
        "# W-PAM simulation vs Saito, Satoh & Saga (Actuators 2024, 13, 282)",
        "",
        f"Preset `{params.preset}` ({calib}), physics step dt = {dt:g} s. "
        "Generated by `wpam reproduce`; time series (display units) are in `data/`.",
        "",
        "## Checks of the paper's findings",
        "",
        f"{n_pass} of {len(checks)} pass.",
        "",
        checks_markdown(checks),
        "",
        "## Table 2: hysteresis-loop areas",
        "",
        "Loop areas of the measured chamber Pi against x (`loop_area(method=\"branches\")`),"
        " normalized by the open-loop, Po = 0 area of the same load. Feedback: the loop of"
        f" the plateau means (last {t2.feedback_runs[0].settle:g} s of each 10 s plateau,"
        " up branch then down branch), as in the paper's Fig. 16."
        f" Paper values: {paper.TABLE2_SOURCE}.",
        "",
        "| condition | " + " | ".join(f"{v:g} N ours | {v:g} N paper" for v in t2.loads)
        + " |",
        "|---|" + "---|---|" * len(t2.loads),
        "| open loop, no Po (Fig. 8) | " + " | ".join(
            f"1.0000 | {_fmt(ref['open'].get(v))}" for v in t2.loads) + " |",
        f"| open loop, Po = {_mpa(t2.po_down)} MPa (Fig. 9) | " + " | ".join(
            f"{t2.open_po[v]:.4f} | {_fmt(ref['open_po'].get(v))}" for v in t2.loads) + " |",
        "| feedback control (Fig. 16) | " + " | ".join(
            f"{t2.feedback[v]:.4f} | {_fmt(ref['feedback'].get(v))}" for v in t2.loads)
        + " |",
        "",
        "Raw areas [MPa mm]: " + "; ".join(
            f"{r['load_n']:g} N: open {r['open_area_mpa_mm']:.4g}, "
            f"Po {r['open_po_area_mpa_mm']:.4g}, feedback {r['feedback_area_mpa_mm']:.3g}"
            for r in t2.rows()) + ".",
        "",
        "![Table 2](table2.png)",
        "",
        "## Static characteristics (Figs. 3, 8, 9)",
        "",
        "Paper (Fig. 3, §2.2): a rubber McKibben muscle has a much smaller loop than the RLAM."
        " Ours at 100 N, loop areas: " + ", ".join(
            f"{lp.preset} {lp.area_mpa_mm:.3g} MPa mm" for lp in preset_loops) + ".",
        "",
        "![Fig. 3](fig03_presets.png)",
        "",
        "Paper (Fig. 8): contraction grows curvilinearly with Pi; on release x stays put for a"
        " while, then extends quickly.",
        "",
        "![Fig. 8](fig08_static_po0.png)",
        "",
        f"Paper (Fig. 9): a constant Po = {_mpa(t2.po_down)} MPa while Pi falls shrinks the "
        "loop, the more so the heavier the load.",
        "",
        "![Fig. 9](fig09_static_po.png)",
        "",
        "## Step experiments (Figs. 12-16)",
        "",
        "Paper (Figs. 12-13): in open loop the muscle hardly extends after 60 s; with PI on Po"
        " it converges to each target with no steady-state error.",
        "",
        _step_table([open_step, *t2.feedback_runs]),
        "",
        "![Figs. 12-13](fig12_13_step_100N.png)",
        "",
        "![Figs. 14-15](fig14_15_step_pi.png)",
        "",
        "Paper (Fig. 16): the plateau means have no visible hysteresis loop.",
        "",
        "![Fig. 16](fig16_closed_loop_static.png)",
        "",
        "## Frequency response (Figs. 17-19)",
        "",
        "Target 25 mm amplitude about 25 mm; gain and phase lag fitted over "
        "whole steady cycles. Paper: gain falls and lag grows with frequency; gain does "
        "not change with load; below 0.5 Hz lag is smaller at lower load; PID lags less "
        "than PI (150 N); above about 0.5 Hz the system runs at its limit velocity and Po "
        f"hits its {paper.PO_CAP_MPA:g} MPa cap.",
        "",
        _sweep_table(sw),
        "",
        "![Fig. 17](fig17_frequency_response.png)",
        "",
        "![Figs. 18-19](fig18_19_sine.png)",
        "",
        "## Parameters",
        "",
        params_markdown(params),
        "",
    ]
    return "\n".join(md)


def _step_table(runs: Sequence[StepRun]) -> str:
    lines = ["| load | control | max abs plateau error [mm] | error at last plateau (0 mm) [mm] |",
             "|---|---|---|---|"]
    for r in runs:
        err = np.abs(r.error) / MM
        lines.append(f"| {r.load:g} N | {r.control} | {err.max():.3f} | {err[-1]:.3f} |")
    return "\n".join(lines)


def _sweep_table(sw: SweepResult) -> str:
    head = "| load | controller | " + " | ".join(f"{f:g} Hz" for f in sw.freqs) + " |"
    lines = ["Gain / phase lag [deg] / max chamber Po [MPa]:", "", head,
             "|---|---|" + "---|" * len(sw.freqs)]
    for load in sw.loads:
        for c in sw.controllers:
            cells = []
            for f in sw.freqs:
                p = sw.point(load, f, c)
                cells.append("-" if p is None else
                             f"{p.gain:.3f} / {p.phase_lag_deg:.1f} / {p.po_max / MPA:.3f}")
            lines.append(f"| {load:g} N | {c.upper()} | " + " | ".join(cells) + " |")
    return "\n".join(lines)
