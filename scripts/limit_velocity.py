"""What sets the limit velocity (§4.2): fastest contraction and extension per load under a
saturated Po command, on the plant and with each candidate element removed in turn.

    python scripts/limit_velocity.py [--config FILE] [--out DIR]

Writes limit_velocity.csv (load, variant, speeds in mm/s) and prints the table
(`wpam_mj.experiments.limit_velocity`).
"""

from __future__ import annotations

import argparse
import csv
import io
from pathlib import Path

from wpam_mj import paper
from wpam_mj.experiments.limit_velocity import VARIANTS, limit_velocity, variant
from wpam_mj.infra.files import write_text_atomic
from wpam_mj.physics.params import apply_overrides, preset
from wpam_mj.errors import load_toml
from wpam_mj.units import MM


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--config", help="TOML overrides of the shipped W-PAM")
    ap.add_argument("--out", default="out/limit_velocity", help="output folder")
    ap.add_argument("--dt", type=float, default=1e-3, help="physics step [s]")
    args = ap.parse_args()
    params = preset("wpam")
    if args.config:
        params = apply_overrides(params, load_toml(args.config))
    rows = []
    for name, overrides in VARIANTS.items():
        for load in paper.LOADS_N:
            lv = limit_velocity(variant(params, overrides), load, dt=args.dt)
            rows.append({"variant": name, "load_n": load,
                         "contraction_mm_s": lv.contraction / MM,
                         "extension_mm_s": lv.extension / MM})
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=list(rows[0]))
    writer.writeheader()
    writer.writerows(rows)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    write_text_atomic(out / "limit_velocity.csv", buf.getvalue())
    print(f"{'variant':44s} " + " ".join(f"{v:>14g} N" for v in paper.LOADS_N))
    for name in VARIANTS:
        cells = [r for r in rows if r["variant"] == name]
        print(f"{name:44s} " + " ".join(
            f"{r['contraction_mm_s']:6.0f}/{r['extension_mm_s']:<6.0f}  " for r in cells))
    print("(fastest contraction/extension [mm/s] under Po switched cap <-> floor, Pi at the "
          f"25 mm feedforward); wrote {out / 'limit_velocity.csv'}")


if __name__ == "__main__":
    main()
