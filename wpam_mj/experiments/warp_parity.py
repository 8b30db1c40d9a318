"""The Warp backend against the compiled plugin: the runs both make and how far apart they
end (docs/warp.md, "Parity"). tests/test_warp.py holds the gaps to their tolerances on
the device it is given; `benchmarks/warp_parity.py` prints them for any device.

Every preset and control mode at 100 N follows a staircase of 20, 8 and 25 mm over 3 s at
dt = 1 ms from rest: a rise, a fall that the dry friction holds, then a slip, a rise.
"""

from __future__ import annotations

import numpy as np

from wpam_mj.experiments.drives import drive_for_targets, step_targets
from wpam_mj.physics.params import preset
from wpam_mj.simulation.context import RunContext
from wpam_mj.simulation.simulate import Run

# float32 tolerances of the Warp backend against the float64 plugin over PARITY_S
# (measured on Warp's CPU device: x 1.5e-7 m, Pi 0.52 Pa, Po 0.27 Pa, tension 1.6 mN,
# friction level 0.4 mN)
TOLERANCE = {"x": 5e-7, "pi": 2.0, "po": 2.0, "tension": 5e-3, "friction": 2e-3}
STUCK_M_S = 1e-5  # |dx/dt| below this: the load sticks [m/s]
STUCK_ALIKE = 0.99  # the least share of samples both must stick or slide at together
PARITY_S = 3.0
LEVELS_MM = (20, 8, 25)  # a rise, a fall the friction holds, a rise
CASES = [("wpam", c) for c in ("open", "pi", "pid", "pi_ff")] + [
    ("rlam", "open"), ("mckibben", "open")]


def parity_runs(params_of=preset) -> list[Run]:
    """One run per CASES entry (`params_of(preset name)` its plant), recorded every 10 ms."""
    dt = 1e-3
    t = np.arange(round(PARITY_S / dt)) * dt
    x_ref = step_targets(t, LEVELS_MM, hold=PARITY_S / len(LEVELS_MM))
    return [Run.make(RunContext(params_of(name), dt, 100.0, control, 0.01),
                     drive_for_targets(params_of(name), 100.0, x_ref, control, dt))
            for name, control in CASES]


def gaps(reference, got) -> dict[str, float]:
    """The largest gap over the run of every TOLERANCE field, the share of samples both
    stick (or both slide) at, and how many the reference sticks at."""
    out = {field: float(np.max(np.abs(getattr(got, field) - getattr(reference, field))))
           for field in TOLERANCE}
    stuck_ref = np.abs(reference.velocity) < STUCK_M_S
    out["stuck_alike"] = float(np.mean(stuck_ref == (np.abs(got.velocity) < STUCK_M_S)))
    out["stuck"] = int(np.sum(stuck_ref))
    return out


def within(g: dict[str, float]) -> list[str]:
    """The fields of `gaps` outside their tolerance (empty: the run follows the plugin)."""
    return [f"{field} {g[field]:g} > {tol:g}" for field, tol in TOLERANCE.items()
            if not g[field] <= tol] + ([f"stuck alike {g['stuck_alike']:.3f} < {STUCK_ALIKE}"]
                                       if g["stuck_alike"] < STUCK_ALIKE else [])
