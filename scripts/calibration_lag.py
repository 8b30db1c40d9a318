"""Why the controller's model, fitted to the plant's own Figs. 8-9 ramps, is not the plant:
the chamber runs behind the regulator's gauge while the muscle slides, and the fit reads x
against the gauge.

    python scripts/calibration_lag.py [--ramp-times 60,120,240] [--slower-than 10,5,3,2,1]
                                      [--dt 0.001] [--json FILE]

For each ramp time (each direction) the shipped plant's six open-loop ramps (`wpam
table2`'s, three loads, Po = 0 and 0.04 MPa on the way down) are run and, per ramp
(`feedforward_fit.gauge_lag`): how far the chamber's Pi sits from the gauge's where the
muscle holds still and where it slides, and how far x is from the plant's own
equilibrium model read on each. Then the controller's model is fitted to the logged
ramps as `wpam reproduce` fits it (`feedforward_fit.fit_feedforward`), and its error
against the plant printed. `--slower-than` refits the first ramp time's logs on the
samples the encoder logs slower than each speed [mm/s] (a reading the experimenter could
take instead of slower ramps; not the shipped one).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import sys

from wpam_mj.cli.arguments import float_list
from wpam_mj.experiments.protocol import SHIPPED, open_loop_tasks
from wpam_mj.infra.files import write_text_atomic
from wpam_mj.physics.params import preset
from wpam_mj.reproduction import feedforward_fit as ff
from wpam_mj.simulation.execution import execute
from wpam_mj.units import MM


def _errors(fit: ff.FeedforwardFit, plant) -> dict[str, float]:
    """The fitted model / the plant - 1, by short name (`feedforward_fit.model_error`)."""
    return {n.split(".")[1]: e for n, e in ff.model_error(fit.controller_of(plant))}


def _span(values, scale: float) -> str:
    return f"{min(values) / scale:.2f}-{max(values) / scale:.2f}"


def _model_text(errors: dict[str, float]) -> str:
    rest = max((k for k in errors if k != "friction_const"), key=lambda k: abs(errors[k]))
    return f"F_f0 {errors['friction_const']:+.1%}, {rest} {errors[rest]:+.1%}"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ramp-times", type=float_list, default=(60.0, 120.0, 240.0),
                    help="ramp times [s], each direction, comma-separated")
    ap.add_argument("--slower-than", type=float_list, default=(),
                    help="refit the first ramp time on the samples slower than these [mm/s]")
    ap.add_argument("--dt", type=float, default=1e-3)
    ap.add_argument("--jobs", type=int, default=os.cpu_count())
    ap.add_argument("--json", help="write every figure here")
    args = ap.parse_args(argv)
    plant = preset()
    rows, refits = [], []
    print("| ramp [s] | chamber from gauge, held / sliding [kPa] | x from the plant's model "
          "on chamber / gauge Pi, sliding [mm rms] | fitted model's error | x residual [mm] |")
    print("|---|---|---|---|---|")
    for ramp in args.ramp_times:
        protocol = dataclasses.replace(SHIPPED, ramp_time=ramp)
        loops = execute(open_loop_tasks(plant, protocol, dt=args.dt), args.jobs)
        lags = [ff.gauge_lag(lp, plant) for lp in loops]
        logged = [ff.measured_loop(lp) for lp in loops]
        fit = ff.fit_feedforward(plant, logged)
        row = {"ramp_time_s": ramp, "lags": [dataclasses.asdict(g) for g in lags],
               "model_error": _errors(fit, plant), "rms_mm": fit.rms / MM}
        rows.append(row)
        print(f"| {ramp:g} | {_span([g.lag_held for g in lags], 1e3)} / "
              f"{_span([g.lag_sliding for g in lags], 1e3)} | "
              f"{_span([g.x_error_chamber for g in lags], MM)} / "
              f"{_span([g.x_error_gauge for g in lags], MM)} | "
              f"{_model_text(row['model_error'])} | {row['rms_mm']:.2f} |", flush=True)
        if ramp == args.ramp_times[0]:
            for v in args.slower_than:
                refit = ff.fit_feedforward(plant, logged, slower_than=v * MM)
                refits.append({"ramp_time_s": ramp, "slower_than_mm_s": v,
                               "model_error": _errors(refit, plant)})
    for r in refits:
        print(f"{r['ramp_time_s']:g} s ramps, fitted on samples slower than "
              f"{r['slower_than_mm_s']:g} mm/s: {_model_text(r['model_error'])}")
    if args.json:
        write_text_atomic(args.json, json.dumps({"ramps": rows, "slower_than": refits},
                                                indent=2, allow_nan=False) + "\n")
    return 0 if all(math.isfinite(r["rms_mm"]) for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
