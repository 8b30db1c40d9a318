"""What a finding is and how it is checked: signed margins, checks, their text.

A finding of the paper is one function from a study's result to `Margin`s: one signed
distance per place it can be checked (a load, a frequency, a controller), >= 0 where it
holds. `wpam reproduce` prints PASS/FAIL from them (`Check`), calibration uses the same
margins as its residuals (`residuals`) and the search as its map's coordinates, so none
of them can disagree about what the paper says or how closely we must match it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable, Sequence

import numpy as np

from wpam_mj.paper import CALIBRATION_HEADROOM


@dataclass(frozen=True)
class Margin:
    """One place a finding is checked: `value` against `limit` in the same unit.

    sense = +1: holds when value >= limit; -1: when value <= limit. `margin` is the
    signed distance (>= 0 holds); `scale` is the size of a clear miss in that unit (the
    calibration residual's unit). load [N], freq [Hz], controller: where it was checked.
    """

    value: float
    limit: float
    sense: int
    scale: float
    load: float | None = None
    freq: float | None = None
    controller: str | None = None

    @property
    def margin(self) -> float:
        return self.sense * (self.value - self.limit)


@dataclass(frozen=True)
class Finding:
    """A claim of the paper and how we read it.

    `name`: how code and files refer to it; `sentence`: the paper's own words with where
    they stand; `text`: our reading as a test, with its limits (formatted with the
    simulated po_cap_mpa, read from the result's context); `short`: a label;
    `margins(result)` (None when the result lacks the data, said by `needs`);
    `detail(result, margins)`: the numbers a reader checks it by. `counted`: False for a
    reading of ours that no sentence of the paper states (reported as an extra, not
    counted in the score).
    """

    name: str
    short: str
    sentence: str
    text: str
    margins: Callable[[Any], list[Margin] | None]
    detail: Callable[[Any, list[Margin]], str]
    needs: str
    counted: bool = True


@dataclass(frozen=True)
class Check:
    """A finding checked on a result: passed is None when the data are missing.
    `name` is the finding's, `finding` our reading of it, `sentence` the paper's words."""

    name: str
    finding: str
    passed: bool | None
    detail: str
    margins: tuple[Margin, ...] = ()
    sentence: str = ""
    counted: bool = True

    @property
    def verdict(self) -> str:
        return {True: "PASS", False: "FAIL", None: "n/a"}[self.passed]

    @property
    def worst_margin(self) -> float:
        """The smallest margin in units of its scale (>= 0 holds; nan: not checked)."""
        return min((m.margin / m.scale for m in self.margins), default=math.nan)


def check(finding: Finding, result) -> Check:
    """Evaluate one finding on a study result, which carries its context (the simulated
    Po cap among it)."""
    text = finding.text.format(po_cap_mpa=result.context.po_cap / 1e6)
    where = dict(sentence=finding.sentence, counted=finding.counted)
    margins = finding.margins(result)
    if margins is None:
        return Check(finding.name, text, None, finding.needs, **where)
    return Check(finding.name, text, all(m.margin >= 0.0 for m in margins),
                 finding.detail(result, margins), tuple(margins), **where)


def check_all(findings: Sequence[Finding], result) -> list[Check]:
    return [check(f, result) for f in findings]


def residuals(checks: Sequence[Check]) -> np.ndarray:
    """Calibration residuals of checked findings: one per margin, 0 where it holds with
    CALIBRATION_HEADROOM to spare, else the shortfall in units of the margin's scale."""
    return np.array([max(0.0, CALIBRATION_HEADROOM - m.margin / m.scale)
                     for c in checks for m in c.margins])


def score(checks: Sequence[Check]) -> tuple[int, int]:
    """(held, counted): the paper's sentences that hold, of those checked; extras aside."""
    counted = [c for c in checks if c.counted and c.passed is not None]
    return sum(c.passed for c in counted), len(counted)


def checks_text(checks: Sequence[Check]) -> str:
    """One line per check: verdict, finding, worst margin (scale units), our numbers;
    an extra (a reading of ours, not counted) is marked so."""
    return "\n".join(f"[{c.verdict}]{'' if c.counted else ' (extra)'} {c.finding} "
                     f"(margin {c.worst_margin:+.3f}): {c.detail}" for c in checks)


def checks_markdown(checks: Sequence[Check]) -> str:
    """The checks as a Markdown table (the report's): the paper's sentence, our reading,
    the verdict, the worst margin and our numbers."""
    lines = ["| the paper says | our reading (test) | result | worst margin (scale units, "
             ">= 0 holds) | our numbers |", "|---|---|---|---|---|"]
    for c in checks:
        said = c.sentence if c.counted else f"(extra: no sentence states it) {c.sentence}"
        lines.append(f"| {said} | {c.finding} | **{c.verdict}** | {c.worst_margin:+.3f} | "
                     f"{c.detail} |")
    return "\n".join(lines)
