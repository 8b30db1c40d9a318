"""Recovery check of `wpam fit`: synthesise measurements from
plant parameters 20-40 % away from the shipped ones (halfway to the farther bound where
the plausible range is narrower), fit them back from the shipped values, and compare.

Data: static ramps (Po = 0.04 MPa while Pi falls) and a PI staircase at 50/100/150 N,
fitted; a PI sine run per load, held out. Noise 0.05 mm on x and 1 kPa on the gauges.
Prints each free parameter's error against its true value, the RMS per file, the
held-out RMS against the noise, the wall time and the machine's load average.

    python scripts/fit_recovery.py [--jobs 2] [--json] [--keep DIR]
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path

from wpam_mj import preset
from wpam_mj.fitting import estimation
from wpam_mj.fitting.measured_fit import fit_data
from wpam_mj.fitting.measurements import experiment_files, read_experiment
from wpam_mj.units import MM
from wpam_mj.fitting.synthetic import HOLDOUT_DIR, synth

# Relative offsets of the true values from the shipped ones, in default_free() order;
# the sign flips (then the offset shrinks to 20 %) where a value would leave its range.
OFFSETS = (0.3, -0.25, 0.35, -0.3, 0.25, -0.35, 0.4)
TARGET_REL = 0.05  # every free parameter within 5 % of its true value
TARGET_HOLDOUT = 1.5  # held-out RMS within 1.5x the x noise


def true_values(shipped, free: tuple[estimation.FreeParameter, ...]) -> dict[str, float]:
    out = {}
    for p, d in zip(free, OFFSETS * 2):
        v0 = p.value(shipped)
        for rel in (d, -d, 0.2, -0.2):
            if p.lo <= v0 * (1.0 + rel) <= p.hi:
                out[p.name] = v0 * (1.0 + rel)
                break
        else:  # a narrow range (the braid angle's 18-25 deg): halfway to the farther bound
            far = p.lo if v0 - p.lo >= p.hi - v0 else p.hi
            out[p.name] = 0.5 * (v0 + far)
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--jobs", type=int, default=os.cpu_count() or 1,
                    help="worker processes [count]")
    ap.add_argument("--noise-mm", type=float, default=0.05, help="x noise [mm] (1 sigma)")
    ap.add_argument("--noise-kpa", type=float, default=1.0, help="gauge noise [kPa]")
    ap.add_argument("--seed", type=int, default=0, help="noise seed")
    ap.add_argument("--max-evals", type=int, default=60, help="most residual evaluations")
    ap.add_argument("--keep", type=Path, help="write the data and figures here")
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    args = ap.parse_args()

    shipped = preset("wpam")
    free = tuple(estimation.FreeParameter.of(n) for n in estimation.default_free())
    truth = true_values(shipped, free)
    hidden = estimation.with_values(shipped, free, [truth[p.name] for p in free])
    folder = args.keep or Path(tempfile.mkdtemp(prefix="wpam_recovery_"))
    start = time.perf_counter()
    synth(hidden, folder, noise_mm=args.noise_mm, noise_kpa=args.noise_kpa,
          seed=args.seed, jobs=args.jobs)
    t_synth = time.perf_counter() - start
    fitted = [read_experiment(f, shipped) for f in experiment_files([folder])]
    held = [read_experiment(f, shipped) for f in experiment_files([folder / HOLDOUT_DIR])]
    load_before = os.getloadavg()
    start = time.perf_counter()
    result = fit_data(shipped, fitted, free, holdout=held, jobs=args.jobs,
                      max_nfev=args.max_evals, progress=True)
    t_fit = time.perf_counter() - start
    load = os.getloadavg()
    rows = [{"name": e.name, "true": truth[e.name], "start": p.value(shipped),
             "fitted": e.value, "sigma": e.sigma, "error": e.value / truth[e.name] - 1.0,
             "note": e.note} for e, p in zip(result.result.estimates, free)]
    holdout = result.rms(True) / MM
    summary = {
        "parameters": rows,
        "files": [f.as_json() for f in result.files],
        "rms_fit_mm": result.rms(False) / MM, "rms_holdout_mm": holdout,
        "noise_mm": args.noise_mm,
        "worst_error": max(abs(r["error"]) for r in rows),
        "pass_parameters": all(abs(r["error"]) <= TARGET_REL for r in rows),
        "pass_holdout": holdout <= TARGET_HOLDOUT * args.noise_mm,
        "fit_s": t_fit, "synth_s": t_synth, "evaluations": result.result.nfev,
        "jacobians": result.result.njev, "jobs": args.jobs,
        "load_average_before": load_before, "load_average_after": load,
    }
    if args.keep:
        from wpam_mj.fitting.measured_fit import write_figures  # noqa: PLC0415 (matplotlib)
        write_figures(result, args.keep / "figures")
    if args.json:
        print(json.dumps(summary, indent=2))
        return 0
    print(f"{'parameter':<30} {'true':>11} {'start':>11} {'fitted':>11} {'1-sigma':>10} "
          f"{'error':>8}")
    for r in rows:
        print(f"{r['name']:<30} {r['true']:>11.5g} {r['start']:>11.5g} {r['fitted']:>11.5g} "
              f"{r['sigma']:>10.3g} {r['error']:>+8.2%} {r['note']}")
    for f in result.files:
        print(f"  {f.experiment.name:<14} {'held out' if f.held_out else 'fitted':<9} "
              f"RMS {f.rms / MM:.4f} mm")
    print(f"RMS fitted {summary['rms_fit_mm']:.4f} mm, held out {holdout:.4f} mm "
          f"(target <= {TARGET_HOLDOUT * args.noise_mm:.3f} mm): "
          f"{'PASS' if summary['pass_holdout'] else 'FAIL'}")
    print(f"worst parameter error {summary['worst_error']:.2%} (target <= "
          f"{TARGET_REL:.0%}): {'PASS' if summary['pass_parameters'] else 'FAIL'}")
    print(f"fit {t_fit:.1f} s ({result.result.nfev} evaluations, {result.result.njev} "
          f"Jacobians of the last pass, {args.jobs} jobs), synth {t_synth:.1f} s; load "
          f"average (1/5/15 min) before {'/'.join(f'{v:.2f}' for v in load_before)}, after "
          f"{'/'.join(f'{v:.2f}' for v in load)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
