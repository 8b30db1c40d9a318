"""How far the static ramps' protocol readings alone move Table 2's "Po = 0.04" row.

On one plant (the shipped parameters, or --config FILE), every combination of the ramp
top (per load, or one common Pi), the hold at the top with Po on (0 or --hold S) and
both loop-area definitions ("branches", "shoelace"; measured on the same runs), with
60 s ramps. Prints the row and its errors against the paper's 0.7042/0.1899/0.0638.

    nice -n 10 python scripts/protocol_scan.py [--config FILE] [--jobs 1]

About 2.5 core-minutes (96 ramps of 122 s).
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

from wpam_mj import paper
from wpam_mj.experiments.analysis import loop_area
from wpam_mj.physics.params import apply_overrides, preset
from wpam_mj.errors import load_toml
from wpam_mj.units import MPA
from wpam_mj.experiments.protocol import LOOP_METHODS, Protocol, ProtocolStaticTask
from wpam_mj.simulation.execution import execute

TOPS_MPA = (0.0, 0.10, 0.13, 0.16, 0.19, 0.22, 0.26, 0.30)  # 0: per load


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--config", type=Path)
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--hold", type=float, default=2.0, help="the hold tried beside 0 [s]")
    a = ap.parse_args()
    params = preset("wpam")
    if a.config is not None:
        params = apply_overrides(params, load_toml(a.config))
    protocols = [Protocol(ramp_top=top * MPA, top_hold=h) for top in TOPS_MPA
                 for h in (0.0, a.hold)]
    tasks = [ProtocolStaticTask(params, load, po, 1e-3, pr) for pr in protocols
             for po in (0.0, paper.PO_DOWN_STATIC_MPA * MPA) for load in paper.LOADS_N]
    loops = iter(execute(tasks, a.jobs))
    ref = [paper.TABLE2["open_po"][f] for f in paper.LOADS_N]
    print("top [MPa]  hold [s]  method    row 50/100/150 N          errors")
    for pr in protocols:
        open_, po = ([next(loops) for _ in paper.LOADS_N] for _ in range(2))
        for method in LOOP_METHODS:
            area = [loop_area(lp.result.pi, lp.result.x, method=method) for lp in (*open_, *po)]
            row = [b / a for a, b in zip(area[:3], area[3:])]
            top = "per load" if pr.ramp_top == 0 else f"{pr.ramp_top / MPA:.2f}"
            print(f"{top:>9}  {pr.top_hold:>8g}  {method:<8}  "
                  + "/".join(f"{v:.4f}" for v in row) + "   "
                  + "/".join(f"{v / p - 1:+.0%}" for v, p in zip(row, ref)))
    print(dataclasses.asdict(params.muscle))


if __name__ == "__main__":
    main()
