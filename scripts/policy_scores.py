"""Mean episode return of the reference policies on each registered id (action "po").

    python scripts/policy_scores.py [--seeds 10]

Constant Po at the regulator minimum (the Pi feedforward alone), random actions and the
paper's PI on Po (`wpam_mj.environments.policies`), each over the seeds 0..N-1; the ratio is the
constant policy's score over the PI's. docs/learning.md quotes its output.
"""

from __future__ import annotations

import argparse
import time

import wpam_mj  # noqa: F401 (registers the ids)
from wpam_mj.environments.policies import POLICIES, mean_return
from wpam_mj.environments.registry import VARIANTS


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=10)
    args = parser.parse_args()
    seeds = range(args.seeds)
    print(f"{'id':32s} " + " ".join(f"{p:>9s}" for p in POLICIES) + "  const/PI")
    for env_id, kwargs in VARIANTS.items():
        if kwargs.get("action", "po") != "po":
            continue
        start = time.perf_counter()
        scores = {p: mean_return(env_id, p, seeds) for p in POLICIES}
        print(f"{env_id:32s} " + " ".join(f"{scores[p]:9.1f}" for p in POLICIES)
              + f"  {scores['constant'] / scores['pi']:8.3f}"
              f"  ({time.perf_counter() - start:.0f} s)", flush=True)


if __name__ == "__main__":
    main()
