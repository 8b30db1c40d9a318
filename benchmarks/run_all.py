"""Every speed target of the project in one table: run from the repository root,

    python benchmarks/run_all.py [--quick]

Figures are measured side by side in one run and, where the target is a ratio, as ratios
(this machine is shared and noisy; the machine line says how busy it was). Each figure
comes from its own script, which prints more detail: bench_step.py (per-step cost of the
plugin), bench_batch.py (runs on mujoco.batch threads), bench_vector_env.py (the batched
Gymnasium vector environment), bench_reproduce.py (reproduce wall time, memory, sweep
speed-up), bench_render.py (video), bench_search.py (the search's points per CPU-second on
the execution layer, here and on Dask, against a process pool).

--quick runs every benchmark on a few runs and steps, in seconds (the test suite does, so
that no benchmark can rot): its figures say that each still runs, not whether a target
holds, and it fails only if one does not run.
"""

from __future__ import annotations

import argparse
import sys

import bench_batch
import bench_render
import bench_reproduce
import bench_search
import bench_step
import bench_vector_env
from common import Figure, describe, print_table

BENCHMARKS = (bench_step, bench_batch, bench_vector_env, bench_reproduce, bench_render,
              bench_search)
QUICK = {bench_step: dict(n=200, n_py=50, repeats=1),
         bench_batch: dict(runs=2, duration=0.5, repeats=1),
         bench_vector_env: dict(envs=2, steps=20, repeats=1),
         bench_reproduce: dict(repeats=1, quick=True),
         bench_render: dict(quick=True), bench_search: dict(quick=True)}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true",
                        help="a few runs of each benchmark: do they all still run?")
    args = parser.parse_args(argv)
    rows = [f for bench in BENCHMARKS
            for f in bench.figures(**(QUICK[bench] if args.quick else {}))]
    if args.quick:
        print("quick: every benchmark ran; figures of a few runs, not judged")
        print_table([Figure(f.name, f.measured, "") for f in rows])
        return 0
    print(describe())
    return 0 if print_table(rows) else 1


if __name__ == "__main__":
    sys.exit(main())
