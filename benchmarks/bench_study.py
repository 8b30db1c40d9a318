"""Throughput of `wpam study` against the engine's floor, and its memory against run count.

The study: seeded random staircase runs (PI, load 50-150 N, friction coefficient 0.010-
0.015), --runs of --duration s each (default 1,000 runs of 100 s: 1e8 physics steps).
Figures (runs per second of wall time, each from a clean output folder):
  floor2   the engine alone on both cores: two forked processes, each calling
           `experiments.step_run` (drive + `simulate`) directly for its half of the same
           runs; no batching, metrics, part files or table.
  jobs1    `run_study` in this process;  jobs2: on a local process pool of 2 (pool start
           included);  dask2: on a Dask LocalCluster of 2 single-threaded worker processes
           (cluster start excluded: a study connects to a running cluster).
  overhead per run: CPU time (this process and its reaped children, i.e. the floor's
  processes or the pool's workers) of jobs1 / jobs2 minus the floor's, per run [ms];
  CPU time is much less disturbed by other tenants than wall time.
  Targets: jobs2 >= 80 % and dask2 >= 70 % of floor2.
With --repeats R every figure is the best of R interleaved repeats (on a shared machine).
Peak RSS: `python -m wpam_mj study --jobs 2` of 100 and of 1,000 short runs (--rss-duration
s each), largest process of the tree (wait4), to show that memory does not grow with runs.

Run: python benchmarks/bench_study.py [--runs N] [--duration S] [--repeats R]
[--rss-duration S]   (quick check on a busy machine: --runs 100 --duration 33 --repeats 3)
"""

from __future__ import annotations

import argparse
import multiprocessing
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from common import Figure, describe, print_table
from wpam_mj.design import sampling, study, study_spec
from wpam_mj.infra.pool import open_workers
from wpam_mj.experiments.drives import STEP_LEVELS_MM, step_run
from wpam_mj.physics.params import preset

REPO = Path(__file__).resolve().parent.parent
JOBS2_TARGET = 0.8  # fraction of the floor's runs/s (the target)
DASK2_TARGET = 0.7


def spec_dict(runs: int, duration: float) -> dict:
    return {"experiment": "step", "fixed": {"duration": duration, "controller": "pi"},
            "vary": {"method": "random", "n": runs, "seed": 2024,
                     "ranges": {"load": [50.0, 150.0],
                                "muscle.friction_coeff": [0.010, 0.015]}}}


def spec_toml(runs: int, duration: float) -> str:
    return (f'experiment = "step"\n[fixed]\nduration = {duration!r}\ncontroller = "pi"\n'
            f'[vary]\nmethod = "random"\nn = {runs}\nseed = 2024\n[vary.ranges]\n'
            'load = [50.0, 150.0]\n"muscle.friction_coeff" = [0.010, 0.015]\n')


def _floor_share(runs: list[dict], duration: float) -> None:
    base = preset("wpam")
    hold = duration / len(STEP_LEVELS_MM)
    for r in runs:
        params = base.replace(muscle={"friction_coeff": r["muscle.friction_coeff"]})
        step_run(params, r["load"], "pi", hold=hold)


def _cpu() -> float:
    """CPU seconds of this process and of its children reaped so far."""
    return sum(r.ru_utime + r.ru_stime for r in (resource.getrusage(resource.RUSAGE_SELF),
                                                resource.getrusage(resource.RUSAGE_CHILDREN)))


def time_floor(spec: study_spec.StudySpec, duration: float) -> tuple[float, float]:
    """(wall, CPU) seconds of two forked processes simulating half of the runs each."""
    runs = sampling.sample(spec)
    ctx = multiprocessing.get_context("fork")
    cpu, start = _cpu(), time.perf_counter()
    procs = [ctx.Process(target=_floor_share, args=(runs[i::2], duration)) for i in (0, 1)]
    for p in procs:
        p.start()
    for p in procs:
        p.join()
    return time.perf_counter() - start, _cpu() - cpu


def time_study(spec: study_spec.StudySpec, jobs: int) -> tuple[float, float]:
    """(wall, CPU) seconds of `run_study` on `jobs` local processes, pool start and
    shutdown included."""
    with tempfile.TemporaryDirectory() as out:
        cpu, start = _cpu(), time.perf_counter()
        with open_workers(jobs) as workers:
            study.run_study(spec, out, workers)
        return time.perf_counter() - start, _cpu() - cpu


def time_dask(spec: study_spec.StudySpec, cluster) -> float:
    """Wall seconds of `run_study` on a running Dask cluster (connection included)."""
    with tempfile.TemporaryDirectory() as out:
        start = time.perf_counter()
        with open_workers(1, cluster.scheduler_address) as workers:
            study.run_study(spec, out, workers)
        return time.perf_counter() - start


def peak_rss_mb(runs: int, duration: float) -> float:
    """Peak RSS [MB] of the largest process of a `wpam study --jobs 2` run."""
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "bench.toml"
        path.write_text(spec_toml(runs, duration))
        env = {**os.environ, "PYTHONPATH": str(REPO)}
        proc = subprocess.Popen([sys.executable, "-m", "wpam_mj", "study", str(path),
                                 "--out", str(Path(tmp) / "out"), "--jobs", "2",
                                 "--no-progress"], env=env, stdout=subprocess.DEVNULL)
        _, status, usage = os.wait4(proc.pid, 0)
        if status != 0:
            raise RuntimeError(f"wpam study exited with status {status}")
        return usage.ru_maxrss / 1024.0  # KiB on Linux


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--runs", type=int, default=1000, help="runs in the study (default 1000)")
    ap.add_argument("--duration", type=float, default=100.0,
                    help="simulated seconds per step run (default 100)")
    ap.add_argument("--repeats", type=int, default=1,
                    help="interleaved repeats; each figure is the best (default 1)")
    ap.add_argument("--rss-duration", type=float, default=33.0,
                    help="simulated seconds per run of the RSS studies (default 33, the "
                         "shortest a step study takes)")
    args = ap.parse_args()
    spec = study_spec.parse_spec(spec_dict(args.runs, args.duration))
    print(describe())
    print(f"study: {args.runs} random PI step runs of {args.duration:g} s "
          f"({args.runs * args.duration / 1e-3:.3g} physics steps at 1 ms)")
    from distributed import LocalCluster  # noqa: PLC0415 (optional dependency)
    walls: dict[str, list[float]] = {}
    cpus: dict[str, list[float]] = {}
    for _ in range(args.repeats):
        # the local runs fork: they go before the cluster's threads exist, and the cluster
        # closes before the next repeat
        for name, (wall, cpu) in (("floor2", time_floor(spec, args.duration)),
                                  ("jobs1", time_study(spec, 1)),
                                  ("jobs2", time_study(spec, 2))):
            walls.setdefault(name, []).append(wall)
            cpus.setdefault(name, []).append(cpu)
        with LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                          dashboard_address=None) as cluster:
            walls.setdefault("dask2", []).append(time_dask(spec, cluster))
    rate = {k: args.runs / min(v) for k, v in walls.items()}
    overhead = {k: (min(cpus[k]) - min(cpus["floor2"])) / args.runs * 1e3
                for k in ("jobs1", "jobs2")}
    rss = {n: peak_rss_mb(n, args.rss_duration) for n in (100, 1000)}
    ok = print_table([
        Figure("floor2 [runs/s]", rate["floor2"], ""),
        Figure("jobs1 [runs/s]", rate["jobs1"], ""),
        Figure("jobs2 [runs/s]", rate["jobs2"], ""),
        Figure("dask2 [runs/s]", rate["dask2"], ""),
        Figure("jobs2 / floor2", rate["jobs2"] / rate["floor2"], ">=", JOBS2_TARGET),
        Figure("dask2 / floor2", rate["dask2"] / rate["floor2"], ">=", DASK2_TARGET),
        Figure("CPU overhead per run, jobs1 [ms]", overhead["jobs1"], ""),
        Figure("CPU overhead per run, jobs2 [ms]", overhead["jobs2"], ""),
        Figure("peak RSS, 100 runs [MB]", rss[100], ""),
        Figure("peak RSS, 1000 runs [MB]", rss[1000], ""),
    ])
    print("runs/s " + " ".join(f"{k}={rate[k]:.3g}" for k in ("jobs1", "jobs2", "dask2",
                                                              "floor2")))
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
