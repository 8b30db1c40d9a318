"""Environment step throughput with a 10 ms control step, against the loop called directly.

Every row advances the same physics: the hung muscle at 100 N, 1 ms physics steps, 10 per
control step, Pi from the feedforward for a 20 mm target and a constant Po command (no
policy, so only the layers differ). Figures in control steps per second of wall time
(best of --repeats, interleaved):
  direct rig steps       `wpam_mj.simulation.live.LiveRig`: commands set, then 10 physics
                         steps of the plugin (what the environments call), no environment
                         layers; the reference
  simulate               `simulate(engine="plugin")` for the same physics steps (model build
                         and result assembly included); information
  dm_control env.step    `wpam_mj.environments.dm_env_task.make_env(flat_observation=True)`
  gymnasium env.step     `wpam_mj.environments.gym_env.WPAMEnv`, bare
  gymnasium.make         the same through `gymnasium.make` (its order-enforcing and
                         passive-checker wrappers)
The ratio column is the reference's time per control step over the row's; the overhead
column is the extra time per control step [us]. Target: both env.step rows at least 0.5
(tests/test_gym_env.py holds a looser floor). On a shared machine read it beside the load
average printed with it.

Run: python benchmarks/bench_env.py [--steps N] [--repeats R]
"""

from __future__ import annotations

import argparse
import time

import gymnasium
import mujoco
import numpy as np

import wpam_mj
from wpam_mj.control.controllers import pi_feedforward
from wpam_mj.environments.dm_env_task import make_env
from wpam_mj.environments.gym_env import ENV_ID, WPAMEnv
from wpam_mj.simulation.context import RunContext
from wpam_mj.simulation.live import LiveRig
from wpam_mj.physics.muscle import MuscleModel
from wpam_mj.units import MM, MPA
from wpam_mj.simulation.simulate import Drive, simulate

LOAD = 100.0  # N, the paper's nominal load (§4.1)
DT = 1e-3  # s, physics step
SUBSTEPS = 10  # physics steps per 10 ms control step
TARGET = 20 * MM  # m
PO = 0.03 * MPA  # Pa, constant Po command
REFERENCE = "direct rig steps"


def _pi(params) -> float:
    return float(pi_feedforward(MuscleModel.from_params(params), params, [TARGET], LOAD,
                                params.controller.po_feedforward)[0])


def time_direct(params, n: int) -> float:
    rig = LiveRig.build(RunContext(params, DT, LOAD))
    data = mujoco.MjData(rig.model)
    pi = _pi(params)
    start = time.perf_counter()
    for _ in range(n):
        rig.set_commands(data, pi, PO)
        rig.step(data, SUBSTEPS)
    return time.perf_counter() - start


def time_simulate(params, n: int) -> float:
    steps = n * SUBSTEPS + 1
    drive = Drive(np.full(steps, _pi(params)), np.full(steps, PO), np.full(steps, np.nan))
    start = time.perf_counter()
    simulate(params, LOAD, drive, dt=DT, control="open", record_dt=SUBSTEPS * DT,
             engine="plugin")
    return time.perf_counter() - start


def time_dm_control(params, n: int) -> float:
    env = make_env(params, target=TARGET, load=LOAD, time_limit=n * SUBSTEPS * DT,
                   control_timestep=SUBSTEPS * DT, dt=DT, flat_observation=True)
    env.reset()
    return _time_steps(env.step, n)


def _time_gym(env, n: int) -> float:
    env.reset(seed=0)
    return _time_steps(env.step, n)


def _time_steps(step, n: int) -> float:
    """Wall time [s] of n calls of `step` with the constant Po action."""
    action = np.array([PO])
    start = time.perf_counter()
    for _ in range(n):
        step(action)
    return time.perf_counter() - start


def time_gym(params, n: int) -> float:
    return _time_gym(WPAMEnv(params, target=TARGET, load=LOAD, frame_skip=SUBSTEPS, dt=DT,
                             time_limit=n * SUBSTEPS * DT), n)


def time_gym_make(params, n: int) -> float:
    return _time_gym(gymnasium.make(ENV_ID, params=params, target=TARGET, load=LOAD,
                                    frame_skip=SUBSTEPS, dt=DT, time_limit=n * SUBSTEPS * DT),
                     n)


ROWS = {REFERENCE: time_direct, 'simulate engine="plugin"': time_simulate,
        "dm_control env.step": time_dm_control, "gymnasium env.step": time_gym,
        "gymnasium.make(...).step": time_gym_make}


def measure(n: int, repeats: int) -> dict[str, float]:
    """Best wall time [s] of each row for n control steps."""
    params = wpam_mj.preset()
    best = {name: float("inf") for name in ROWS}
    for _ in range(repeats):
        for name, run in ROWS.items():
            best[name] = min(best[name], run(params, n))
    return best


def print_rows(best: dict[str, float], n: int) -> None:
    ref = best[REFERENCE] / n
    width = max(map(len, best)) + 2
    print(f"{n} control steps of {SUBSTEPS} x {DT * 1e3:g} ms physics steps, best of runs")
    print(f"{'row':<{width}}{'steps/s':>10}{'us/step':>10}{'ratio':>8}{'overhead us':>13}")
    for name, seconds in best.items():
        per = seconds / n
        print(f"{name:<{width}}{1 / per:>10.0f}{per * 1e6:>10.1f}{ref / per:>8.2f}"
              f"{(per - ref) * 1e6:>13.1f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=2000, help="control steps per run")
    parser.add_argument("--repeats", type=int, default=3, help="interleaved repeats")
    args = parser.parse_args()
    from common import describe  # noqa: PLC0415 (benchmarks/ on sys.path when run)

    print(describe())
    print_rows(measure(args.steps, args.repeats), args.steps)


if __name__ == "__main__":
    main()
