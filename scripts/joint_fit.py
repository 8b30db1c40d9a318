"""The joint fit behind the shipped parameters: random search, then Nelder-Mead.

Every fitted parameter moves inside its plausible range (`wpam_mj.physics.params`), the three
readings of the paper's gains (`controller.command_scale` 1, 0.1, 0.05) are drawn as a
category, and one cost adds (docs/physics.md): the squared log errors of Table 2's
"Po = 0.04" row; the PI step runs' settled plateau error beyond 0.45 mm and peak-to-peak
beyond 0.18 mm (last 5 s of each plateau); the feedback row above 0.018, out of order or
with 150 N below 3x 100 N; Po missing its cap at 150 N 0.5 Hz, reaching 0.068 MPa at 50 N
0.1 Hz, or a plateau-mean Po falling with load.

    python scripts/joint_fit.py [--seed 7] [--samples 150] [--nm-from 2] [--nm-evals 160]

With these defaults (about 40 minutes on the shared two cores) it wrote the values in
docs/calibration_start.toml, where the shipped calibration starts (with the
contracting-branch feedforward reading; docs/physics.md, Calibration), before the step
and sine runs started at rest: rerun today it searches a slightly different cost and need
not land on those values. It prints the best
cost and writes calibrated-joint.toml in the current folder. Its cost predates
`wpam_mj.reproduction.calibrate.PaperTargets`, which adds the PID steps and the whole sweep.
"""

from __future__ import annotations

import argparse
import math

import numpy as np
from scipy.optimize import minimize

from wpam_mj import paper, preset
from wpam_mj.physics.params import Params, plausible_range
from wpam_mj.units import MM, MPA
from wpam_mj.infra.files import write_text_atomic
from wpam_mj.infra.pool import Workers, open_workers
from wpam_mj.experiments.paper_studies import SineTask, StaticTask, StepTask
from wpam_mj.simulation.execution import execute

FREE = ("braid.braid_angle", "muscle.output_coeff", "muscle.friction_coeff",
        "muscle.friction_const", "muscle.axial_area", "pneumatics.outer_conductance",
        "pneumatics.inner_conductance", "controller.po_feedforward",
        "controller.feedforward_friction")
LOG = {"pneumatics.outer_conductance", "pneumatics.inner_conductance"}
READINGS = (1.0, 0.1, 0.05)
DT = 1e-3  # s


def params_at(u: np.ndarray, reading: float) -> Params:
    """Parameters at unit coordinates u (one per FREE name, log for conductances)."""
    values = {"controller.command_scale": reading}
    for name, ui in zip(FREE, np.clip(u, 0.0, 1.0)):
        lo, hi = plausible_range(name)
        values[name] = math.exp(math.log(lo) + ui * math.log(hi / lo)) if name in LOG \
            else lo + ui * (hi - lo)
    return preset("wpam").with_values(values)


SETTLE_S = 5.0  # the last 5 s of each 10 s plateau


def cost(params: Params, workers: Workers) -> float:
    """The joint cost of `params` from its runs: each PI staircase's settled errors and
    plateau means, each static loop's area, each sine's highest regulator Po."""
    loads = paper.LOADS_N
    tasks = ([StepTask(params, f, "pi", DT) for f in loads]
             + [StaticTask(params, f, po, DT) for f in loads for po in (0.0, 0.04 * MPA)]
             + [SineTask(params, 50.0, "pi", 0.1, DT, True),
                SineTask(params, 150.0, "pi", 0.5, DT, True)])
    try:
        out = execute(tasks, workers)
    except Exception:  # noqa: BLE001 (a parameter set the simulator refuses costs the most)
        return 1e9
    steps = [(r.worst_error(SETTLE_S), r.worst_peak_to_peak(SETTLE_S), r.area,
              float(np.mean(r.po_mean))) for r in out[:3]]
    static = [loop.area for loop in out[3:9]]
    po_slow, po_fast = (float(r.po_reg.max()) for _, r in out[9:])
    t2 = [static[2 * i + 1] / static[2 * i] for i in range(3)]
    fb = [area / static[2 * i] for i, (_, _, area, _) in enumerate(steps)]
    c = sum(math.log(v / paper.TABLE2["open_po"][f]) ** 2 for v, f in zip(t2, loads))
    c += sum(4 * max(0, err / MM - 0.45) ** 2 + 4 * max(0, pp / MM - 0.18) ** 2
             for err, pp, _, _ in steps)
    c += sum(100 * max(0, v - 0.018) for v in fb) + 30 * max(0, 3 * fb[1] - fb[2]) \
        + 30 * max(0, fb[0] - fb[1])
    c += 100 * max(0, 0.079 - po_fast / MPA) + 100 * max(0, po_slow / MPA - 0.068) \
        + 100 * max(0, (steps[0][3] - steps[2][3]) / MPA + 0.005)
    return c


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=7, help="random-search seed (default 7)")
    ap.add_argument("--samples", type=int, default=150, help="random samples (default 150)")
    ap.add_argument("--nm-from", type=int, default=2,
                    help="start Nelder-Mead from the n-th best sample (default 2)")
    ap.add_argument("--nm-evals", type=int, default=160, help="Nelder-Mead evaluations")
    ap.add_argument("--jobs", type=int, default=2, help="cores (batch threads)")
    args = ap.parse_args()
    rng = np.random.default_rng(args.seed)
    samples = [(rng.uniform(size=len(FREE)), float(rng.choice(READINGS)))
               for _ in range(args.samples)]
    with open_workers(args.jobs) as pool:
        scored = []
        for i, (u, reading) in enumerate(samples):
            scored.append((cost(params_at(u, reading), pool), i))
            print(f"sample {i + 1}/{len(samples)}: cost {scored[-1][0]:.3f}", flush=True)
        scored.sort()
        u0, reading = samples[scored[args.nm_from - 1][1]]
        res = minimize(lambda u: cost(params_at(u, reading), pool), u0, method="Nelder-Mead",
                       options=dict(maxfev=args.nm_evals, xatol=1e-3, fatol=1e-3))
    best = params_at(res.x, reading)
    lines = ["# scripts/joint_fit.py; SI units", ""]
    for section in ("braid", "muscle", "pneumatics", "controller"):
        lines.append(f"[{section}]")
        keys = [n.partition(".")[2] for n in FREE if n.startswith(section + ".")]
        lines += [f"{k} = {getattr(getattr(best, section), k)!r}" for k in keys]
        if section == "controller":
            lines.append(f"command_scale = {reading!r}")
        lines.append("")
    write_text_atomic("calibrated-joint.toml", "\n".join(lines))
    print(f"best cost {res.fun:.3f}; wrote calibrated-joint.toml")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
