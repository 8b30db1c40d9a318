"""Write the parameter table of models/README.md from wpam_mj.physics.params (the one source).

    python scripts/param_table.py          # rewrite the table between its markers
    python scripts/param_table.py --check  # exit 1 if the file's table is stale

Each row: the parameter as `section.field` (the `--config` TOML name), its shipped value,
unit, plausible range for the paper's W-PAM (the calibration bounds; blank where the value
is given, not fitted) and source.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

from wpam_mj.physics.params import describe_with_ranges, preset

README = Path(__file__).resolve().parent.parent / "models" / "README.md"
BEGIN, END = "<!-- parameter table: scripts/param_table.py -->", "<!-- end of table -->"


def _num(value: float, unit: str) -> str:
    if unit == "rad":
        return f"{value:.4g} ({math.degrees(value):.1f} deg)"
    return f"{value:.4g}"


AT_BOUND = 0.01  # within this share of its range of a bound: "at the bound"


def at_bound(value: float, plausible: tuple[float, float] | None) -> str | None:
    """"lower" or "upper" when `value` sits at that end of its plausible range."""
    if plausible is None:
        return None
    lo, hi = plausible
    if value <= lo + AT_BOUND * (hi - lo):
        return "lower"
    return "upper" if value >= hi - AT_BOUND * (hi - lo) else None


def table() -> str:
    rows = ["| parameter | value | unit | plausible range | source |", "|---|---|---|---|---|"]
    for name, value, unit, plausible, source in describe_with_ranges(preset("wpam")):
        rng = "" if plausible is None else \
            f"{_num(plausible[0], unit)} – {_num(plausible[1], unit)}"
        end = at_bound(value, plausible)
        mark = f" **(at the {end} bound)**" if end else ""
        rows.append(f"| `{name}` | {_num(value, unit)}{mark} | {unit} | {rng} | {source} |")
    return "\n".join(rows)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="only check, do not write")
    args = parser.parse_args()
    text = README.read_text()
    head, rest = text.split(BEGIN, 1)
    _, tail = rest.split(END, 1)
    new = f"{head}{BEGIN}\n{table()}\n{END}{tail}"
    if args.check:
        if new != text:
            print(f"{README} parameter table is stale: run scripts/param_table.py",
                  file=sys.stderr)
            return 1
        return 0
    README.write_text(new)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
