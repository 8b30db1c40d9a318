"""The high-frequency sentences of §4.2 over the pneumatic structure: does any credible
line, tube, regulator or chamber make the loads' gains and lags alike above 0.5 Hz?

    python scripts/structure_sweep.py [--samples 256] [--seed 0] [--freqs 0.5,1] [--out DIR]
                                      [--backend mujoco|warp] [--device cpu|cuda]

Draws `--samples` plants by a Latin hypercube over every element of the structure between
the regulators and the bags that no paper value pins (`limit_velocity.STRUCTURE_BOX`:
both lines, the tube volume, the exhaust valve, ISO 6358's critical ratio, the chamber
air's polytropic index, the regulators' lag and dead time), the muscle and its controller
as shipped (the controller reading the plant's own values, as `wpam sweep` does), and runs
Fig. 17's sweep on each (3 loads, PI and PID) at `--freqs` (default 0.5 and 1 Hz, §4.2's
"frequency band above 0.5 Hz", where the limit velocity acts; `--freqs
0.1,0.2,0.25,0.5,1` for all of Fig. 17). Every sweep sentence the frequencies allow is
checked on every plant (`findings.sweep_checks`; equal gains only at those frequencies),
and counted over the plants whose load moves in every sine (a load that stalls holds
"alike" vacuously).
Writes structure_sweep.csv (one row per plant: its values, each check's verdict and worst
margin), structure_sweep.json (the fraction of plants holding each check, and the three
high-frequency sentences together) and structure_sweep.png; prints the fractions. On
`--backend warp --device cuda` (the gpu extra) thousands of plants take minutes.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from wpam_mj.cli.arguments import float_list  # noqa: E402
from wpam_mj.experiments.figures import save_figure  # noqa: E402
from wpam_mj.experiments.limit_velocity import STRUCTURE_BOX, structure_sample  # noqa: E402
from wpam_mj.experiments.paper_studies import sweep_batch  # noqa: E402
from wpam_mj.infra.files import csv_text, write_text_atomic  # noqa: E402
from wpam_mj.physics.params import preset  # noqa: E402
from wpam_mj.reproduction import findings  # noqa: E402
from wpam_mj.simulation.execution import Failed, execute  # noqa: E402

HIGH_FREQ = ("gain_spread", "lag_same_high_freq", "pid_gain_equals_pi")  # what the limit sets


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, default=256)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--freqs", type=float_list, default="0.5,1",
                    help="sine frequencies [Hz], comma-separated")
    ap.add_argument("--out", default="out/structure_sweep")
    ap.add_argument("--backend", default="mujoco", choices=("mujoco", "warp"))
    ap.add_argument("--device", default="cpu", help="Warp device (cpu, cuda)")
    ap.add_argument("--jobs", type=int, default=os.cpu_count(),
                    help="CPU cores for the mujoco backend (default: all)")
    args = ap.parse_args(argv)
    if not 1 <= args.samples <= 65536:
        print(f"structure_sweep: --samples {args.samples} outside 1-65536", file=sys.stderr)
        return 2
    plants = structure_sample(preset("wpam"), args.samples, args.seed)
    start = time.perf_counter()
    workers = args.jobs if args.backend == "mujoco" else None
    sweeps = execute([sweep_batch(p, freqs=args.freqs, keep=()) for p in plants], workers,
                     backend=args.backend, device=args.device, failed=Failed,
                     progress=sys.stderr.isatty(), desc="structure sweep")
    wall = time.perf_counter() - start
    rows = []
    for i, (plant, sw) in enumerate(zip(plants, sweeps)):
        row = {"plant": i, **{name: plant.value(name) for name in STRUCTURE_BOX}}
        if isinstance(sw, Failed):
            row["error"] = str(sw.error).splitlines()[0] if str(sw.error) else "failed"
        else:
            row["error"] = ""
            row["moved"] = all(p.load_moved for p in sw.points)
            row["least_gain"] = min(p.gain for p in sw.points)
            for c in findings.sweep_checks(sw):
                row[f"{c.name}_holds"] = c.passed
                row[f"{c.name}_margin"] = c.worst_margin
        rows.append(row)
    ran = [r for r in rows if not r["error"]]
    # a plant whose load does not move in some sine (`feasibility.load_moved`) holds the
    # sentences about alike gains and lags vacuously: only plants that move are counted
    moving = [r for r in ran if r["moved"]]
    names = [f.name for f in findings.SWEEP_FINDINGS  # those the frequencies let it check
             if any(r.get(f"{f.name}_holds") is not None for r in ran)]
    held = {n: (sum(bool(r.get(f"{n}_holds")) for r in moving) / len(moving) if moving
                else math.nan) for n in names}
    together = [r for r in moving if all(r.get(f"{n}_holds") for n in HIGH_FREQ)]
    summary = {"plants": len(rows), "ran": len(ran), "moving": len(moving),
               "seed": args.seed, "freqs_hz": args.freqs,
               "backend": args.backend, "device": args.device, "wall_s": wall,
               "box": {n: list(v[:2]) for n, v in STRUCTURE_BOX.items()},
               "held_fraction": held, "high_freq_sentences": list(HIGH_FREQ),
               "high_freq_together": len(together) / len(moving) if moving else math.nan,
               "high_freq_together_plants": [r["plant"] for r in together]}
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    write_text_atomic(out / "structure_sweep.csv", csv_text(rows))
    write_text_atomic(out / "structure_sweep.json", json.dumps(summary, indent=2) + "\n")
    save_figure(_figure(rows, preset("wpam")), out / "structure_sweep.png")
    print(f"{len(ran)} of {len(rows)} plants ran ({wall:.0f} s, {args.backend}/{args.device}); "
          f"{len(moving)} of them move in every "
          "sine; of those, holding each sweep sentence:")
    for n in names:
        print(f"  {n:28s} {held[n]:6.1%}")
    print(f"  the three high-frequency sentences together: {len(together)} of {len(moving)}")
    print(f"wrote {out}/structure_sweep.csv, .json, .png")
    return 0


def _figure(rows: list[dict], shipped) -> plt.Figure:
    """The two lines' conductances of every plant that moves, coloured by the worst margin
    of the three high-frequency sentences (>= 0: all three hold), the `shipped` plant's
    starred."""
    ran = [r for r in rows if not r["error"] and r["moved"]]
    fig, ax = plt.subplots(figsize=(7, 5))
    if ran:
        worst = [min(r.get(f"{n}_margin", -np.inf) for n in HIGH_FREQ) for r in ran]
        sc = ax.scatter([r["pneumatics.inner_conductance"] for r in ran],
                        [r["pneumatics.outer_conductance"] for r in ran],
                        c=np.clip(worst, -3, 1), cmap="RdYlGn", vmin=-3, vmax=1, s=14)
        fig.colorbar(sc, ax=ax, label="worst margin of the three high-frequency sentences "
                     "(>= 0: all hold)")
    ax.plot([shipped.pneumatics.inner_conductance], [shipped.pneumatics.outer_conductance],
            "k*", ms=12, label="shipped plant")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("Pi line conductance [m³/(s Pa)]")
    ax.set_ylabel("Po line conductance [m³/(s Pa)]")
    ax.set_title(f"{len(ran)} plants that move, over the pneumatic structure")
    ax.legend(loc="lower right")
    fig.tight_layout()
    return fig


if __name__ == "__main__":
    sys.exit(main())
