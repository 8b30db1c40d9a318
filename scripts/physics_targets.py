"""Measure every target of the credible-plant revision on the shipped parameters.

Prints one table (figure, measured, target, pass/fail) and writes it as JSON and Markdown:
Table 2 under the shipped protocol with 60 s and 240 s ramps (the paper does not state its
ramp), each loop measured with every lobe counted and signed, the step runs'
settled plateau error and peak-to-peak (PI and PID, 50/100/150 N), the §4.2 findings of
the sweep (`wpam_mj.paper`), time-step convergence of every reported figure, and the
plausible readings of the paper's unitless gains (`Controller.command_scale`).

    python scripts/physics_targets.py [--out DIR] [--jobs N] [--quick]

Takes about 20 s on two quiet cores (--quick: the readings table and dt check skipped).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

import numpy as np

from wpam_mj import paper, preset
from wpam_mj.reproduction import findings
from wpam_mj.infra import pool
from wpam_mj.experiments.drives import SineSpec, sine_run
from wpam_mj.physics.params import Params
from wpam_mj.units import MM, MPA
from wpam_mj.experiments.protocol import SHIPPED, remeasure, table2_batch
from wpam_mj.infra.files import write_text_atomic
from wpam_mj.simulation.execution import execute
from wpam_mj.experiments.paper_studies import step_study, sweep

READINGS = {"MPa/mm": 1.0, "V/mm, 0-5 V input": 0.1, "V/mm, 0-10 V input": 0.05}
SETTLE_S = 5.0  # the last 5 s of each 10 s plateau


class _ReadingTask:
    """Step runs and two sine runs of the PI loop under one reading of the gains."""

    def __init__(self, params: Params, dt: float) -> None:
        self.params, self.dt, self.cost = params, dt, 400.0 / dt

    def run(self) -> dict:
        steps = step_study(self.params, [(load, "pi") for load in paper.LOADS_N], dt=self.dt)
        out = {"worst_error_mm": max(s.worst_error(SETTLE_S) for s in steps) / MM,
               "peak_to_peak_mm": max(s.worst_peak_to_peak(SETTLE_S) for s in steps) / MM}
        for load, freq in ((50.0, 0.1), (150.0, 0.5)):
            r = sine_run(self.params, load, "pi", SineSpec(freq), dt=self.dt)
            out[f"po_max_{load:g}N_{freq:g}Hz_mpa"] = float(r.po_reg.max() / MPA)
        return out


def measure(params: Params, *, dt: float, jobs: int) -> dict:
    """Every figure of the targets at one time step."""
    (t2,) = execute([table2_batch(params, SHIPPED, dt=dt)], jobs)
    steps = step_study(params, [(load, c) for c in ("pi", "pid") for load in paper.LOADS_N],
                       dt=dt, jobs=jobs)
    sw = sweep(params, keep=(), dt=dt, jobs=jobs)
    return {
        "table2_po_row": {f"{k:g}": v for k, v in t2.open_po.items()},
        "table2_feedback_row": {f"{k:g}": v for k, v in t2.feedback.items()},
        "steps": {f"{s.control} {s.load:g} N": {
            "worst_error_mm": s.worst_error(SETTLE_S) / MM,
            "peak_to_peak_mm": s.worst_peak_to_peak(SETTLE_S) / MM,
            "po_plateau_mean_mpa": float(np.mean(s.po_mean) / MPA),
            "pi_plateau_mean_mpa": float(np.mean(s.pi_mean) / MPA)} for s in steps},
        "sweep": [p.as_json() for p in sw.points],
        "checks": [{"finding": c.finding, "verdict": c.verdict, "detail": c.detail}
                   for c in findings.sweep_checks(sw)
                   + findings.table2_checks(t2)],
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("out") / "physics_targets",
                        help="output folder (default: out/physics_targets)")
    parser.add_argument("--jobs", type=int, default=pool.default_jobs(),
                        help="worker processes [count]")
    parser.add_argument("--quick", action="store_true",
                        help="skip the gain-readings table and the dt/2 run")
    args = parser.parse_args()
    params = preset("wpam")
    dt = 1e-3
    result = measure(params, dt=dt, jobs=args.jobs)
    fast, slow = execute(
        [table2_batch(params, dataclasses.replace(SHIPPED, ramp_time=r), dt=dt)
         for r in (SHIPPED.ramp_time, 240.0)], args.jobs)
    result["po_row_ramp"] = {
        f"{r:g} s, {m}": {f"{k:g}": v for k, v in remeasure(t, m).open_po.items()}
        for r, t in ((SHIPPED.ramp_time, fast), (240.0, slow))
        for m in ("branches", "shoelace")}
    if not args.quick:
        half = measure(params, dt=dt / 2, jobs=args.jobs)
        result["dt_half"] = half
        result["readings"] = dict(zip(READINGS, execute(
            [_ReadingTask(params.replace(controller={"command_scale": s}), dt)
             for s in READINGS.values()], args.jobs)))
    args.out.mkdir(parents=True, exist_ok=True)
    write_text_atomic(args.out / "physics_targets.json", json.dumps(result, indent=1) + "\n")
    print(json.dumps({k: v for k, v in result.items() if k not in ("sweep", "dt_half")},
                     indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
