"""The global search of the credible box, as `wpam search` (a thin wrapper for background runs).

    nice -n 10 python scripts/global_search.py --out out/search --seed 20 [--resume]
        [--objective checks]

Journals every point to OUT/journal.jsonl (resumable), prints progress with the time
left, and writes OUT/best.toml, best.txt, convergence.csv, convergence.png,
feasibility.md and feasibility.png.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from wpam_mj.reproduction import search, search_outputs


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path("out") / "search")
    ap.add_argument("--seed", type=int, default=20)
    ap.add_argument("--popsize", type=int, default=search.POPSIZE)
    ap.add_argument("--maxiter", type=int, default=search.MAXITER)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--resume", action="store_true")
    ap.add_argument("--objective", choices=tuple(search.OBJECTIVES), default="cost")
    a = ap.parse_args()
    for path in search_outputs.write_search(a.out, seed=a.seed, popsize=a.popsize,
                                            maxiter=a.maxiter, jobs=a.jobs, resume=a.resume,
                                            objective=a.objective):
        print(f"wrote {path}")


if __name__ == "__main__":
    main()
