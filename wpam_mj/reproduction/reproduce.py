"""`reproduce`: every experiment of the paper into one folder, with report.md.

The execution layer runs every study's runs at once (longest first), then every CSV and
figure (on the local process pool with --jobs > 1); the summaries, checks and report
follow.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Sequence

from wpam_mj import paper
from wpam_mj.experiments import figures
from wpam_mj.reproduction import feedforward_fit, findings, robustness
from wpam_mj.reproduction.findings import Check
from wpam_mj.physics.muscle_types import COMPARED_TYPES
from wpam_mj.physics.params import Params, preset
from wpam_mj.infra.pool import open_workers
from wpam_mj.reproduction.report import report_markdown
from wpam_mj.infra.files import write_text_atomic
from wpam_mj.experiments.protocol import SHIPPED, Protocol, table2_batch
from wpam_mj.experiments.paper_studies import StaticTask, StepTask, figure_run_key, sweep_batch
from wpam_mj.experiments.responses import SweepResult, Table2Result
from wpam_mj.simulation.execution import Batch, execute
from wpam_mj.experiments.writers import (run_metadata, sine_csv_name, static_csv_name,
                                         step_csv_name, write_sweep, write_table2)


PRESET_COMPARE_LOAD_N = 100.0  # our choice for Fig. 3 (the paper's load is not given)


class _CsvTask:
    """Write one run's CSV (a task)."""

    cost = 1.0

    def __init__(self, path: Path, result) -> None:
        self.path, self.result = path, result

    def run(self) -> Path:
        return self.result.to_csv(self.path)


class _FigureTask:
    """Build one figure with `wpam_mj.experiments.figures.<builder>` and save it (a task)."""

    cost = 3.0

    def __init__(self, path: Path, builder: str, args: tuple, kwargs: dict,
                 run_id: str | None) -> None:
        self.path, self.builder, self.args, self.kwargs = path, builder, args, kwargs
        self.run_id = run_id

    def run(self) -> Path:
        return figures.save_figure(getattr(figures, self.builder)(*self.args, **self.kwargs),
                                   self.path, run_id=self.run_id)


@dataclass(frozen=True)
class Reproduction:
    report: Path
    table2: Table2Result
    sweep: SweepResult
    checks: tuple[Check, ...]
    files: dict[Path, dict]  # every file written, with its manifest metadata


def reproduce(out_dir: str | Path, params: Params, *, dt: float = 1e-3, jobs: int = 1,
              progress: bool = False, compare: Sequence[Params] | None = None,
              run_id: str | None = None, protocol: Protocol = SHIPPED,
              feedforward: str = "calibrated", calibration_ramp_time: float | None = None,
              robustness_sample: Mapping[str, Any] | None = None) -> Reproduction:
    """Run every experiment and write CSV/PNG/JSON and `report.md` into `out_dir`.

    Args:
      params: the W-PAM parameters (all experiments).
      compare: muscle types for the Fig. 3 comparison at 100 N; default: every type of
        `COMPARED_TYPES`, `params` for its own.
      dt: physics step [s]; jobs: process-pool size.
      run_id: the run's id (`wpam_mj.infra.manifest.run_id`), recorded in every figure.
      protocol: the static ramps' readings (`wpam_mj.experiments.protocol`) for Figs. 8-9, Table 2.
      feedforward: the controller's equilibrium model (`feedforward_fit`): "calibrated",
        fitted to the plant's own open-loop loops first (ramps of `calibration_ramp_time`
        [s], default the protocol's); "nominal", `params`' own values.
      robustness_sample: the keywords of `wpam_mj.reproduction.robustness.robustness`
        (n plants, seed, rel, measured, feedforward): adds the findings over those
        plants to report.md and its files (None or n = 0: none).
    """
    out = Path(out_dir)
    data = out / "data"
    feedforward_fit.check_feedforward_model(feedforward)
    compare = list(compare) if compare is not None else [
        params if name == params.preset else preset(name) for name in COMPARED_TYPES]

    files: dict[Path, dict] = {}

    def csv_tasks(runs, file_name) -> list[_CsvTask]:
        return [csv_task(data / file_name(run), run.result) for run in runs]

    def csv_task(path: Path, result) -> _CsvTask:
        files[path] = run_metadata(result)
        return _CsvTask(path, result)

    def figure_tasks(figs: dict) -> list[_FigureTask]:
        files.update(dict.fromkeys((out / name for name in figs), {}))
        return [_FigureTask(out / name, *spec, run_id) for name, spec in figs.items()]

    # Table 2's and the comparisons' runs; then the sweep's runs here while their CSVs and
    # figures are drawn on the pool; then the sweep's.
    with open_workers(jobs) as workers:
        plant, controller_model, open_loops = params, "", ()
        if feedforward == "calibrated":
            fit = feedforward_fit.calibrate_one(plant, protocol, dt, workers,
                                                ramp_time=calibration_ramp_time)
            params, open_loops = fit.params, fit.loops
            compare = [params if p == plant else p for p in compare]
            controller_model = feedforward_fit.model_markdown(params, fit.rms)
        extra = ([StepTask(params, 100.0, "open", dt)]
                 + [StaticTask(p, PRESET_COMPARE_LOAD_N, 0.0, dt) for p in compare
                    if p != params])
        t2, (open_step, *preset_runs) = execute(
            [table2_batch(params, protocol, dt=dt, open_loops=open_loops),
             Batch(extra, list)], workers,
            progress=progress, desc="reproduce")
        outputs = (
            csv_tasks((*t2.open_loops, *t2.po_loops), static_csv_name)
            + csv_tasks(t2.feedback_runs, step_csv_name)
            + figure_tasks({
                "fig08_static_po0.png": ("static_figure", (t2.open_loops,), {}),
                "fig09_static_po.png": ("static_figure", (t2.po_loops,), {}),
                "fig14_15_step_pi.png": ("step_figure", ([r.result for r in t2.feedback_runs],),
                                         dict(title="PI on Po at each load (cf. Figs. 14-15)")),
                "fig16_closed_loop_static.png": ("closed_loop_static_figure",
                                                 (t2.feedback_runs,), {}),
                "table2.png": ("table2_figure", (t2,), {})}))
        files.update(dict.fromkeys(write_table2(out, t2), {}))

        own_loop = t2.open_loops[t2.loads.index(PRESET_COMPARE_LOAD_N)]
        ran = iter(preset_runs)
        preset_loops = [own_loop if p == params else next(ran) for p in compare]
        pi_100 = t2.feedback_runs[t2.loads.index(100.0)]
        outputs += (
            csv_tasks([r for r in preset_loops if r is not own_loop], static_csv_name)
            + csv_tasks([open_step], step_csv_name)
            + figure_tasks({
                "fig03_presets.png": ("static_figure", (preset_loops,), dict(
                    title="Muscle types, open loop, Po = 0 (cf. paper Fig. 3)")),
                "fig12_13_step_100N.png": ("step_figure", ([open_step.result, pi_100.result],),
                                           dict(title="Step response at 100 N: open loop vs "
                                                      "PI on Po (cf. Figs. 12-13)"))}))

        sw, *_ = execute([sweep_batch(params, dt=dt), *outputs], workers, progress=progress,
                         desc="sweep")
        fig_key = figure_run_key(paper.LOADS_N, paper.SWEEP_FREQS_HZ,
                                 paper.SWEEP_CONTROLLERS)
        outputs = (
            [csv_task(data / sine_csv_name(fig_key), sw.series[fig_key])]
            + figure_tasks({
                "fig17_frequency_response.png": ("sweep_figure", (sw,), {}),
                "fig18_19_sine.png": ("sine_figure", (sw.series[fig_key], fig_key[1]), {})}))
        files.update(dict.fromkeys(write_sweep(out, sw), {}))
        checks = findings.all_checks(t2, open_step, sw)
        files[write_checks(out, checks)] = {}
        execute(outputs, workers, progress=progress, desc="files")
    text = report_markdown(t2, sw, open_step, preset_loops, checks, protocol,
                           controller_model)
    if robustness_sample and robustness_sample.get("n"):
        rob = robustness.robustness(plant, **robustness_sample, dt=dt, jobs=jobs,
                                    progress=progress, protocol=protocol)
        files.update(dict.fromkeys(robustness.write_robustness(out, rob), {}))
        text += ("\n## Robustness: the findings across the plant's uncertainty\n\n"
                 + rob.markdown() + "\n\n![Robustness](robustness.png)\n")
    report = write_text_atomic(out / "report.md", text)
    files[report] = {}
    return Reproduction(report=report, table2=t2, sweep=sw, checks=tuple(checks), files=files)


def write_checks(out: Path, checks: Sequence[Check]) -> Path:
    """checks.json in `out`: finding, passed (true/false/null) and detail of each check."""
    return write_text_atomic(out / "checks.json", json.dumps(
        [{"name": c.name, "sentence": c.sentence, "finding": c.finding, "counted": c.counted,
          "passed": c.passed, "worst_margin": c.worst_margin, "detail": c.detail}
         for c in checks],
        indent=2) + "\n")
