"""The measured feasibility map of the paper's findings, from a search's archive.

For findings i and j, `pair_margins` gives the best margin of i found among the points
of the search at which j holds (>= 0: some credible point meets both); the diagonal is
i's best margin over every point. Margins are in units of each margin's scale
(`wpam_mj.reproduction.search_scoring.finding_margins`). A map is a measurement of the
points searched, not a proof over the whole box: a pair marked as conflicting had no point
meeting both among those evaluated, and the best joint margin says by how much it missed.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Sequence

import numpy as np

from wpam_mj.reproduction.search_scoring import (FINDING_TEXT, FINDINGS, PAPER_CHECKS, TRACK_MM,
                                                 margin_of,
                                                 Record, shortfall)


def margin_matrix(records: Sequence[Record]) -> np.ndarray:
    """Margins of the points that track, shape (n_points, n_findings); a margin that
    could not be computed (NaN: e.g. no gain where the muscle did not move) fails."""
    rows = [[margin_of(r, f) for f in FINDINGS] for r in records if r.tracks]
    m = np.array(rows, dtype=float).reshape(-1, len(FINDINGS))
    return np.where(np.isnan(m), -np.inf, m)


def pair_margins(records: Sequence[Record]) -> np.ndarray:
    """M[i, j]: the best margin of finding i where finding j holds (NaN: j never
    holds); M[i, i]: i's best margin anywhere."""
    m = margin_matrix(records)
    n = len(FINDINGS)
    out = np.full((n, n), math.nan)
    for j in range(n):
        holds = m[:, j] >= 0.0
        for i in range(n):
            rows = m[:, i] if i == j else m[holds, i]
            if rows.size:
                out[i, j] = rows.max()
    return out


def conflicts(pm: np.ndarray) -> list[tuple[str, str, float]]:
    """(i, j, best margin of i while j holds) for pairs each met alone but never
    together among the points searched (each unordered pair once)."""
    out = []
    for i in range(len(FINDINGS)):
        for j in range(i + 1, len(FINDINGS)):
            if pm[i, i] >= 0.0 and pm[j, j] >= 0.0 and not pm[i, j] >= 0.0:
                out.append((FINDINGS[i], FINDINGS[j], float(pm[i, j])))
    return out


def never_met(pm: np.ndarray) -> list[tuple[str, float]]:
    """(finding, best margin) of the findings no point of the search meets."""
    return [(f, float(pm[i, i])) for i, f in enumerate(FINDINGS) if not pm[i, i] >= 0.0]


def verdict(pm: np.ndarray) -> str:
    """The findings never met, and the pairs met alone but never together."""
    lines = ["Never met by any point searched (best margin):"]
    lines += [f"- {FINDING_TEXT[f]} ({m:+.2f})" for f, m in never_met(pm)] or ["- none"]
    lines += ["", "Met alone but never together (best margin of the first while the "
              "second holds):"]
    lines += [f"- {FINDING_TEXT[a]} / {FINDING_TEXT[b]} ({m:+.2f})"
              for a, b, m in conflicts(pm)] or ["- none"]
    return "\n".join(lines)


def _rest(records: Sequence[Record]) -> dict[str, tuple[float, int]]:
    """Per finding: its best margin among the points at which every other finding holds
    (NaN: no point holds all the others), and how many such points there are."""
    m = margin_matrix(records)
    out = {}
    for i, f in enumerate(FINDINGS):
        rest = np.all(np.delete(m, i, axis=1) >= 0.0, axis=1)
        out[f] = (float(m[rest, i].max()) if rest.any() else math.nan, int(rest.sum()))
    return out


def rest_margins(records: Sequence[Record]) -> dict[str, float]:
    """Per finding: its best margin among the points at which every other finding holds
    (NaN: no point holds all the others). Negative: among the points searched, that
    finding conflicts with the rest taken together, by that much at least."""
    return {f: v for f, (v, _) in _rest(records).items()}


def rest_verdict(records: Sequence[Record]) -> str:
    """`rest_margins` as text: which findings the others, held together, leave open."""
    lines = ["With every other finding held (best margin of the finding; points holding "
             "all the others):"]
    for f, (v, n) in _rest(records).items():
        lines.append(f"- {FINDING_TEXT[f]}: " + ("no point holds all the others"
                                                  if math.isnan(v) else f"{v:+.2f} ({n})"))
    return "\n".join(lines)


def held_with(records: Sequence[Record], kept: str) -> tuple[int, int, list[str]]:
    """Among the tracking points at which finding `kept` holds: how many there are, the
    most of `wpam reproduce`'s checks one of them meets, and the checks that point (the
    least shortfall among those meeting most) misses. (0, 0, []) when none holds it."""
    ok = [r for r in records if r.tracks and margin_of(r, kept) >= 0.0]
    if not ok:
        return 0, 0, []
    best = min(ok, key=lambda r: (-r.held, shortfall(r)))
    return len(ok), best.held, [f for f in PAPER_CHECKS if margin_of(best, f) < 0.0]


def best_compromise(records: Sequence[Record], objective=lambda r: r.cost) -> Record:
    """The tracking point of least `objective` (default calibrate's one cost, which
    weighs by how much each finding is missed, where a count of findings met would take
    a Table 2 cell 20x off the paper for one more frequency-response finding)."""
    return min((r for r in records if r.tracks), key=objective)


def most_findings(records: Sequence[Record]) -> Record:
    """The tracking point meeting the most findings (least cost among those)."""
    return min((r for r in records if r.tracks), key=lambda r: (-r.held, r.cost))


def _cell(v: float) -> str:
    return "never holds" if math.isnan(v) else f"{v:+.2f}"


def markdown(pm: np.ndarray, records: Sequence[Record]) -> str:
    """The map as a Markdown table (rows: finding i; columns: while j holds)."""
    short = [f"F{k + 1}" for k in range(len(FINDINGS))]
    lines = ["| finding | best alone | " + " | ".join(f"while {s}" for s in short) + " |",
             "|---|---|" + "---|" * len(FINDINGS)]
    for i, f in enumerate(FINDINGS):
        cells = ["" if i == j else _cell(pm[i, j]) for j in range(len(FINDINGS))]
        lines.append(f"| {short[i]} {FINDING_TEXT[f]} | {_cell(pm[i, i])} | "
                     + " | ".join(cells) + " |")
    lines.append("")
    n = sum(r.tracks for r in records)
    lines.append(f"Best signed margin of each finding (in units of its margin's scale; "
                 f">= 0 holds) over the {n} points of the {len(records)} searched whose PI "
                 f"staircase follows its targets (worst error <= {TRACK_MM:g} mm), alone "
                 "and while another finding holds.")
    return "\n".join(lines)


def figure(pm: np.ndarray, path: Path, title: str) -> Path:
    """A heat map of `pair_margins` (green: both met; red: never together), as PNG."""
    import matplotlib  # noqa: PLC0415 (plotting only here)
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    n = len(FINDINGS)
    shown = np.clip(np.nan_to_num(pm, nan=-3.0), -3.0, 3.0)
    fig, ax = plt.subplots(figsize=(11, 9))
    im = ax.imshow(shown, cmap="RdYlGn", vmin=-1.0, vmax=1.0)
    for i in range(n):
        for j in range(n):
            ax.text(j, i, _cell(pm[i, j]).replace("never holds", "-"), ha="center",
                    va="center", fontsize=7, fontweight="bold" if i == j else "normal")
    labels = [f"F{k + 1} {FINDING_TEXT[f]}" for k, f in enumerate(FINDINGS)]
    ax.set_xticks(range(n), [f"F{k + 1}" for k in range(n)])
    ax.set_yticks(range(n), labels, fontsize=8)
    ax.set_xlabel("while this finding holds")
    ax.set_title(title, fontsize=10)
    fig.colorbar(im, ax=ax, shrink=0.7, label="best margin of the row's finding (scale units)")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def convergence_csv(conv: Sequence[tuple[int, float, int, float]]) -> str:
    """`search.convergence` as CSV: points scored, least objective and most of `wpam
    reproduce`'s checks met so far, and the wall seconds into the search (blank: not
    recorded)."""
    return "points_scored,best_cost,most_checks_met,seconds\n" + "".join(
        f"{i},{c!r},{h},{'' if math.isnan(t) else f'{t:.1f}'}\n" for i, c, h, t in conv)


def convergence_figure(runs: dict[str, Sequence[tuple[int, float, int, float]]], path: Path,
                       title: str, objective: str = "calibrate's cost 1/2 |r|^2") -> Path:
    """Least cost (log scale) and most findings met against points scored, one line per
    search (`runs`: label -> `search.convergence`), as PNG."""
    import matplotlib  # noqa: PLC0415 (plotting only here)
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    fig, (top, bottom) = plt.subplots(2, 1, figsize=(7, 6), sharex=True)
    for label, conv in runs.items():
        i, cost, held, _ = (np.array(v) for v in zip(*conv))
        top.step(i, np.minimum(cost, 1e3), where="post", label=label)
        bottom.step(i, held, where="post", label=label)
    top.set_yscale("log")
    top.set_ylabel(f"least so far:\n{objective}")
    bottom.set_ylabel(f"most checks met (of {len(PAPER_CHECKS)})")
    bottom.set_xlabel("points scored")
    bottom.axhline(6, color="grey", lw=0.8, ls=":")
    bottom.set_ylim(0, len(PAPER_CHECKS) + 0.5)
    top.legend(fontsize=8)
    top.set_title(title, fontsize=10)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
