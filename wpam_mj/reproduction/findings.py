"""The paper's findings, each once, by name: every claim of §4 and the abstract as a
`margins.Finding` that prints the paper's sentence beside our reading of it.

`wpam reproduce` prints PASS/FAIL from them, calibration uses the same margins as its
residuals and the search as its map's coordinates. Findings are looked up by name
(`FINDINGS`), never by position. A reading of ours that no sentence supports is an extra
(`Finding.counted` False): reported, not counted in the score.
"""

from __future__ import annotations

from wpam_mj.reproduction.margins import (Check, Finding, Margin, check, check_all,  # noqa: F401
                                          checks_markdown, checks_text, residuals, score)
from wpam_mj.reproduction.sweep_findings import SWEEP_FINDINGS
from wpam_mj.reproduction.table2_findings import (OPEN_STEP_FINDINGS, TABLE2_FINDINGS,
                                                  plateau_error_limit)  # noqa: F401

# Every finding by name: code and files refer to findings this way, never by position.
FINDINGS: dict[str, Finding] = {f.name: f for f in (*TABLE2_FINDINGS, *OPEN_STEP_FINDINGS,
                                                    *SWEEP_FINDINGS)}


def sweep_checks(sw) -> list[Check]:
    """The §4.2 findings on a `wpam_mj.experiments.responses.SweepResult` (the Po cap
    from its context)."""
    return check_all(SWEEP_FINDINGS, sw)


def table2_checks(t2) -> list[Check]:
    """Table 2 and the PI staircases on a `wpam_mj.experiments.responses.Table2Result`."""
    return check_all(TABLE2_FINDINGS, t2)


def open_step_checks(run) -> list[Check]:
    """Fig. 12's open loop on the 100 N open-loop `StepRun`."""
    return check_all(OPEN_STEP_FINDINGS, run)


def all_checks(t2, open_step, sw) -> list[Check]:
    """Every finding of `wpam reproduce`, in the paper's order."""
    return [*table2_checks(t2), *open_step_checks(open_step), *sweep_checks(sw)]

