"""The Warp backend against the compiled plugin on one device: the parity table of
docs/warp.md (every preset and control mode, the largest gap over a 3 s staircase), and
whether a world's run depends on how many worlds share its batch (needs the gpu extra).

    python benchmarks/warp_parity.py [--device cuda] [--copies 1024] [--json FILE]

With --copies K every case also runs K times in one batch of 6 K worlds; each copy must
reproduce the batch of one world's run of its case bit for bit. Exits 1 where a gap is
outside its tolerance (`wpam_mj.experiments.warp_parity.TOLERANCE`) or a copy differs.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from wpam_mj.infra.files import write_text_atomic
from wpam_mj.simulation import warp_muscle
from wpam_mj.simulation.simulate import simulate_run
from wpam_mj.experiments.warp_parity import CASES, TOLERANCE, gaps, parity_runs, within

FIELDS = ("x", "pi", "po", "tension", "friction")
UNITS = {"x": "m", "pi": "Pa", "po": "Pa", "tension": "N", "friction": "N"}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default="cpu", help="Warp device: cpu or cuda")
    parser.add_argument("--copies", type=int, default=0,
                        help="also run each case this many times in one batch (0: not)")
    parser.add_argument("--json", help="write the gaps here as JSON")
    args = parser.parse_args(argv)
    if not warp_muscle.warp_available():
        print("warp_parity: needs the gpu extra (pip install '.[gpu]')", file=sys.stderr)
        return 2
    from wpam_mj.simulation.warp_backend import run_warp  # noqa: PLC0415 (the extra)

    runs = parity_runs()
    reference = [simulate_run(run, "plugin") for run in runs]
    start = time.perf_counter()
    got = run_warp(runs, device=args.device)
    rows, bad = [], []
    print(f"device {args.device}: {len(runs)} worlds, {time.perf_counter() - start:.1f} s "
          "(compiling included)")
    print("| preset, control | " + " | ".join(f"{f} [{UNITS[f]}]" for f in FIELDS)
          + " | samples stuck alike |")
    print("|---" * (len(FIELDS) + 2) + "|")
    for (name, control), ref, warp in zip(CASES, reference, got):
        if isinstance(warp, Exception):
            bad.append(f"{name} {control}: {warp}")
            continue
        g = gaps(ref, warp)
        rows.append({"preset": name, "control": control, **g})
        bad += [f"{name} {control}: {m}" for m in within(g)]
        n = len(ref.x)
        print(f"| {name}, {control} | " + " | ".join(f"{g[f]:.2g}" for f in FIELDS)
              + f" | {round(g['stuck_alike'] * n)} of {n} ({g['stuck']} stuck) |")
    out = {"device": args.device, "tolerance": TOLERANCE, "cases": rows}
    if args.copies:
        start = time.perf_counter()
        many = run_warp([run for run in runs for _ in range(args.copies)], device=args.device)
        wall = time.perf_counter() - start
        pairs = [(m, warp) for i, warp in enumerate(got)
                 for m in many[i * args.copies:(i + 1) * args.copies]]
        differing = sum(not (np.array_equal(m.x, w.x) and np.array_equal(m.po, w.po))
                        for m, w in pairs)
        x_gap = max(float(np.max(np.abs(m.x - w.x))) for m, w in pairs)
        print(f"{args.copies} copies of each case in one batch ({len(many)} worlds, "
              f"{wall:.1f} s): {differing} differ from their case's one-world run "
              f"(largest x gap {x_gap:.2g} m)")
        out["copies"] = {"per_case": args.copies, "worlds": len(many), "wall_s": wall,
                         "differing": differing, "x_gap_m": x_gap}
        if differing:
            bad.append(f"{differing} copies differ from their case's one-world run")
    if args.json:
        write_text_atomic(Path(args.json), json.dumps(out, indent=2) + "\n")
    for line in bad:
        print("outside tolerance:", line)
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
