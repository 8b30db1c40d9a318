"""How far a pull on the hung load moves it, and where the Po feedback brings it back: the
live rig of `wpam view` (`wpam_mj.visualisation.viewer.LiveRig`) holding a load at a
target while a force pulls it down for 1 s (README, "the interactive viewer").

    python scripts/pull_rejection.py [--load 100] [--target 20] [--pulls 120,130,200]

Prints, per pull and controller: the largest |x - x_r| during and just after the pull,
1.5 s after it, and before it (the over-contraction Po held back), in mm.
"""

from __future__ import annotations

import argparse

import numpy as np

import wpam_mj
from wpam_mj import paper
from wpam_mj.units import MM
from wpam_mj.visualisation.viewer import LiveRig

PULL_S = (2.0, 3.0)  # the pull's start and end [s]


def errors(params, load: float, target: float, force: float, control: str) -> tuple:
    rig = LiveRig(params, load, control, target)
    rows = []
    for k in range(1, 61):  # 6 s in 0.1 s frames, as the viewer advances
        rig.advance(k * 0.1, lambda t: -force if PULL_S[0] <= t < PULL_S[1] else 0.0)
        rows.append((rig.time, rig.x))
    t, x = np.array(rows).T
    e = np.abs(x - target) / MM
    return (e[(t > PULL_S[0]) & (t <= PULL_S[1] + 0.5)].max(),
            e[(t >= PULL_S[1] + 1.5) & (t < PULL_S[1] + 2.0)].max(),
            e[(t > PULL_S[0] - 0.5) & (t <= PULL_S[0])].max())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--load", type=float, default=100.0, help="load [N]")
    ap.add_argument("--target", type=float, default=20.0, help="held contraction [mm]")
    ap.add_argument("--pulls", default="120,130,200", help="pulls [N], comma-separated")
    a = ap.parse_args()
    base = wpam_mj.preset()
    cases = (("pi", base), ("pid", base),
             ("pi, 10x Ki", base.replace(controller={"ki": 10 * paper.KI})))
    print("| pull [N] | controller | during [mm] | 1.5 s after [mm] | before [mm] |")
    print("|---|---|---|---|---|")
    for force in (float(f) for f in a.pulls.split(",")):
        for name, params in cases:
            control = "pid" if name == "pid" else "pi"
            d, after, before = errors(params, a.load, a.target * MM, force, control)
            print(f"| {force:g} | {name} | {d:.2f} | {after:.2f} | {before:.2f} |")


if __name__ == "__main__":
    main()
