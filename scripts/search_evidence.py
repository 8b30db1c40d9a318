"""What the searches' journals say together: per journal and pooled, the points that track
their steps, those whose PI steps settle, the most of `wpam reproduce`'s checks met at all
and with settled steps (and what that point misses), and each finding's best margin with
every other finding held (docs/physics.md, "Where the physics cannot reach the paper");
with --figure, their convergence on one yardstick, the checks' summed shortfall
(`search_scoring.shortfall`, whatever objective each search minimised), and the most checks met;
with --map, the feasibility map of all their points together.

    python scripts/search_evidence.py out/search-20 out/search-21 ... \
        [--figure convergence.png] [--map feasibility.png]
"""

from __future__ import annotations

import argparse
from pathlib import Path

from wpam_mj.reproduction import findings_map, search, search_scoring


def _line(name: str, records: list) -> str:
    tracking = [r for r in records if r.tracks]
    settled, most_settled, missed = findings_map.held_with(records, "steps_settle")
    most = max((r.held for r in tracking), default=0)
    return (f"| {name} | {len(records)} | {len(tracking)} | {most} | {settled} | "
            f"{most_settled} | {', '.join(missed) or '-'} |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("dirs", type=Path, nargs="+", help="folders holding a journal.jsonl")
    ap.add_argument("--figure", type=Path, help="convergence of every journal (PNG)")
    ap.add_argument("--map", type=Path, help="feasibility map of the pooled points (PNG)")
    a = ap.parse_args()
    runs = {d.name: search.load_records(d) for d in a.dirs}
    pooled = [r for rs in runs.values() for r in rs]
    print("| search | points | tracking | most checks met | PI steps settle | most met "
          "with settled steps | that point misses |\n|---|---|---|---|---|---|---|")
    for name, records in [*runs.items(), ("all", pooled)]:
        print(_line(name, records))
    print()
    print(findings_map.rest_verdict(pooled))
    if a.figure:
        conv = {name: search.convergence(rs, "checks") for name, rs in runs.items()}
        findings_map.convergence_figure(
            conv, a.figure, f"Convergence of {len(runs)} searches ({len(pooled)} points)",
            search_scoring.OBJECTIVE_TEXT["checks"])
        print(f"wrote {a.figure}")
    if a.map:
        pm = findings_map.pair_margins(pooled)
        print("\n" + findings_map.verdict(pm))
        findings_map.figure(pm, a.map, f"Feasibility of the paper's findings: {len(pooled)} "
                            f"points of {len(runs)} searches")
        print(f"wrote {a.map}")


if __name__ == "__main__":
    main()
