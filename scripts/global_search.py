"""Issue 20's global search: DE over the credible box and the protocol readings.

    nice -n 10 python scripts/global_search.py --out out/search [--resume]

Journals every point to OUT/journal.jsonl (resumable), prints progress with the time
left, and writes OUT/best.txt; `wpam feasibility OUT` turns the journal into the map.
Same as `wpam search --out OUT`.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

from wpam_mj import search


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path("out") / "search")
    ap.add_argument("--seed", type=int, default=20)
    ap.add_argument("--popsize", type=int, default=2)
    ap.add_argument("--maxiter", type=int, default=3)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--resume", action="store_true")
    a = ap.parse_args()
    load0 = os.getloadavg()
    r = search.search(a.out, seed=a.seed, popsize=a.popsize, maxiter=a.maxiter,
                      jobs=a.jobs, resume=a.resume)
    text = (f"{r.evaluations} points in {r.seconds / 60:.1f} min "
            f"(load average at start {load0[0]:.2f}, at end {os.getloadavg()[0]:.2f}; "
            f"{time.strftime('%Y-%m-%d %H:%M')}); {r.message}\n"
            f"best cost {r.best.cost:.4f}, findings held {r.best.held} of "
            f"{len(search.FINDINGS)}\n" + search.describe_point(r.best.u, search.preset("wpam"))
            + f"\nmargins {r.best.margins}\nfigures {r.best.figures}\n")
    (a.out / "best.txt").write_text(text)
    print(text)


if __name__ == "__main__":
    main()
