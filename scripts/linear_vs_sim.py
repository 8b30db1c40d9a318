"""Regenerate the numbers of docs/linear_model.md: the §3 linear model against the simulation.

For each load, the linear models at the sweep's mean contraction and the simulated sweeps at
several amplitudes; prints Markdown tables (operating points and stability; worst agreement
at 0.1-0.25 Hz per amplitude; every point at the paper's and the small amplitude; the Po
limit cycle beside the extended model's instability; what bounds the linear range) and writes
linear_vs_sim.json and linear_vs_sim.csv. About 75 s of wall time on two shared cores.

Usage: python scripts/linear_vs_sim.py [--loads 50,100,150] [--amplitudes MM,...] [--out DIR]
"""

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from wpam_mj import paper
from wpam_mj.design import linear_study
from wpam_mj.infra import pool
from wpam_mj.physics import pneumatics as pn
from wpam_mj.experiments.drives import SineSpec, sine_run
from wpam_mj.design.linear_study import AGREEMENT_FREQS_HZ, GAIN_TOL_DB, LAG_TOL_DEG
from wpam_mj.physics.muscle import MuscleModel
from wpam_mj.physics.params import preset
from wpam_mj.units import MM, MPA
from wpam_mj.infra.files import write_text_atomic

SCAN_AMPLITUDES_MM = (0.2, 0.5, 1.0, 2.0, 5.0, 10.0, 25.0)


def _float_list(text: str) -> tuple[float, ...]:
    try:
        return tuple(float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a list like 1,2.5") from None


def _models_table(comparisons) -> list[str]:
    lines = ["| load [N] | Pi [MPa] | m [kg] | c [N s/m] | A_o [m^2] | k [N/m] | model | "
             "ctrl | stable | GM [1] @ Hz | PM [deg] @ Hz |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for c in comparisons:
        op = c.loops[0].op
        for lp in c.loops:
            mg = lp.margins()
            lines.append(
                f"| {c.load:g} | {op.pi / MPA:.4f} | {op.mass:.3f} | {op.damping:.4g} | "
                f"{op.po_area:.4g} | {op.stiffness:.4g} | {lp.model} | {lp.control.upper()} | "
                f"{'yes' if lp.stable else 'no'} | {mg['gain_margin']:.3g} @ "
                f"{mg['phase_crossover_hz']:.3g} | {mg['phase_margin_deg']:.3g} @ "
                f"{mg['gain_crossover_hz']:.3g} |")
    return lines


def _agreement_table(comparisons) -> list[str]:
    lines = [f"| load [N] | amplitude [mm] | worst gain diff [dB] | worst lag diff [deg] | "
             f"within {GAIN_TOL_DB:g} dB and {LAG_TOL_DEG:g} deg |", "|---|---|---|---|---|"]
    for row in linear_study.amplitude_scan(comparisons):
        lines.append(f"| {row['load_n']:g} | {row['amplitude_mm']:g} | "
                     f"{row['worst_gain_db']:.2f} | {row['worst_lag_deg']:.1f} | "
                     f"{'yes' if row['agrees'] else 'no'} |")
    return lines


def _points_table(comparisons, amplitudes_mm) -> list[str]:
    lines = ["| load [N] | amplitude [mm] | ctrl | f [Hz] | sim gain | sim lag [deg] | "
             "§3 gain | §3 lag [deg] | extended gain | extended lag [deg] |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for c in comparisons:
        for r in c.rows():
            if r["amplitude_mm"] in amplitudes_mm:
                lines.append(
                    f"| {c.load:g} | {r['amplitude_mm']:g} | {r['controller'].upper()} | "
                    f"{r['freq_hz']:g} | {r['sim_gain']:.3f} | {r['sim_lag_deg']:.1f} | "
                    f"{r['paper_gain']:.3f} | {r['paper_lag_deg']:.1f} | "
                    f"{r['extended_gain']:.3f} | {r['extended_lag_deg']:.1f} |")
    return lines


def _limit_cycle_table(params, comparisons, freq: float = 0.25) -> list[str]:
    """Frequency of the Po oscillation under PI at the small amplitude beside the extended
    model's phase crossover (where a describing-function limit cycle sits)."""
    lines = ["| load [N] | Po oscillation in the simulation [Hz] | Po range [MPa] | "
             "extended model: phase crossover [Hz], unstable pole [Hz] |", "|---|---|---|---|"]
    spec = SineSpec(freq, amplitude=linear_study.SMALL_AMPLITUDE_MM * MM)
    for c in comparisons:
        r = sine_run(params, c.load, "pi", spec)
        window = r.time >= spec.settle_cycles / freq
        po = r.po[window] - r.po[window].mean()
        f = np.fft.rfftfreq(po.size, r.time[1] - r.time[0])
        above = f > 4 * freq  # beyond the target's own harmonics
        peak = f[above][np.argmax(np.abs(np.fft.rfft(po))[above])]
        lp = c.loop("extended", "pi")
        pole = max(lp.poles(), key=lambda p: p.real)
        lines.append(f"| {c.load:g} | {peak:.2f} | {r.po[window].min() / MPA:.3f}-"
                     f"{r.po[window].max() / MPA:.3f} | "
                     f"{lp.margins()['phase_crossover_hz']:.2f}, "
                     f"{abs(pole.imag) / (2 * np.pi):.2f} |")
    return lines


def _regimes_table(params, comparisons) -> list[str]:
    """What bounds the linear range at each load: the friction band Po must cross to reverse
    the load, the Po swing over which the line's flow law is linear, and how fast the
    outer chamber can fill (regulator at the cap) and vent (at p_min) from the rest Po."""
    muscle = MuscleModel.from_params(params)
    pnm, cap = params.pneumatics, params.controller.po_cap
    lines = ["| load [N] | friction Ff [N] | reversal band 2 Ff / A_o [MPa] | linear flow "
             "range of Po [kPa] (= error [mm]) | fill / vent rate [MPa/s] |",
             "|---|---|---|---|---|"]
    for c in comparisons:
        op = c.loops[0].op
        ff = muscle.friction(op.x, op.pi, op.po)
        linear_kpa = (1.0 - pn.R_LAMINAR) * op.outer.pressure / 1e3
        kp = params.controller.kp * params.controller.command_scale  # MPa/mm

        def rate(p_set: float) -> float:
            flow = pn.mass_flow(p_set + pnm.atmosphere, op.outer.pressure,
                                pnm.outer_conductance, pnm.critical_ratio)
            return abs(pn.RT0 * flow / op.outer.volume) / MPA
        lines.append(f"| {c.load:g} | {ff:.1f} | {2 * ff / op.po_area / MPA:.4f} | "
                     f"{linear_kpa:.2f} (= {linear_kpa / 1e3 / kp:.3f}) | "
                     f"{rate(cap):.3f} / {rate(pnm.p_min):.3f} |")
    return lines


def _saturation_table(params, comparisons, amplitudes_mm, freq: float = 0.25) -> list[str]:
    """How long the Po command sits at a limit of its range (PI): short stints are the limit
    cycle, stints of most of a half cycle mean the loop is open."""
    lo, hi = params.pneumatics.p_min, params.controller.po_cap
    lines = ["| load [N] | amplitude [mm] | Po command at a limit [% of time] | longest stint "
             "[s] |", "|---|---|---|---|"]
    for c in comparisons:
        for amp in sorted(amplitudes_mm):
            spec = SineSpec(freq, amplitude=amp * MM)
            r = sine_run(params, c.load, "pi", spec)
            window = r.time >= spec.settle_cycles / freq
            at_limit = (r.po_cmd[window] <= lo) | (r.po_cmd[window] >= hi)
            edges = np.flatnonzero(np.diff(np.concatenate([[0], at_limit.astype(int), [0]])))
            longest = np.max(np.diff(edges)[::2], initial=0) * (r.time[1] - r.time[0])
            lines.append(f"| {c.load:g} | {amp:g} | {100 * at_limit.mean():.0f} | "
                         f"{longest:.2f} |")
    return lines


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--loads", type=_float_list, default=paper.LOADS_N,
                        metavar="N,N", help="hanging loads [N] (default: 50,100,150)")
    parser.add_argument("--amplitudes", type=_float_list, default=SCAN_AMPLITUDES_MM,
                        metavar="MM,MM", help="sine amplitudes [mm] (default: "
                        + ",".join(f"{a:g}" for a in SCAN_AMPLITUDES_MM) + ")")
    parser.add_argument("--jobs", type=int, default=pool.default_jobs(), metavar="N",
                        help="worker processes [count]")
    parser.add_argument("--out", type=Path, default=Path("out") / "linear_vs_sim",
                        metavar="DIR", help="output folder (default: out/linear_vs_sim)")
    args = parser.parse_args(argv)
    params = preset("wpam")
    comparisons = linear_study.compare(params, args.loads,
                                       amplitudes=[a * MM for a in args.amplitudes],
                                       jobs=args.jobs)
    shown = {linear_study.SMALL_AMPLITUDE_MM, max(args.amplitudes)}
    print("\n".join(["## Operating points and stability", *_models_table(comparisons), "",
                     f"## Agreement with the §3 model at {', '.join(map(str, AGREEMENT_FREQS_HZ))}"
                     " Hz (PI and PID)", *_agreement_table(comparisons), "",
                     "## Every point at " + " and ".join(f"{a:g}" for a in sorted(shown)) + " mm",
                     *_points_table(comparisons, shown), "",
                     f"## The Po limit cycle (PI, {linear_study.SMALL_AMPLITUDE_MM:g} mm, "
                     "0.25 Hz)", *_limit_cycle_table(params, comparisons), "",
                     "## What bounds the linear range", *_regimes_table(params, comparisons),
                     "", "## The Po command at its limits (PI, 0.25 Hz)",
                     *_saturation_table(params, comparisons, shown)]))
    args.out.mkdir(parents=True, exist_ok=True)
    write_text_atomic(args.out / "linear_vs_sim.json",
                      json.dumps([c.as_json() for c in comparisons], indent=2) + "\n")
    write_text_atomic(args.out / "linear_vs_sim.csv",
                      "".join(c.csv_text() if i == 0 else c.csv_text().split("\n", 1)[1]
                              for i, c in enumerate(comparisons)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
