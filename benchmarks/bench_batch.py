"""Many short runs through `mujoco.batch` (`wpam_mj.execute` on 1 and 2 cores): threads.

100 PI runs of 20 s (a 0 -> 10 -> 20 mm staircase, loads spread over 50-150 N), each on
its own model, stepped by one batch on 1 and on 2 threads (best of --repeats). Figures:
runs/s on each, the speed-up (target >= 1.8x on 2 threads; it needs two idle cores, so
`parallel_capacity` is printed beside it), whether the records are bit-identical, and,
for comparison, the same runs through `simulate` on a process pool of 2 (pool start
included), the way every many-run job ran before the execution layer (docs/cluster.md).

Run: python benchmarks/bench_batch.py [--runs N] [--duration S] [--repeats R]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from common import Figure, parallel_capacity, plugin_missing, print_table
from wpam_mj.infra.pool import WorkerPool
from wpam_mj import execute, preset
from wpam_mj.experiments.drives import drive_for_targets, step_targets
from wpam_mj.simulation.context import RunContext
from wpam_mj.simulation.simulate import Run, simulate

DT = 1e-3  # s
TARGET_SPEEDUP = 1.8  # 2 threads / 1 thread


def _drive(load: float, duration: float):
    t = np.arange(round(duration / DT)) * DT
    x_ref = step_targets(t, (0, 10, 20), hold=duration / 3) * 1e-3
    return drive_for_targets(preset("wpam"), load, x_ref, "pi", DT)


def make_runs(n: int, duration: float) -> list[Run]:
    return [Run.make(RunContext(preset("wpam"), DT, load, "pi"), _drive(load, duration))
            for load in np.linspace(50.0, 150.0, n)]


def _one(load: float, duration: float) -> float:
    return float(simulate(preset("wpam"), load, _drive(load, duration), dt=DT,
                          control="pi").x[-1])


def time_pool(n: int, duration: float) -> float:
    start = time.perf_counter()
    with WorkerPool(2) as pool:
        list(pool.map(_one, np.linspace(50.0, 150.0, n), [duration] * n))
    return time.perf_counter() - start


def measure(runs: list[Run], repeats: int, *, pool: bool = True) -> tuple[dict, bool]:
    """Best wall time [s] of `runs` on 1 and 2 batch threads (and a pool of 2), and
    whether the records of 1 and 2 threads are bit-identical."""
    best, results = {1: np.inf, 2: np.inf, "pool": np.inf}, {}
    for _ in range(repeats):
        for nthread in (1, 2):
            start = time.perf_counter()
            results[nthread] = execute(runs, nthread)
            best[nthread] = min(best[nthread], time.perf_counter() - start)
        if pool:
            best["pool"] = min(best["pool"], time_pool(len(runs), _duration(runs[0])))
    same = all(np.array_equal(a.x, b.x) and np.array_equal(a.po, b.po)
               for a, b in zip(results[1], results[2]))
    return best, same


def _duration(run: Run) -> float:
    return len(run.inputs) * run.context.dt


def figures(runs: int = 40, duration: float = 20.0, repeats: int = 2) -> list[Figure]:
    """The target figures for run_all: 2-thread speed-up, identical records."""
    best, same = measure(make_runs(runs, duration), repeats, pool=False)
    return [Figure("batch, 2 threads / 1 [x]", best[1] / best[2], ">=", TARGET_SPEEDUP),
            Figure("batch records identical (1 = yes)", float(same), ">=", 1.0)]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=100, help="runs per batch (default 100)")
    parser.add_argument("--duration", type=float, default=20.0, help="seconds per run")
    parser.add_argument("--repeats", type=int, default=3, help="best of (default 3)")
    args = parser.parse_args(argv)
    if plugin_missing():
        return 1
    best, same = measure(make_runs(args.runs, args.duration), args.repeats)
    print(f"{args.runs} PI runs of {args.duration:g} s, dt {DT * 1e3:g} ms, best of "
          f"{args.repeats}; parallel capacity of this machine now: {parallel_capacity():.2f}"
          " cores")
    ok = print_table([Figure("1 thread [runs/s]", args.runs / best[1], ""),
                      Figure("2 threads [runs/s]", args.runs / best[2], ""),
                      Figure("speed-up, 2 threads [x]", best[1] / best[2], ">=",
                             TARGET_SPEEDUP),
                      Figure("records identical (1 = yes)", float(same), ">=", 1.0),
                      Figure("process pool of 2, simulate [runs/s]", args.runs / best["pool"],
                             ""),
                      Figure("2 threads / process pool of 2 [x]", best["pool"] / best[2],
                             "")])
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
