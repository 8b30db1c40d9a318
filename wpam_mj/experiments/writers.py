"""Output files of the studies: their names and the CSV/JSON summaries, each written
whole or not at all (`wpam_mj.infra.files.write_text_atomic`), and the figure-and-CSV sets
the single-study commands write."""

from __future__ import annotations

import csv
import io
import json
from pathlib import Path
from typing import Sequence

from wpam_mj.experiments import figures
from wpam_mj.experiments.feasibility import MOVE_MIN_MM, load_moved
from wpam_mj.simulation.results import SimResult
from wpam_mj.infra.files import write_text_atomic
from wpam_mj.experiments.responses import StaticLoop, StepRun, SweepKey, SweepResult, Table2Result
from wpam_mj.experiments.tables import mpa_label


def static_csv_name(loop: StaticLoop) -> str:
    po = "" if loop.po_down == 0.0 else f"_po{mpa_label(loop.po_down)}MPa"
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


SWEEP_COLUMNS = ("load_n", "freq_hz", "controller", "gain", "phase_lag_deg", "po_max_mpa",
                 "load_moved")


def sweep_csv_text(sw: SweepResult) -> str:
    return _csv([SWEEP_COLUMNS] + [[p.as_json()[k] for k in SWEEP_COLUMNS]
                                   for p in sw.points])


def still_points(sw: SweepResult) -> list[str]:
    """The sweep points whose load did not move in the analysed cycles, as
    "100 N 0.5 Hz pi, analysed cycles"."""
    return [f"{p.load:g} N {p.freq:g} Hz {p.controller}, analysed cycles" for p in sw.points
            if not p.load_moved]


def write_sweep(out: Path, sw: SweepResult) -> list[Path]:
    """sweep.json and sweep.csv in `out`."""
    return [write_text_atomic(out / "sweep.json", json.dumps(sw.as_json(), indent=2) + "\n"),
            write_text_atomic(out / "sweep.csv", sweep_csv_text(sw))]


# ---- what the single-study commands write (figures through wpam_mj.experiments.figures), as
# {path: manifest metadata} (`wpam_mj.infra.manifest.write_manifest`); `run_id` goes into each PNG


def run_metadata(result: SimResult) -> dict:
    """What a run's CSV does not hold, for the manifest: its settings and whether the load
    moved at all (`wpam_mj.experiments.feasibility.load_moved`)."""
    return {**result.metadata(), "load_moved": load_moved(result)}


def mark_still_on_figure(fig, still: Sequence[str]):
    """`fig` with one red line naming the runs whose load never moved (their numbers
    mean nothing), so that a figure never shows them as results unmarked."""
    if still:
        fig.text(0.5, 0.0, f"the load never moved (x spanned < {MOVE_MIN_MM:g} mm): "
                 + "; ".join(still), color="red", ha="center", va="bottom", fontsize=7,
                 wrap=True)
    return fig


def write_static_outputs(out: Path, loops: Sequence[StaticLoop], *,
                         compare_presets: bool = False,
                         run_id: str | None = None) -> dict[Path, dict]:
    """One CSV per loop and one figure of all of them (`wpam static`)."""
    written = {lp.result.to_csv(out / static_csv_name(lp)): run_metadata(lp.result)
               for lp in loops}
    po_down = loops[0].po_down
    po = "" if po_down == 0.0 else f"_po{mpa_label(po_down)}MPa"
    stem = "static_presets" if compare_presets else f"static_{loops[0].preset}"
    still = [f"{lp.preset} {lp.load:g} N" for lp in loops if not load_moved(lp.result)]
    written[figures.save_figure(mark_still_on_figure(figures.static_figure(loops), still),
                                out / f"{stem}{po}.png", run_id=run_id)] = {}
    return written


def write_step_outputs(out: Path, run: StepRun, *,
                       run_id: str | None = None) -> dict[Path, dict]:
    """The run's CSV and its figure (`wpam step`)."""
    name = step_csv_name(run)
    return {run.result.to_csv(out / name): run_metadata(run.result),
            figures.save_figure(mark_still_on_figure(figures.step_figure([run.result]),
                                           [] if load_moved(run.result) else [name[:-4]]),
                                out / name.replace(".csv", ".png"), run_id=run_id): {}}


def write_table2_outputs(out: Path, t2: Table2Result, *,
                         run_id: str | None = None) -> dict[Path, dict]:
    """table2.json, table2.csv and table2.png (`wpam table2`)."""
    return {**dict.fromkeys(write_table2(out, t2), {}),
            figures.save_figure(mark_still_on_figure(figures.table2_figure(t2), table2_still(t2)),
                                out / "table2.png", run_id=run_id): {}}


def table2_still(t2: Table2Result) -> list[str]:
    """The Table 2 runs whose load never moved."""
    runs = [(f"open loop {lp.load:g} N, Po {lp.po_down / 1e6:g} MPa", lp.result)
            for lp in (*t2.open_loops, *t2.po_loops)]
    runs += [(f"PI {f.load:g} N", f.result) for f in t2.feedback_runs]
    return [name for name, result in runs if not load_moved(result)]


def write_sweep_outputs(out: Path, sw: SweepResult, key: SweepKey, *,
                        run_id: str | None = None) -> dict[Path, dict]:
    """sweep.json/.csv, the gain-phase figure, and the CSV and figure of the kept run
    `key` (`wpam sweep`), its Po cap drawn in the Po panel."""
    series = sw.series[key]
    return {**dict.fromkeys(write_sweep(out, sw), {}),
            figures.save_figure(mark_still_on_figure(figures.sweep_figure(sw), still_points(sw)),
                                out / "sweep_gain_phase.png", run_id=run_id): {},
            series.to_csv(out / sine_csv_name(key)): run_metadata(series),
            figures.save_figure(mark_still_on_figure(figures.sine_figure(series, key[1]),
                                           [] if load_moved(series) else [sine_csv_name(key)[:-4]]),
                                out / sine_csv_name(key).replace(".csv", ".png"),
                                run_id=run_id): {}}
