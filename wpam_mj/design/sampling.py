"""The runs of a study: its varied inputs, sampled in a fixed order (grid, list, random,
Latin hypercube), so that a study file always means the same runs."""

from __future__ import annotations

import itertools
import math
from typing import Any

import numpy as np

from wpam_mj.design.study_spec import MAX_RUNS, StudySpec
from wpam_mj.errors import ParameterError


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
