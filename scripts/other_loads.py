"""The paper's figures at loads between and beyond its own: is the fit physical
away from 50/100/150 N?

At 25, 50, 75, 100, 125, 150 and 200 N, on the shipped parameters and protocol (or
--config FILE and the protocol options of `wpam reproduce`'s defaults): Table 2's rows,
the PI staircase (worst settled plateau error and x peak-to-peak, plateau-mean Pi and
Po), and the PI frequency response (gain, lag, regulator Po max). Then the trends a
physical rig must show: Table 2's Po row falling with load, Pi and Po rising with load,
every step settled, Po inside [p_min, cap] and the lag at 0.1 Hz rising with load.

    nice -n 10 python scripts/other_loads.py [--config FILE] [--jobs 2]
        [--ramp-top MPA] [--loop-area branches|shoelace] [--out out/other_loads]

About 2 core-minutes; writes OUT/other_loads.json and OUT/other_loads.md.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

import numpy as np

from wpam_mj import paper
from wpam_mj.physics.params import apply_overrides, preset
from wpam_mj.errors import load_toml
from wpam_mj.units import MM, MPA
from wpam_mj.experiments.protocol import LOOP_METHODS, SHIPPED, table2_batch
from wpam_mj.infra.files import write_text_atomic
from wpam_mj.experiments.paper_studies import PLATEAU_SETTLE_S, sweep_batch
from wpam_mj.simulation.execution import execute

LOADS_N = (25.0, 50.0, 75.0, 100.0, 125.0, 150.0, 200.0)
LAG_FREQ_HZ = 0.1


def measure(params, protocol, jobs: int) -> dict:
    t2, sw = execute([table2_batch(params, protocol, loads=LOADS_N),
                      sweep_batch(params, LOADS_N, paper.SWEEP_FREQS_HZ, ("pi",), keep=())],
                     jobs)
    rows = {}
    for run in t2.feedback_runs:
        load = run.load
        pts = [sw.point(load, f, "pi") for f in paper.SWEEP_FREQS_HZ]
        rows[f"{load:g}"] = {
            "table2_po": t2.open_po[load], "table2_feedback": t2.feedback[load],
            "step_error_mm": run.worst_error(PLATEAU_SETTLE_S) / MM,
            "step_pp_mm": run.worst_peak_to_peak(PLATEAU_SETTLE_S) / MM,
            "pi_plateau_mpa": float(np.mean(run.pi_mean)) / MPA,
            "po_plateau_mpa": float(np.mean(run.po_mean)) / MPA,
            "po_plateau_min_mpa": float(np.min(run.po_mean)) / MPA,
            "gain": [p.gain for p in pts], "lag_deg": [p.phase_lag_deg for p in pts],
            "po_max_mpa": [p.po_max / MPA for p in pts]}
    return rows


def _rising(values) -> bool:
    return bool(np.all(np.diff(values) >= 0.0))


def trends(rows: dict, params) -> dict[str, bool]:
    """The trends a physical rig shows across loads (module docstring)."""
    col = {k: [r[k] for r in rows.values()] for k in next(iter(rows.values()))}
    lag_i = paper.SWEEP_FREQS_HZ.index(LAG_FREQ_HZ)
    cap = params.controller.po_cap / MPA
    return {"Table 2 Po row falls with load": _rising([-v for v in col["table2_po"]]),
            "plateau-mean Pi rises with load": _rising(col["pi_plateau_mpa"]),
            "plateau-mean Po rises with load": _rising(col["po_plateau_mpa"]),
            "every step settled (<= 0.5 mm, p-p <= 0.2 mm)": all(
                e <= 0.5 and p <= 0.2 for e, p in zip(col["step_error_mm"],
                                                       col["step_pp_mm"])),
            f"Po within [p_min, {cap:g} MPa]": all(
                params.pneumatics.p_min / MPA - 1e-6 <= lo and hi <= cap + 1e-6
                for lo, hi in zip(col["po_plateau_min_mpa"],
                                  [max(v) for v in col["po_max_mpa"]])),
            f"PI lag at {LAG_FREQ_HZ:g} Hz rises with load": _rising(
                [v[lag_i] for v in col["lag_deg"]])}


def markdown(rows: dict, checks: dict[str, bool]) -> str:
    fr = "/".join(f"{f:g}" for f in paper.SWEEP_FREQS_HZ)
    lines = ["| load | Table 2 Po | feedback | PI error / p-p [mm] | Pi / Po plateau [MPa] "
             f"| PI gain ({fr} Hz) | PI lag [deg] | Po max [MPa] |",
             "|---|---|---|---|---|---|---|---|"]
    for load, r in rows.items():
        lines.append(
            f"| {load} N | {r['table2_po']:.4f} | {r['table2_feedback']:.4f} | "
            f"{r['step_error_mm']:.2f} / {r['step_pp_mm']:.2f} | "
            f"{r['pi_plateau_mpa']:.4f} / {r['po_plateau_mpa']:.4f} | "
            + "/".join(f"{g:.2f}" for g in r["gain"]) + " | "
            + "/".join(f"{v:.1f}" for v in r["lag_deg"]) + " | "
            + "/".join(f"{v:.3f}" for v in r["po_max_mpa"]) + " |")
    lines += ["", *(f"- {k}: {'yes' if v else 'NO'}" for k, v in checks.items())]
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--config", type=Path)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--ramp-top", type=float, default=None, metavar="MPA",
                    help="one common ramp top [MPa] (default: the shipped protocol's)")
    ap.add_argument("--loop-area", choices=LOOP_METHODS, default=None,
                    help="loop-area definition (default: the shipped protocol's)")
    ap.add_argument("--out", type=Path, default=Path("out") / "other_loads")
    a = ap.parse_args()
    params = preset("wpam")
    if a.config is not None:
        params = apply_overrides(params, load_toml(a.config))
    protocol = SHIPPED if a.ramp_top is None else dataclasses.replace(
        SHIPPED, ramp_top=a.ramp_top * MPA)
    if a.loop_area is not None:
        protocol = dataclasses.replace(protocol, loop_method=a.loop_area)
    rows = measure(params, protocol, a.jobs)
    checks = trends(rows, params)
    a.out.mkdir(parents=True, exist_ok=True)
    write_text_atomic(a.out / "other_loads.json", json.dumps(
        {"protocol": protocol.describe(), "loads": rows, "trends": checks}, indent=1))
    text = markdown(rows, checks)
    write_text_atomic(a.out / "other_loads.md", text)
    print(f"protocol: {protocol.describe()}\n{text}")


if __name__ == "__main__":
    main()
