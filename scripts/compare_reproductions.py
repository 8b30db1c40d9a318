"""Compare two `wpam reproduce` output folders: Table 2 cells, sweep gains, lags and Po
maxima, and the step runs' plateau means (the last 3 s of each 10 s plateau).

    python scripts/compare_reproductions.py OLD_DIR NEW_DIR

Used to check that a new engine reproduces an old one's figures (the plugin against the
compiled loop it replaced: the closing note of that change quotes this script's output).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from wpam_mj.experiments.drives import STEP_HOLD_S

SETTLED_S = 3.0  # the end of each plateau averaged [s]


def _step_csv(path: Path) -> dict[str, np.ndarray]:
    lines = [line for line in path.read_text().splitlines() if not line.startswith("#")]
    header = lines[0].split(",")
    data = np.array([[float(v) for v in line.split(",")] for line in lines[1:]])
    return dict(zip(header, data.T))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("old", type=Path)
    parser.add_argument("new", type=Path)
    args = parser.parse_args()
    old_t2, new_t2 = (json.loads((d / "table2.json").read_text()) for d in (args.old, args.new))
    for row in ("open_po", "feedback"):
        for load, value in old_t2[row].items():
            print(f"Table 2 {row} {load} N: {value:.5f} -> {new_t2[row][load]:.5f} "
                  f"({(new_t2[row][load] / value - 1) * 100:+.3f} %)")
    key = ("load_n", "freq_hz", "controller")
    old_sw, new_sw = ({tuple(r[k] for k in key): r for r in json.loads((d / "sweep.json")
                                                                         .read_text())}
                      for d in (args.old, args.new))
    gain = max(abs(new_sw[k]["gain"] / r["gain"] - 1) for k, r in old_sw.items())
    lag = max(abs(new_sw[k]["phase_lag_deg"] - r["phase_lag_deg"]) for k, r in old_sw.items())
    po = max(abs(new_sw[k]["po_max_mpa"] - r["po_max_mpa"]) for k, r in old_sw.items())
    print(f"sweep, {len(old_sw)} points: gains within {gain * 100:.3f} %, lags within "
          f"{lag:.3f} deg, Po maxima within {po * 1e3:.3f} kPa")
    for old_csv in sorted((args.old / "data").glob("step_*.csv")):
        a, b = _step_csv(old_csv), _step_csv(args.new / "data" / old_csv.name)
        n = round(a["time_s"][-1] / STEP_HOLD_S)
        diffs = []
        for k in range(n):
            window = ((a["time_s"] >= (k + 1) * STEP_HOLD_S - SETTLED_S)
                      & (a["time_s"] < (k + 1) * STEP_HOLD_S))
            diffs.append(abs(a["x_mm"][window].mean() - b["x_mm"][window].mean()))
        print(f"{old_csv.name}: plateau means within {max(diffs):.4f} mm")


if __name__ == "__main__":
    main()
