"""Figures of a study table: every metric against each varied input, one PNG per input.

When exactly one other input varies over a few values (a two-way grid, e.g. Po cap x
load), each of its values is a line; otherwise every run is a point. A dotted vertical
line marks the preset's own value of a model parameter (e.g. the paper's 0.08 MPa cap).
Display units as in the table. Diverged and infeasible runs have no metrics and are left
out (their count is in the title).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np
from matplotlib.figure import Figure

from wpam_mj.physics.params import preset
from wpam_mj.experiments.figures import save_figure
from wpam_mj.design.study_spec import StudySpec, input_column, metric_labels

MAX_LINES = 8  # our choice: more lines than this are unreadable; plot points instead


def _preset_value(spec: StudySpec, name: str) -> float | None:
    if "." not in name:
        return None
    section, key = name.split(".", 1)
    return input_column(name).display(getattr(getattr(preset(spec.preset), section), key))


def study_figure(spec: StudySpec, rows: Sequence[Mapping[str, Any]], name: str) -> Figure:
    """Metrics of `rows` against the varied input `name`."""
    col = input_column(name)
    metrics = metric_labels(spec.experiment)
    ok = [r for r in rows if not (r["diverged"] or r["infeasible"])]
    others = [n for n in spec.varied if n != name]
    group = None
    if len(others) == 1 and len({r[input_column(others[0]).column] for r in rows}) <= MAX_LINES:
        group = input_column(others[0])
    categorical = name == "controller"
    xs_all = sorted({r[col.column] for r in rows})

    def x_of(row):
        return xs_all.index(row[col.column]) if categorical else row[col.column]

    fig = Figure(figsize=(6.4, 2.2 * len(metrics) + 0.8), layout="constrained")
    axes = fig.subplots(len(metrics), 1, sharex=True, squeeze=False)[:, 0]
    marker_only = group is None or spec.method in ("random", "lhs")
    for ax, (metric, label) in zip(axes, metrics):
        keys = sorted({r[group.column] for r in ok}) if group else [None]
        for key in keys:
            mine = [r for r in ok if group is None or r[group.column] == key]
            mine.sort(key=x_of)
            kw = {"label": group.describe(key) if group else None}
            ax.plot([x_of(r) for r in mine], [r[metric] for r in mine],
                    "o" if marker_only else "o-", ms=3 if group is None else 4, **kw)
        ref = _preset_value(spec, name)
        if ref is not None:
            ax.axvline(ref, color="0.4", ls=":", lw=1)
        ax.set_ylabel(label)
        ax.grid(True, alpha=0.3)
    if group is not None:
        axes[0].legend(fontsize="small")
    axes[-1].set_xlabel(col.label + ("  (dotted: preset value)"
                                     if _preset_value(spec, name) is not None else ""))
    if categorical:
        axes[-1].set_xticks(np.arange(len(xs_all)), xs_all)
    failed = len(rows) - len(ok)
    fig.suptitle(f"{spec.experiment} study: {len(rows)} runs"
                 + (f", {failed} diverged or infeasible" if failed else ""))
    return fig


def save_study_plots(spec: StudySpec, rows: Sequence[Mapping[str, Any]],
                     folder: str | Path) -> list[Path]:
    """One PNG per varied input in `folder` (named after its table column)."""
    folder = Path(folder)
    return [save_figure(study_figure(spec, rows, name),
                        folder / f"{input_column(name).column}.png")
            for name in spec.varied]
