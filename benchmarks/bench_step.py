"""Cost of one W-PAM physics step on the plugin against a bare mj_step of the same MJCF.

Figures, measured side by side (interleaved repeats, best of --repeats, us per step):
  bare mj_step           the rig compiled with plain motors (`model.build_model`: what the
                         Python engine runs), started in the plugin run's settled state
                         (the load held at the target), with the muscle's force and the
                         tendon's frictionloss frozen at the plugin's values there (the
                         same constraints to solve), mujoco.mj_step(m, d, nstep=N) in C.
                         The reference for the ratios.
  plugin mj_step         the rig with the wpam_mj.muscle plugin running PI feedback on the
                         held target from the same settled state, mj_step(m, d, nstep=N).
                         Target <= 1.1x.
  simulate engine="plugin"  a whole PI run through simulate(): model build, chunked
                         mujoco.batch rollout, recording. Information.
  simulate engine="python"  the same run on the Python engine (the readable definition).

  plugin instructions    with --instructions (needs valgrind): the plugin's own instructions
                         per step against the whole plugin step's, counted by callgrind
                         (repeatable on a shared machine, unlike wall time). Information.

Run: python benchmarks/bench_step.py [--steps N] [--python-steps N] [--repeats R]
     [--instructions]
(benchmarks/run_all.py prints the target figure with the others)
"""

from __future__ import annotations

import argparse
import copy
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import mujoco
import numpy as np

from common import Figure, plugin_missing, print_table
from wpam_mj import Drive, preset
from wpam_mj.simulation import plugin
from wpam_mj.control.controllers import pi_feedforward
from wpam_mj.simulation.context import RunContext
from wpam_mj.simulation.model import build_model, rig_spec
from wpam_mj.physics.muscle import MuscleModel
from wpam_mj.simulation.simulate import simulate

HERE = Path(__file__).resolve().parent
LOAD = 100.0  # N, the paper's nominal load (§4.1)
DT = 1e-3  # s
X_REF = 0.02  # m, the held target
TARGET_RATIO = 1.1  # plugin step / bare mj_step
REFERENCE = "bare mj_step (reference)"
PLUGIN = "plugin mj_step"


def _feedforward(params) -> float:
    return float(pi_feedforward(MuscleModel.from_params(params), params, np.array([X_REF]),
                                LOAD, params.controller.po_feedforward)[0])


def plugin_model(params) -> mujoco.MjModel:
    return rig_spec(RunContext(params, DT, LOAD, "pi"), start_at_rest=True).compile()


def settled(params) -> mujoco.MjData:
    """The plugin rig after 5 s of holding the target."""
    model = plugin_model(params)
    data = mujoco.MjData(model)
    data.ctrl[:] = (X_REF, _feedforward(params))
    mujoco.mj_step(model, data, nstep=5000)
    return data


def time_bare(params, n: int, state: mujoco.MjData) -> float:
    """Seconds for n bare mj_steps of the motor rig from the settled state."""
    model = build_model(params, LOAD, DT)
    muscle = plugin.state_of(state.model, state)
    model.tendon_frictionloss[model.tendon("muscle").id] = muscle["friction"]
    data = mujoco.MjData(model)
    data.qpos[:], data.qvel[:] = state.qpos, state.qvel
    data.ctrl[model.actuator("muscle_force").id] = -muscle["tension"]
    start = time.perf_counter()
    mujoco.mj_step(model, data, nstep=n)
    return time.perf_counter() - start


def time_plugin(params, n: int, state: mujoco.MjData) -> float:
    """Seconds for n mj_steps of the plugin rig under PI feedback from the settled state."""
    data = copy.copy(state)
    start = time.perf_counter()
    mujoco.mj_step(state.model, data, nstep=n)
    return time.perf_counter() - start


def time_simulate(params, n: int, engine: str) -> float:
    t = np.arange(n) * DT
    x_ref = np.where((t // 2.0) % 2 == 0, 0.01, 0.03)
    pi = pi_feedforward(MuscleModel.from_params(params), params, x_ref, LOAD,
                        params.controller.po_feedforward)
    drive = Drive(pi_cmd=pi, po_cmd=np.zeros(n), x_ref=x_ref, start_at_rest=True)
    start = time.perf_counter()
    simulate(params, LOAD, drive, dt=DT, control="pi", engine=engine)
    return time.perf_counter() - start


def measure(n: int = 20000, n_py: int = 4000, repeats: int = 7) -> dict[str, float]:
    """Best us/step of each figure over `repeats` interleaved rounds."""
    params = preset("wpam")
    state = settled(params)
    timed = {REFERENCE: (n, lambda: time_bare(params, n, state)),
             PLUGIN: (n, lambda: time_plugin(params, n, state)),
             'simulate engine="plugin"': (n, lambda: time_simulate(params, n, "plugin")),
             'simulate engine="python"': (n_py, lambda: time_simulate(params, n_py, "python"))}
    best = dict.fromkeys(timed, np.inf)
    for _ in range(repeats):
        for name, (k, run) in timed.items():
            best[name] = min(best[name], run() / k * 1e6)
    return best


def instructions_per_step(n: int = 5000) -> tuple[float, float]:
    """(the plugin's own, the whole step's) instructions per plugin step, by callgrind:
    the difference of n steps and 0 steps from the settled state, and within it the
    functions of the plugin's library."""
    counts = {}
    with tempfile.TemporaryDirectory() as tmp:
        for steps in (0, n):
            out = Path(tmp) / f"cg.{steps}"
            code = ("import copy, sys, mujoco; sys.path.insert(0, %r); import bench_step as b;"
                    "from wpam_mj import preset; s = b.settled(preset('wpam'));"
                    "mujoco.mj_step(s.model, copy.copy(s), nstep=%d)") % (str(HERE), steps)
            subprocess.run(["valgrind", "--tool=callgrind", f"--callgrind-out-file={out}",
                            sys.executable, "-c", code], check=True, capture_output=True)
            text = subprocess.run(["callgrind_annotate", str(out)], check=True,
                                  capture_output=True, text=True).stdout
            total = int(re.search(r"([\d,]+) \(100.0%\)\s+PROGRAM TOTALS", text)[1]
                        .replace(",", ""))
            own = sum(int(m[1].replace(",", "")) for m in
                      re.finditer(r"^\s*([\d,]+) \(.*wpam_muscle", text, re.M))
            counts[steps] = (own, total)
    return ((counts[n][0] - counts[0][0]) / n, (counts[n][1] - counts[0][1]) / n)


def figures(**kwargs) -> list[Figure]:
    """The target figure: plugin step / bare mj_step."""
    best = measure(**kwargs)
    return [Figure("W-PAM plugin step / bare mj_step [x]", best[PLUGIN] / best[REFERENCE],
                   "<=", TARGET_RATIO)]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=20000,
                        help="physics steps per timed C run (default 20000 = 20 s)")
    parser.add_argument("--python-steps", type=int, default=4000,
                        help="physics steps per timed Python-engine run (default 4000)")
    parser.add_argument("--repeats", type=int, default=7,
                        help="interleaved repeats; the best of each figure is kept (default 7)")
    parser.add_argument("--instructions", action="store_true",
                        help="also count the plugin's instructions per step with callgrind")
    args = parser.parse_args(argv)
    if plugin_missing():
        return 1
    best = measure(args.steps, args.python_steps, args.repeats)
    ref = best[REFERENCE]
    print(f"W-PAM step cost, load {LOAD:g} N, dt {DT * 1e3:g} ms, PI feedback, "
          f"best of {args.repeats}; ratios to the bare mj_step")
    ok = print_table([Figure(f"{name} [us/step]", us, "") for name, us in best.items()]
                     + [Figure(f"{name} [x bare]", us / ref, "<=", TARGET_RATIO)
                        if name == PLUGIN else Figure(f"{name} [x bare]", us / ref, "")
                        for name, us in best.items() if name != REFERENCE])
    if args.instructions:
        own, total = instructions_per_step()
        print(f"callgrind: the plugin's functions {own:.0f} of {total:.0f} instructions per "
              f"plugin step ({own / total:.1%})")
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
