"""Every speed target of the project in one table: run from the repository root,

    python benchmarks/run_all.py

Figures are measured side by side in one run and, where the target is a ratio, as ratios
(this machine is shared and noisy; the machine line says how busy it was). Each figure
comes from its own script, which prints more detail: bench_step.py (per-step cost of the
plugin), bench_batch.py (runs on mujoco.batch threads), bench_vector_env.py (the batched
Gymnasium vector environment), bench_reproduce.py (reproduce wall time, memory, sweep
speed-up), bench_render.py (video), bench_search.py (the search's points per CPU-second on
the execution layer, here and on Dask, against a process pool).
"""

from __future__ import annotations

import sys

import bench_batch
import bench_render
import bench_reproduce
import bench_search
import bench_step
import bench_vector_env
from common import describe, print_table


def main() -> int:
    rows = [*bench_step.figures(), *bench_batch.figures(), *bench_vector_env.figures(),
            *bench_reproduce.figures(), *bench_render.figures(), *bench_search.figures()]
    print(describe())
    return 0 if print_table(rows) else 1


if __name__ == "__main__":
    sys.exit(main())
