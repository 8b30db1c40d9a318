"""What sets the limit velocity (§4.2): fastest contraction and extension per load under a
saturated Po command, on the plant and with each candidate element removed in turn.

    python scripts/limit_velocity.py [--config FILE] [--out DIR] [--sines]

Writes limit_velocity.csv (load, variant, speeds in mm/s) and prints the table
(`wpam_mj.experiments.limit_velocity`). With --sines, also the PI sines at 0.5 and 1 Hz
on every variant and on a grid of the two lines (x0.5-4 each): per load the gain, the lag,
where the Po command sits and the speeds reached; sines.csv, and per variant the spreads
§4.2's sentences ask to be small (gains within 5 %, lags within 5 deg).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from wpam_mj import paper
from wpam_mj.design.study_table import csv_text
from wpam_mj.experiments.limit_velocity import (VARIANTS, limit_velocity, line_grid,
                                                sine_at_the_limit, variant)
from wpam_mj.infra.files import write_text_atomic
from wpam_mj.physics.params import apply_overrides, preset
from wpam_mj.errors import load_toml
from wpam_mj.units import MM


SINE_FREQS = (0.5, 1.0)  # Hz: §4.2's "frequency band above 0.5 Hz"
STALL_GAIN = 0.05  # a gain below this: the load hardly follows (our reading)


def _write_csv(path: Path, rows: list[dict]) -> None:
    write_text_atomic(path, csv_text(list(rows[0]), rows))


def sines(params, out: Path, dt: float) -> None:
    """The PI sines at the limit on every variant; prints the spreads across loads."""
    variants = {**VARIANTS, **line_grid()}
    rows = []
    for i, (name, overrides) in enumerate(variants.items()):
        print(f"  sines {i + 1}/{len(variants)}: {name}", flush=True)
        for freq in SINE_FREQS:
            for load in paper.LOADS_N:
                s = sine_at_the_limit(variant(params, overrides), load, freq, dt=dt)
                rows.append({"variant": name, "freq_hz": freq, "load_n": load,
                             "gain": s.gain, "lag_deg": s.lag_deg,
                             "po_at_floor": s.at_floor, "po_at_cap": s.at_cap,
                             "contraction_mm_s": s.contraction / MM,
                             "extension_mm_s": s.extension / MM,
                             "centre_below_target_mm": s.centre_offset / MM})
    _write_csv(out / "sines.csv", rows)
    print(f"{'variant':44s} " + " ".join(f"{'gain / lag spread ' + format(f, 'g') + ' Hz':>26s}"
                                         for f in SINE_FREQS) + "  heavier lags more")
    alike = heavier = stalled = 0
    for name in variants:
        cells, order, ok, stall = [], True, True, False
        for freq in SINE_FREQS:
            pts = [r for r in rows if r["variant"] == name and r["freq_hz"] == freq]
            gains = [r["gain"] for r in pts]
            lags = list(np.degrees(np.unwrap(np.radians([r["lag_deg"] for r in pts]))))
            if min(gains) < STALL_GAIN:  # the load hardly moves: its lag means nothing
                stall = True
                cells.append(f"stalls (gain {min(gains):.3f})")
                continue
            g, lag = max(gains) / min(gains) - 1.0, max(lags) - min(lags)
            ok &= g <= 0.05 and lag <= 5.0
            order &= lags == sorted(lags)
            cells.append(f"{100 * g:10.1f} % / {lag:6.1f} deg")
        alike += ok and not stall
        heavier += order and not stall
        stalled += stall
        print(f"{name:44s} " + " ".join(f"{c:>26s}" for c in cells)
              + f"  {'-' if stall else 'yes' if order else 'no'}")
    print(f"{alike} of {len(variants)} variants hold both sentences (gains within 5 % and "
          f"lags within 5 deg across loads at {' and '.join(map(str, SINE_FREQS))} Hz); "
          f"{stalled} stall; in {heavier} of the others the lag grows with load at "
          f"both; wrote {out / 'sines.csv'}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--config", help="TOML overrides of the shipped W-PAM")
    ap.add_argument("--out", default="out/limit_velocity", help="output folder")
    ap.add_argument("--dt", type=float, default=1e-3, help="physics step [s]")
    ap.add_argument("--sines", action="store_true",
                    help="also the PI sines at 0.5 and 1 Hz on every variant and line grid")
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
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    _write_csv(out / "limit_velocity.csv", rows)
    print(f"{'variant':44s} " + " ".join(f"{v:>14g} N" for v in paper.LOADS_N))
    for name in VARIANTS:
        cells = [r for r in rows if r["variant"] == name]
        print(f"{name:44s} " + " ".join(
            f"{r['contraction_mm_s']:6.0f}/{r['extension_mm_s']:<6.0f}  " for r in cells))
    print("(fastest contraction/extension [mm/s] under Po switched cap <-> floor, Pi at the "
          f"25 mm feedforward); wrote {out / 'limit_velocity.csv'}")
    if args.sines:
        sines(params, out, args.dt)


if __name__ == "__main__":
    main()
