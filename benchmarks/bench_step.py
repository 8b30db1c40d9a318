"""Cost of one W-PAM physics step on the plugin against a bare mj_step of the same MJCF.

Figures, measured side by side (interleaved repeats, best of --repeats, us per step):
  bare mj_step           the rig compiled with plain motors (`model.build_model`: what the
                         Python engine runs), constant ctrl, the tendon's frictionloss set
                         to the plugin's level at the end of the feedback run (the same
                         friction constraint to solve), mujoco.mj_step(m, d, nstep=N) in C.
                         The reference for the ratios.
  plugin mj_step         the rig with the wpam_mj.muscle plugin running PI feedback on a
                         held target, mujoco.mj_step(m, d, nstep=N). Target <= 1.1x.
  simulate engine="plugin"  a whole PI run through simulate(): model build, chunked
                         mujoco.batch rollout, recording. Information.
  simulate engine="python"  the same run on the Python engine (the readable definition).

Run: python benchmarks/bench_step.py [--steps N] [--python-steps N] [--repeats R]
(benchmarks/run_all.py prints the target figure with the others)
"""

from __future__ import annotations

import argparse
import time

import mujoco
import numpy as np

from common import Figure, print_table
from wpam_mj import Drive, plugin, preset
from wpam_mj.control import pi_feedforward
from wpam_mj.model import build_model, rig_spec
from wpam_mj.muscle import MuscleModel
from wpam_mj.simulate import simulate

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
    return rig_spec(params, LOAD, DT, control="pi", start_at_rest=True).compile()


def settled_friction(params) -> float:
    """The plugin's friction level [N] after 2 s of holding the target."""
    model = plugin_model(params)
    data = mujoco.MjData(model)
    data.ctrl[:] = (X_REF, _feedforward(params))
    mujoco.mj_step(model, data, nstep=2000)
    return float(data.plugin_state[plugin.STATE_FIELDS.index("friction")])


def time_bare(params, n: int, friction: float) -> float:
    """Seconds for n bare mj_steps of the motor rig."""
    model = build_model(params, LOAD, DT)
    model.tendon_frictionloss[model.tendon("muscle").id] = friction
    data = mujoco.MjData(model)
    data.ctrl[model.actuator("muscle_force").id] = -LOAD
    start = time.perf_counter()
    mujoco.mj_step(model, data, nstep=n)
    return time.perf_counter() - start


def time_plugin(params, n: int) -> float:
    """Seconds for n mj_steps of the plugin rig under PI feedback."""
    model = plugin_model(params)
    data = mujoco.MjData(model)
    data.ctrl[:] = (X_REF, _feedforward(params))
    start = time.perf_counter()
    mujoco.mj_step(model, data, nstep=n)
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
    friction = settled_friction(params)
    timed = {REFERENCE: (n, lambda: time_bare(params, n, friction)),
             PLUGIN: (n, lambda: time_plugin(params, n)),
             'simulate engine="plugin"': (n, lambda: time_simulate(params, n, "plugin")),
             'simulate engine="python"': (n_py, lambda: time_simulate(params, n_py, "python"))}
    best = dict.fromkeys(timed, np.inf)
    for _ in range(repeats):
        for name, (k, run) in timed.items():
            best[name] = min(best[name], run() / k * 1e6)
    return best


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
    args = parser.parse_args(argv)
    if not plugin.available():
        print(f"plugin unavailable: {plugin.unavailable_reason()}")
        return 1
    best = measure(args.steps, args.python_steps, args.repeats)
    ref = best[REFERENCE]
    print(f"W-PAM step cost, load {LOAD:g} N, dt {DT * 1e3:g} ms, PI feedback, "
          f"best of {args.repeats}; ratios to the bare mj_step")
    ok = print_table([Figure(f"{name} [us/step]", us, "") for name, us in best.items()]
                     + [Figure(f"{name} [x bare]", us / ref, "<=", TARGET_RATIO)
                        if name == PLUGIN else Figure(f"{name} [x bare]", us / ref, "")
                        for name, us in best.items() if name != REFERENCE])
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
