"""The MuJoCo Warp backend's throughput against the number of worlds and the device, beside
the CPU vector environment in the same run (needs the gpu extra: pip install ".[gpu]").

Rows, for each device and number of worlds N:
  physics   N worlds of the rig (`warp_backend.WarpBatch`: the shipped W-PAM at 100 N, the
            paper's PI in the muscle holding 25 mm) stepped `--nsub` physics steps per
            call (on CUDA one captured graph): physics steps/s counts every world's step,
            and "env steps/s (physics)" is that over the 10 physics steps of an env step,
            what the physics alone would allow an environment.
  env       `gymnasium.make_vec(ENV_ID, num_envs=N, backend="warp", device=...)` with zero
            actions (up to --env-max worlds: each environment is a Python `WPAMEnv`, built
            and reset on the host).
  cpu env   the default backend (`mujoco.batch` on every CPU this process may use), same N.
Each rate is the best of --repeats timed runs of at least --seconds after a warm-up step.
The first use of a device compiles Warp's kernels (about a minute on CPU; cached after).

Run: python benchmarks/bench_warp.py [--devices cpu,cuda] [--worlds 1,16,256,4096,65536]
     [--env-max 1024] [--seconds 2] [--repeats 2] [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
import traceback

import gymnasium
import numpy as np

import wpam_mj  # noqa: F401 (registers the ids)
from wpam_mj.environments.vector_env import default_threads
from wpam_mj.physics.params import preset
from wpam_mj.errors import ParameterError
from wpam_mj.simulation import warp_muscle
from wpam_mj.simulation.context import RunContext
from wpam_mj.simulation.model import rig_spec

ENV_ID = "wpam_mj/WPAMTrack-v0"
FRAME_SKIP = 10  # physics steps per env step of the registered ids
TARGET_ENV_RATE = 1_000_000  # env steps/s on one H100-class GPU (issue 38)


def timed(step, steps_per_call: int, seconds: float, repeats: int) -> float:
    """Best steps/s of `step()` (each call `steps_per_call` steps) over `repeats` runs of at
    least `seconds`, after one warm-up call."""
    step()
    best = 0.0
    for _ in range(repeats):
        calls, start = 0, time.perf_counter()
        while True:
            step()
            calls += 1
            elapsed = time.perf_counter() - start
            if elapsed >= seconds:
                break
        best = max(best, calls * steps_per_call / elapsed)
    return best


def physics_rate(device: str, worlds: int, nsub: int, seconds: float, repeats: int) -> float:
    """Physics steps/s of `worlds` rig worlds on `device` (every world's step counted)."""
    from wpam_mj.simulation.warp_backend import WarpBatch  # noqa: PLC0415 (the extra)

    wp, _ = warp_muscle.require_warp()
    spec = rig_spec(RunContext(preset("wpam"), 1e-3, 100.0, "pi"))
    batch = WarpBatch([spec] * worlds, device)
    batch.reset()
    # channels (x_ref, pi_cmd): hold 25 mm with Pi at 0.3 MPa, Po from the muscle's PI
    batch.set_ctrl(np.tile([0.025, 0.3e6], (worlds, 1)))

    def step() -> None:
        batch.step(nsub)
        wp.synchronize_device(device)

    return worlds * timed(step, nsub, seconds, repeats)


def env_rate(worlds: int, seconds: float, repeats: int, **backend) -> float:
    """Environment steps/s of the vector environment with zero actions."""
    venv = gymnasium.make_vec(ENV_ID, num_envs=worlds, **backend)
    venv.reset(seed=0)
    action = np.zeros((worlds, 1), np.float32)
    rate = worlds * timed(lambda: venv.step(action), 1, seconds, repeats)
    venv.close()
    return rate


def attempt(measure, *args, **kwargs) -> float | None:
    """A measurement, or None with its traceback on stderr: one failed row leaves the
    others (a run on a rented GPU should bring back what it can)."""
    try:
        return measure(*args, **kwargs)
    except Exception:  # noqa: BLE001 (reported, then the next row)
        traceback.print_exc()
        return None


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--devices", default=None,
                        help="comma-separated Warp devices (default: cuda if there is one, "
                             "else cpu)")
    parser.add_argument("--worlds", default=None,
                        help="comma-separated world counts (default 1,16,256,4096,65536 on "
                             "cuda, 1,4,16 on cpu)")
    parser.add_argument("--env-max", type=int, default=1024,
                        help="largest N for the env rows (default 1024)")
    parser.add_argument("--nsub", type=int, default=FRAME_SKIP,
                        help="physics steps per physics-row call (default 10)")
    parser.add_argument("--seconds", type=float, default=2.0)
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--json", default=None, help="also write the rows to this file")
    args = parser.parse_args(argv)
    try:
        wp, _ = warp_muscle.require_warp()
    except ParameterError as err:
        print(f"bench_warp: {err}", file=sys.stderr)
        return 2
    devices = args.devices.split(",") if args.devices else \
        ["cuda" if wp.is_cuda_available() else "cpu"]
    rows = []
    name = {d: (wp.get_device(d).name if d.startswith("cuda") else "CPU") for d in devices}
    print(f"bench_warp: {os.cpu_count()} CPUs, {default_threads(1 << 20)} batch threads; "
          + "; ".join(f"{d}: {name[d]}" for d in devices), flush=True)
    for device in devices:
        counts = [int(n) for n in (args.worlds or ("1,16,256,4096,65536"
                  if device.startswith("cuda") else "1,4,16")).split(",")]
        for n in counts:
            start = time.perf_counter()
            physics = attempt(physics_rate, device, n, args.nsub, args.seconds, args.repeats)
            env = cpu = None
            if n <= args.env_max:
                env = attempt(env_rate, n, args.seconds, args.repeats, backend="warp",
                              device=device)
                cpu = attempt(env_rate, n, args.seconds, args.repeats)
            rows.append({"device": device, "device_name": name[device], "worlds": n,
                         "physics_steps_per_s": physics,
                         "env_steps_per_s_physics": physics and physics / FRAME_SKIP,
                         "env_steps_per_s": env, "cpu_vector_env_steps_per_s": cpu,
                         "wall_s": time.perf_counter() - start})
            print(f"  {device} {n} worlds: done in {rows[-1]['wall_s']:.0f} s", flush=True)
    print()
    print("| device | worlds | physics steps/s | env steps/s (physics) | env steps/s "
          "(warp vector env) | env steps/s (CPU vector env) |")
    print("|---|---|---|---|---|---|")
    for r in rows:
        def f(v):
            return "-" if v is None else f"{v:,.0f}"
        print(f"| {r['device']} ({r['device_name']}) | {r['worlds']:,} | "
              f"{f(r['physics_steps_per_s'])} | {f(r['env_steps_per_s_physics'])} | "
              f"{f(r['env_steps_per_s'])} | {f(r['cpu_vector_env_steps_per_s'])} |")
    best = max(r["env_steps_per_s_physics"] or 0.0 for r in rows)
    print(f"\nbest env steps/s the physics allows: {best:,.0f} (target on one H100-class "
          f"GPU: {TARGET_ENV_RATE:,})")
    if args.json:
        with open(args.json, "w") as out:
            json.dump(rows, out, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
