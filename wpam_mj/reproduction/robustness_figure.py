"""The robustness figure: per finding the fraction of sampled plants that hold it, and
each Table 2 cell over the plants beside the paper's (`wpam_mj.reproduction.robustness`)."""

from __future__ import annotations

import math

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402

from wpam_mj import paper  # noqa: E402
from wpam_mj.reproduction import findings  # noqa: E402


def robustness_figure(result) -> Figure:
    """Left: fraction of plants holding each finding with its 95 % interval (the 80 %
    target dashed), split into the plants the controller's feedforward over-contracts
    (solid) and the others (pale); right: Table 2's cells of every plant (dots) and the
    paper's (black bars), log scale."""
    from wpam_mj.reproduction.robustness import CELLS, HOLD_TARGET  # noqa: PLC0415

    held = result.held_fraction()
    names = [n for n in held if not math.isnan(held[n])]
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(12, 5.8),
                                   gridspec_kw=dict(width_ratios=[3, 2]))
    colours = ["tab:green" if held[n] >= HOLD_TARGET else "tab:red" for n in names]
    over, short = result.over_contracted()
    if over or short:  # each plant's share of the bar, by whether it is over-contracted
        total = len(result.outcomes)
        solid = [100 * sum(bool(o.holds(n)) for o in over) / total for n in names]
        pale = [100 * sum(bool(o.holds(n)) for o in short) / total for n in names]
        ax1.barh(range(len(names)), solid, color=colours)
        ax1.barh(range(len(names)), pale, left=solid, color=colours, alpha=0.4)
        for alpha, label in ((1.0, f"over-contracted by the feedforward's Pi ({len(over)} plants)"),
                             (0.4, f"the others ({len(short)} plants)")):
            ax1.barh([0], [0], color="0.35", alpha=alpha, label=label)  # legend key only
    else:
        ax1.barh(range(len(names)), [100 * held[n] for n in names], color=colours)
    interval = result.held_interval()
    ax1.errorbar([100 * held[n] for n in names], range(len(names)), fmt="none", ecolor="k",
                 elinewidth=1, capsize=3, label="95 % interval (Wilson)",
                 xerr=[[100 * (held[n] - interval[n][0]) for n in names],
                       [100 * (interval[n][1] - held[n]) for n in names]])
    ax1.set_yticks(range(len(names)),
                   [findings.FINDINGS[n].short + ("" if findings.FINDINGS[n].counted
                                                  else " (extra)") for n in names],
                   fontsize=8)
    ax1.invert_yaxis()
    ax1.axvline(100 * HOLD_TARGET, color="k", ls="--", lw=1, label=f"{HOLD_TARGET:.0%} target")
    ax1.set_xlim(0, 100)
    ax1.set_xlabel("plants holding the finding [%]")
    model = ("controller's model fitted to each" if result.feedforward == "calibrated"
             else "controller's model nominal")
    ax1.set_title(f"{len(result.outcomes)} plants, unmeasured values within "
                  f"{result.box()}; {model}", fontsize=10)
    # below the bars: any corner of the axes may hold a bar of 100 % or 0 %
    ax1.legend(loc="upper center", bbox_to_anchor=(0.5, -0.1), ncol=2, fontsize=8)
    for i, (row, load) in enumerate(CELLS):
        v = [o.cells[(row, load)] for o in result.outcomes if (row, load) in o.cells]
        ax2.plot([i] * len(v), v, "o", color="tab:blue", alpha=0.4, ms=4,
                 label="sampled plants" if i == 0 else None)
        ax2.plot([i - 0.3, i + 0.3], [paper.TABLE2[row][load]] * 2, "k-", lw=2,
                 label="paper (Table 2)" if i == 0 else None)
    ax2.set_yscale("log")
    ax2.set_xticks(range(len(CELLS)),
                   [f"{'Po' if r == 'open_po' else 'fb'}\n{load:g} N" for r, load in CELLS])
    ax2.set_ylabel("loop area / open-loop area [1]")
    ax2.set_title("Table 2 cells over the plants")
    ax2.legend(fontsize=8)
    fig.tight_layout()
    return fig
