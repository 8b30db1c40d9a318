"""The PI policy of the environment at its 10 ms control step: how close each gain set
brings the shipped muscle to a step target in a 10 s episode (the target: within 0.5 mm).

Per gain set (Kp, Ki in controller units per mm, as `Controller` reads them) and per
(target, load): |x - x_r| at the end of the episode and the peak-to-peak motion over its
last 3 s (stick-slip hunting shows there), with `PIControl.for_run` as the policy, started
as `simulate` starts it. The README's Gymnasium example and tests/test_env.py use the
outcome. About 2 s per gain set.

Usage: python scripts/env_pi_gains.py [KP,KI ...]   (default: the paper's, and Ki x 10)
"""

import sys

import numpy as np

from wpam_mj import paper, preset
from wpam_mj.control.controllers import PIControl
from wpam_mj.environments.dm_env_task import make_env
from wpam_mj.units import MM

CASES = ((20 * MM, 100.0), (40 * MM, 50.0), (30 * MM, 150.0), (10 * MM, 150.0),
         (45 * MM, 100.0))


def episode(params, target: float, load: float) -> tuple[float, float]:
    """(final |error| [m], peak to peak of x over the last 3 s [m])."""
    env = make_env(params, target=target, load=load, time_limit=10.0, seed=0)
    ts = env.reset()
    policy = PIControl.for_run(params, env.control_timestep())
    xs = []
    while not ts.last():
        o = ts.observation
        ts = env.step([policy.update(o["x_m"][0], o["target_m"][0])])
        xs.append(ts.observation["x_m"][0])
    xs = np.array(xs)
    return abs(xs[-1] - target), float(np.ptp(xs[-300:]))


def main(argv: list[str]) -> int:
    gains = [tuple(float(v) for v in g.split(",")) for g in argv] or \
        [(paper.KP, paper.KI), (paper.KP, 10 * paper.KI)]
    print("| Kp | Ki | target [mm] | load [N] | final error [mm] | last 3 s peak to peak [mm] |")
    print("|---|---|---|---|---|---|")
    for kp, ki in gains:
        params = preset().replace(controller={"kp": kp, "ki": ki})
        for target, load in CASES:
            err, ptp = episode(params, target, load)
            print(f"| {kp:g} | {ki:g} | {target / MM:g} | {load:g} | {err / MM:.3f} | "
                  f"{ptp / MM:.3f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
