"""The global search's points per CPU-second on the execution layer
(`wpam_mj.simulation.execution`) against the process pool the search used before it.

The points: the first of a seeded Latin hypercube over the search's coordinates
(`search.SPACE`, seed 20, as DE's first generation is drawn) that pass the quasi-static
screen; the static fits are done once, before timing (they run the same way in every
mode). Each mode then runs the simulated findings of every point at once (calibrate's
`PaperTargets` tasks at the search's dt, 39 runs a point), as `search.Evaluator._run`
does:

  * pool:   each task submitted to a `WorkerPool` of 2 processes, longest first (the
            search's dispatch before the layer), pool start included;
  * local:  the layer on this machine's 2 cores (`open_workers(2)`: the runs on two
            `mujoco.batch` threads in this process);
  * dask:   the layer on a 2-worker `distributed.LocalCluster` (1 thread each), cluster
            start and the workers' imports of wpam_mj not included (a search pays them
            once, not per generation).

CPU time is this process's and its workers' (the pool's, once joined; the Dask workers'
as they report it, their nannies not counted). The machine is shared: the load average
is printed beside every mode, and points per CPU-second is the figure to compare (wall
time mostly says how busy the neighbours were). The outcomes of every mode are checked
bit-identical.

Run: python benchmarks/bench_search.py [--points N] (default 3: about 20 CPU-s a mode)
"""

from __future__ import annotations

import argparse
import os
import resource
import time


from scipy.stats import qmc

from common import Figure
from wpam_mj.infra.pool import Cluster, WorkerPool, open_workers
from wpam_mj.experiments.protocol import SHIPPED
from wpam_mj.physics.params import preset
from wpam_mj.reproduction import search
from wpam_mj.simulation import execution
from wpam_mj.simulation import plugin
from wpam_mj.simulation.execution import result_bytes

SEED = 20


def screened_points(n: int) -> list[search.Point]:
    """The first `n` points of the seeded hypercube that the static screen passes."""
    base, points = preset("wpam"), []
    sample = qmc.LatinHypercube(d=len(search.SPACE), seed=SEED).random(8 * n)
    for u in sample:
        p = search._point_task((tuple(float(x) for x in u), base, search.GLOBAL))
        if p is not None and p.static_error <= search.TABLE2_PO_RTOL:
            points.append(p)
            if len(points) == n:
                return points
    raise SystemExit(f"only {len(points)} of {len(sample)} points pass the static screen")


def _tasks(points: list[search.Point]) -> list:
    return [t for p in points
            for t in search.Targets(search.SEARCH_DT, p.protocol).tasks(p.params)]


def _cpu_here() -> float:
    own, kids = resource.getrusage(resource.RUSAGE_SELF), \
        resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


def _run_pool(tasks: list) -> list:
    """The search's dispatch before the layer: every task on a pool of 2, longest first;
    a failed run is None."""
    with WorkerPool(2) as pool:
        futures = {k: pool.submit(_Guarded(tasks[k]).run)
                   for k in sorted(range(len(tasks)), key=lambda k: -tasks[k].cost)}
        return [futures[k].result() for k in range(len(tasks))]


class _Guarded:
    """A task whose failure (`execution.FAILURES`) is None, as `search._run` mapped it."""

    def __init__(self, task) -> None:
        self.task, self.cost = task, task.cost

    def run(self):
        try:
            return self.task.run()
        except execution.FAILURES:
            return None


def measure(n_points: int, dask: bool = True) -> list[dict]:
    points = screened_points(n_points)
    return measure_tasks(_tasks(points), len(points), dask)


def measure_tasks(tasks: list, n_points: int, dask: bool = True) -> list[dict]:
    """Each mode's wall and CPU time for `tasks` (the runs of `n_points` points)."""
    rows, outcomes = [], {}

    def timed(name: str, run, extra_cpu=lambda: 0.0) -> None:
        load0, wall0, cpu0, extra0 = os.getloadavg()[0], time.perf_counter(), _cpu_here(), \
            extra_cpu()
        outcomes[name] = run()
        wall, cpu = time.perf_counter() - wall0, _cpu_here() - cpu0 + extra_cpu() - extra0
        rows.append({"mode": name, "wall": wall, "cpu": cpu, "load": (load0,
                                                                      os.getloadavg()[0])})

    timed("pool", lambda: _run_pool(tasks))
    with open_workers(2) as workers:
        timed("local", lambda: execution.execute(tasks, workers, failed=None))
    if dask:
        import distributed  # noqa: PLC0415 (optional: the cluster extra)
        with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                      dashboard_address=None) as cluster, \
                open_workers(Cluster(cluster.scheduler_address)) as workers, \
                distributed.Client(cluster.scheduler_address) as client:
            client.run(plugin.available)  # each worker imports wpam_mj, loads the plugin

            def remote_cpu() -> float:
                return sum(t[0] + t[1] for t in client.run(os.times).values())
            timed("dask", lambda: execution.execute(tasks, workers, failed=None), remote_cpu)
    same = len({result_bytes(out) for out in outcomes.values()}) == 1
    for r in rows:
        r.update(points=n_points, runs=len(tasks), identical=same)
    return rows


def figures(n_points: int = 2, quick: bool = False) -> list[Figure]:
    """For run_all: the layer's points per CPU-second against the pool's; `quick`: the two
    shortest runs of the shipped plant, no screen, no Dask (run_all --quick: does it still run?)."""
    shipped = sorted(search.Targets(search.SEARCH_DT, SHIPPED).tasks(preset("wpam")),
                     key=lambda t: t.cost)[:2]
    rows = {r["mode"]: r for r in (measure_tasks(shipped, 1, dask=False) if quick
                                   else measure(n_points))}
    per_cpu = {m: r["points"] / r["cpu"] for m, r in rows.items()}
    dask = [] if quick else [Figure("search pts/CPU-s, layer Dask 2 / pool [x]",
                                    per_cpu["dask"] / per_cpu["pool"], "")]
    return [Figure("search pts/CPU-s, layer local / pool [x]",
                   per_cpu["local"] / per_cpu["pool"], ""), *dask,
            Figure("search outcomes identical (1 = yes)", float(rows["pool"]["identical"]),
                   ">=", 1.0)]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--points", type=int, default=3, help="points (default 3)")
    parser.add_argument("--no-dask", action="store_true", help="skip the Dask cluster")
    args = parser.parse_args(argv)
    rows = measure(args.points, dask=not args.no_dask)
    r0 = rows[0]
    print(f"{r0['points']} search points ({r0['runs']} runs, dt {search.SEARCH_DT:g} s) on "
          f"{os.cpu_count()} cores; outcomes bit-identical in every mode: "
          f"{'yes' if r0['identical'] else 'NO'}")
    pool = r0["points"] / r0["cpu"]
    print(f"{'mode':<8}{'wall s':>9}{'CPU s':>9}{'pts/CPU-s':>11}{'vs pool':>9}"
          f"{'pts/wall-s':>12}  load average (start, end)")
    for r in rows:
        per_cpu = r["points"] / r["cpu"]
        print(f"{r['mode']:<8}{r['wall']:>9.1f}{r['cpu']:>9.1f}{per_cpu:>11.4f}"
              f"{per_cpu / pool:>9.2f}{r['points'] / r['wall']:>12.4f}  "
              f"{r['load'][0]:.2f}, {r['load'][1]:.2f}")
    return 0 if r0["identical"] else 1


if __name__ == "__main__":
    raise SystemExit(main())
