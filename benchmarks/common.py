"""Shared by the benchmarks: the pass/fail table, and the state of this (shared, noisy)
machine at benchmark time, printed beside wall times.

`parallel_capacity` runs the same pure-Python loop alone and then in two processes at
once: 2.0 means both cores are ours; less means another tenant shares them, and every
wall-time figure measured meanwhile is inflated by up to 2 / capacity.
"""

from __future__ import annotations

import multiprocessing
import operator
import os
import statistics
import time
from dataclasses import dataclass

_SPIN = 2_000_000  # loop iterations: ~0.1-0.2 s of one core
_OPS = {"<=": operator.le, "<": operator.lt, ">=": operator.ge}


@dataclass(frozen=True)
class Figure:
    """One benchmark figure and its target: passed = `measured op target`."""

    name: str
    measured: float
    op: str  # "<=", "<", ">=", or "" for information only
    target: float = float("nan")

    @property
    def passed(self) -> bool | None:
        return _OPS[self.op](self.measured, self.target) if self.op else None


def print_table(figures: list[Figure]) -> bool:
    """Print figure, measured, target, result; True if every target is met."""
    width = max(len(f.name) for f in figures) + 2
    print(f"{'figure':<{width}}{'measured':>10}{'target':>10}  result")
    for f in figures:
        target = f"{f.op}{f.target:g}" if f.op else "-"
        result = {True: "pass", False: "FAIL", None: "info"}[f.passed]
        print(f"{f.name:<{width}}{f.measured:>10.2f}{target:>10}  {result}")
    return all(f.passed is not False for f in figures)


def _spin(n: int = _SPIN) -> float:
    start, total = time.perf_counter(), 0
    for i in range(n):
        total += i
    return time.perf_counter() - start


def parallel_capacity(repeats: int = 3) -> float:
    """Cores' worth of work two processes get done at once [cores], median of `repeats`
    (a single probe can read above 2 when the lone run hits a busy moment)."""
    ratios = []
    with multiprocessing.Pool(2) as pool:
        for _ in range(repeats):
            alone = _spin()
            together = max(pool.map(_spin, [_SPIN, _SPIN]))
            ratios.append(2.0 * alone / together)
    return statistics.median(ratios)


def describe() -> str:
    return (f"machine: {os.cpu_count()} cores, load average {os.getloadavg()[0]:.2f}, "
            f"parallel capacity {parallel_capacity():.2f} of 2 cores")


def plugin_missing() -> bool:
    """True (after one line saying why) when the compiled plugin a benchmark times is not
    available."""
    from wpam_mj.simulation import plugin  # noqa: PLC0415 (only the plugin benchmarks ask)

    if plugin.available():
        return False
    print(f"plugin unavailable: {plugin.unavailable_reason()}")
    return True
