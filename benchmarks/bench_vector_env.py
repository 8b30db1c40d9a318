"""The vector environment's throughput: the batched engine on 1 and 2 mujoco.batch threads
against the serial one, 16 environments of wpam_mj/WPAMTrack-v0.

Each row steps N environments with zero actions (no policy, so only the engines differ)
for --steps vector steps after a reset, autoresets included when an episode ends, and
counts environment steps per second of wall time (best of --repeats, rows interleaved).
The batched engine's results are checked equal, bit for bit, to the serial engine's
over the same steps (tests/test_vector_env.py checks this against SyncVectorEnv too).
Targets: >= 20,000 environment steps/s with 16 environments on two cores, two
batch threads >= 1.8x one. On a shared machine read them beside the load average and the
parallel capacity printed with them: with another tenant on the cores, threads cannot
scale.

Run: python benchmarks/bench_vector_env.py [--envs 16] [--steps 2000] [--repeats 3]
"""

from __future__ import annotations

import argparse
import sys
import time

import gymnasium
import numpy as np

import wpam_mj  # noqa: F401 (registers the ids)
from common import Figure, describe, plugin_missing, print_table

ENV_ID = "wpam_mj/WPAMTrack-v0"
TARGET_RATE = 20_000  # environment steps/s, 16 envs, two cores
TARGET_SPEEDUP = 1.8  # two batch threads over one


def run(engine: str, nthread: int, envs: int, steps: int) -> tuple[float, list]:
    """(environment steps per second, the observations and rewards of every step)."""
    venv = gymnasium.make_vec(ENV_ID, num_envs=envs, engine=engine, nthread=nthread)
    venv.reset(seed=0)
    action = np.zeros((envs, 1), np.float32)
    out = []
    start = time.perf_counter()
    for _ in range(steps):
        obs, rewards, *_ = venv.step(action)
        out.append((obs, rewards))
    rate = envs * steps / (time.perf_counter() - start)
    venv.close()
    return rate, out


def measure(envs: int, steps: int, repeats: int) -> tuple[dict[str, float], bool]:
    """Best rate per row, and whether batch and serial gave the same results."""
    rows = {"serial": ("serial", 1), "batch, 1 thread": ("batch", 1),
            "batch, 2 threads": ("batch", 2)}
    best = dict.fromkeys(rows, 0.0)
    results = {}
    for _ in range(repeats):
        for name, (engine, nthread) in rows.items():
            rate, results[name] = run(engine, nthread, envs, steps)
            best[name] = max(best[name], rate)
    same = all(np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])
               for name in ("batch, 1 thread", "batch, 2 threads")
               for a, b in zip(results[name], results["serial"]))
    return best, same


def _targets(best: dict[str, float], same: bool, label: str) -> list[Figure]:
    """The three targets: 2-thread rate, 2-thread speed-up, batched = serial."""
    two, one = best["batch, 2 threads"], best["batch, 1 thread"]
    return [Figure(f"{label}2 threads [env steps/s]", two, ">=", TARGET_RATE),
            Figure(f"{label}2 threads / 1 [x]", two / one, ">=", TARGET_SPEEDUP),
            Figure(f"{label}batched = serial, bit for bit (1 = yes)", float(same), ">=",
                   1.0)]


def figures(envs: int = 16, steps: int = 1000, repeats: int = 2) -> list[Figure]:
    """The target figures for run_all."""
    best, same = measure(envs, steps, repeats)
    return _targets(best, same, f"vector env, {envs} envs, ")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--envs", type=int, default=16, help="environments (default 16)")
    parser.add_argument("--steps", type=int, default=2000, help="vector steps per row")
    parser.add_argument("--repeats", type=int, default=3, help="best of (default 3)")
    args = parser.parse_args(argv)
    if plugin_missing():
        return 1
    best, same = measure(args.envs, args.steps, args.repeats)
    print(f"{args.envs} environments of {ENV_ID}, {args.steps} vector steps, best of "
          f"{args.repeats}; {describe()}")
    ok = print_table([
        *(Figure(f"{name} [env steps/s]", rate, "") for name, rate in best.items()),
        *_targets(best, same, f"vector env, {args.envs} envs, "),
        Figure("batch, 2 threads / serial [x]", best["batch, 2 threads"] / best["serial"], "")])
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
