"""Cost of one W-PAM physics step against a bare mj_step on the same model.

Figures, measured side by side (interleaved repeats, best of --repeats, us per step):
  bare mj_step           build_model(params, 100 N, 1 ms), constant ctrl and tendon
                         frictionloss frozen at the end state of the feedback run (so MuJoCo
                         has the same friction constraint to solve), stepped in C with
                         mujoco.mj_step(m, d, nstep=N). The reference for the ratios.
  bare, frictionloss 0   the MJCF as shipped (no friction constraint); information.
  bare, noslip off       as the reference with noslip_iterations = 0; information (the
                         model uses 2 no-slip iterations for true stiction).
  simulate engine="c"    a whole PI feedback run through simulate(): model build, the
                         compiled loop, result assembly. Target: <= 2x the reference.
  compiled loop alone    fastloop.run_compiled on a prepared model; information.
  simulate engine="python"  the same feedback run with the reference Python loop.

Run: python benchmarks/bench_step.py [--steps N] [--python-steps N] [--repeats R]
(benchmarks/run_all.py prints the target figure with the others)
"""

from __future__ import annotations

import argparse
import time

import mujoco
import numpy as np

from common import Figure, print_table
from wpam_mj import Drive, fastloop, preset
from wpam_mj.control import make_controller, pi_feedforward
from wpam_mj.loop_contract import REC_ROWS, RunConstants
from wpam_mj.model import build_model
from wpam_mj.muscle import MuscleModel
from wpam_mj.simulate import simulate

LOAD = 100.0  # N, the paper's nominal load (§4.1)
DT = 1e-3  # s
TARGET_RATIO = 2.0  # compiled W-PAM step / bare mj_step
REFERENCE = "bare mj_step (reference)"
FULL_STEP = 'simulate engine="c"'


def feedback_drive(params, n: int) -> Drive:
    """PI run: target alternating 10 mm / 30 mm every 2 s (steps as in paper Fig. 12)."""
    t = np.arange(n) * DT
    x_ref = np.where((t // 2.0) % 2 == 0, 0.01, 0.03)
    pi = pi_feedforward(MuscleModel.from_params(params), params, x_ref, LOAD,
                        params.controller.po_feedforward)
    return Drive(pi_cmd=pi, po_cmd=np.zeros(n), x_ref=x_ref)


def time_bare(params, n: int, state: tuple[float, float, float], *, frictionloss: bool = True,
              noslip: bool = True) -> float:
    """Seconds for n bare mj_steps in C, from the frozen state (x, tension, friction)."""
    x, tension, friction = state
    model = build_model(params, LOAD, DT)
    if not noslip:
        model.opt.noslip_iterations = 0
    model.tendon_frictionloss[model.tendon("muscle").id] = friction if frictionloss else 0.0
    data = mujoco.MjData(model)
    data.joint("contraction").qpos[0] = x
    data.actuator("muscle").ctrl[0] = -tension
    start = time.perf_counter()
    mujoco.mj_step(model, data, nstep=n)
    return time.perf_counter() - start


def time_simulate(params, drive: Drive, engine: str) -> float:
    start = time.perf_counter()
    simulate(params, LOAD, drive, dt=DT, control="pi", engine=engine)
    return time.perf_counter() - start


def time_loop_alone(params, drive: Drive) -> float:
    """Seconds for fastloop.run_compiled alone (model built and result arrays outside)."""
    model = build_model(params, LOAD, DT)
    data = mujoco.MjData(model)
    k = RunConstants.make(params, DT, 0.01)
    rec = np.zeros((REC_ROWS, (len(drive.pi_cmd) - 1) // k.record_every + 1))
    muscle = MuscleModel.from_params(params)
    start = time.perf_counter()
    status = fastloop.run_compiled(model, data, muscle, make_controller("pi", params, DT), k,
                                   drive, rec)
    elapsed = time.perf_counter() - start
    assert status is None, status
    return elapsed


def measure(steps: int = 20000, python_steps: int = 4000, repeats: int = 7) -> dict[str, float]:
    """Best us/step of each figure over `repeats` interleaved repeats."""
    params = preset("wpam")
    drive = feedback_drive(params, steps)
    drive_py = feedback_drive(params, python_steps)
    # frozen end state of the feedback run for the bare steps
    end = simulate(params, LOAD, drive, dt=DT, control="pi", engine="c")
    state = (float(end.x[-1]), float(end.tension[-1]), float(end.friction[-1]))
    n, n_py = steps, python_steps
    timed = {  # name -> (steps per call, timed call)
        REFERENCE: (n, lambda: time_bare(params, n, state)),
        "bare, frictionloss 0": (n, lambda: time_bare(params, n, state, frictionloss=False)),
        "bare, noslip off": (n, lambda: time_bare(params, n, state, noslip=False)),
        FULL_STEP: (n, lambda: time_simulate(params, drive, "c")),
        "compiled loop alone": (n, lambda: time_loop_alone(params, drive)),
        'simulate engine="python"': (n_py, lambda: time_simulate(params, drive_py, "python")),
    }
    best = dict.fromkeys(timed, np.inf)
    for _ in range(repeats):
        for name, (k, run) in timed.items():
            best[name] = min(best[name], run() / k * 1e6)
    return best


def figures(**kwargs) -> list[Figure]:
    """The target figure: full W-PAM step / bare mj_step."""
    best = measure(**kwargs)
    return [Figure("W-PAM step / bare mj_step [x]", best[FULL_STEP] / best[REFERENCE], "<=",
                   TARGET_RATIO)]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=20000,
                        help="physics steps per timed bare / compiled run (default 20000 = 20 s)")
    parser.add_argument("--python-steps", type=int, default=4000,
                        help="physics steps per timed Python-loop run (default 4000 = 4 s)")
    parser.add_argument("--repeats", type=int, default=7,
                        help="interleaved repeats; the best of each figure is kept (default 7)")
    args = parser.parse_args(argv)
    if not fastloop.available():
        print(f"compiled loop unavailable: {fastloop.unavailable_reason()}")
        return 1
    best = measure(args.steps, args.python_steps, args.repeats)
    ref = best[REFERENCE]
    print(f"W-PAM step cost, load {LOAD:g} N, dt {DT * 1e3:g} ms, PI feedback, "
          f"best of {args.repeats}; ratios to the bare mj_step")
    ok = print_table([Figure(f"{name} [us/step]", us, "") for name, us in best.items()]
                     + [Figure(f"{name} [x bare]", us / ref, "<=", TARGET_RATIO)
                        if name == FULL_STEP else Figure(f"{name} [x bare]", us / ref, "")
                        for name, us in best.items() if name != REFERENCE])
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
