"""Whole-reproduction figures: wall time, parallel speed-up, peak memory.

Figures (measured in one run, side by side; this machine is shared, so the ratio is the
robust figure and absolute times vary):
  reproduce wall time   `wpam reproduce` (no video) in a fresh process, default --jobs.
                        Target <= 10 s on 2 cores.
  peak memory           the largest total resident memory of that process and its pool
                        workers, sampled every 20 ms from /proc. Target < 500 MB.
  sweep speed-up        the paper's 30-run sweep with jobs=1 against jobs=2, timed
                        alternately, best of --repeats. Target >= 1.7x. Printed beside
                        it: the machine's parallel capacity at the time (common.py), the
                        ceiling of any speed-up while other tenants share the cores.

Run: python benchmarks/bench_reproduce.py [--repeats R] [--out DIR]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from common import Figure, describe, parallel_capacity, print_table
from wpam_mj.physics.params import preset
from wpam_mj.experiments.paper_studies import sweep

def _tree_rss_mb(pid: int) -> float:
    """Resident memory of `pid` and all its descendants [MB] (Linux /proc; cheap enough
    to sample often without slowing what it measures)."""
    total, stack = 0, [pid]
    while stack:
        p = stack.pop()
        try:
            with open(f"/proc/{p}/statm") as fh:
                total += int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
            for task in os.listdir(f"/proc/{p}/task"):
                with open(f"/proc/{p}/task/{task}/children") as fh:
                    stack.extend(int(c) for c in fh.read().split())
        except OSError:
            continue  # the process ended between two reads
    return total / 2**20


def time_reproduce(out: Path) -> tuple[float, float]:
    """Wall time [s] and peak tree memory [MB] of `wpam reproduce --out out`."""
    cmd = [sys.executable, "-m", "wpam_mj.cli", "reproduce", "--out", str(out), "--no-progress"]
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL)
    peak = 0.0
    while proc.poll() is None:
        peak = max(peak, _tree_rss_mb(proc.pid))
        time.sleep(0.02)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        raise SystemExit(f"wpam reproduce failed with exit code {proc.returncode}")
    return wall, peak


def time_sweep(jobs: int, **kwargs) -> float:
    """Wall time [s] of the paper's sweep (or `paper_studies.sweep(**kwargs)`'s)."""
    params = preset("wpam")
    t0 = time.perf_counter()
    sweep(params, keep=(), jobs=jobs, **kwargs)
    return time.perf_counter() - t0


QUICK_SWEEP = dict(loads=(100.0,), freqs=(2.0,), controllers=("pi", "pid"))  # run_all --quick


def figures(repeats: int = 3, out: Path | None = None, quick: bool = False) -> list[Figure]:
    """Reproduce wall time and peak memory (best of `repeats`), and the sweep speed-up;
    `quick`: a two-run sweep only (run_all --quick: does it still run?)."""
    rows = []
    if not quick:
        with tempfile.TemporaryDirectory() as tmp:
            wall, peak = min(time_reproduce(out or Path(tmp) / "reproduce")
                             for _ in range(repeats))
        rows = [Figure("reproduce wall time [s]", wall, "<=", 10.0),
                Figure("reproduce peak memory [MB]", peak, "<", 500.0)]
    serial = parallel = float("inf")
    capacity = 0.0
    for _ in range(repeats):  # alternately, so that a busy spell hits both
        serial = min(serial, time_sweep(1, **(QUICK_SWEEP if quick else {})))
        parallel = min(parallel, time_sweep(2, **(QUICK_SWEEP if quick else {})))
        capacity = max(capacity, parallel_capacity(1))
    return [*rows,
            Figure("sweep, 1 job [s]", serial, ""),
            Figure("sweep, 2 jobs [s]", parallel, ""),
            Figure("sweep speed-up, 2 jobs vs 1 [x]", serial / parallel, ">=", 1.7),
            # what two processes of plain Python got done meanwhile: the ceiling
            Figure("machine parallel capacity then [cores]", capacity, "")]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=3, help="timing repeats (best of)")
    parser.add_argument("--out", type=Path, default=None,
                        help="folder for the reproduction (default: a temporary folder)")
    args = parser.parse_args(argv)
    rows = figures(args.repeats, args.out)
    print(describe())
    return 0 if print_table(rows) else 1


if __name__ == "__main__":
    sys.exit(main())
