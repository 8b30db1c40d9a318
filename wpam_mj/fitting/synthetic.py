"""Synthetic measurements (`wpam synth`): simulator runs written in the measurement
format of `wpam_mj.fitting.measurements`, with optional Gaussian sensor noise.

For each load (default the paper's 50/100/150 N): an open-loop static ramp with Po =
0.04 MPa while Pi falls (paper Fig. 9: Po rising 0, then the outer chamber pressed) and a
PI staircase (paper §4.1), plus, in a `holdout/` subfolder, a PI sine run (25 mm about
25 mm at 0.25 Hz, paper §4.2) to validate a fit on an experiment of another kind. Each
run is sampled every `sample_dt` like a rig's logger: the regulator gauges (pi_mpa,
po_mpa) and x with noise, the commands (pi_cmd_mpa, po_cmd_mpa, and x_ref_mm for the
feedback runs) exactly, as a controller logs what it sent.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from wpam_mj import paper
from wpam_mj.experiments.drives import STATIC_RAMP_S, SineSpec, sine_run, static_loop, step_run
from wpam_mj.fitting.measurements import Experiment
from wpam_mj.simulation.context import check_dt, check_load
from wpam_mj.physics.params import Params
from wpam_mj.errors import ParameterError, check_int, check_range
from wpam_mj.units import MM, MPA
from wpam_mj.simulation.results import SimResult
from wpam_mj.simulation.execution import execute

HOLDOUT_FREQ_HZ = 0.25  # the sine run of the held-out set
HOLDOUT_DIR = "holdout"
KINDS = ("static", "step", "sine")
# The logger's sample period: the controller's own 1 kHz. Feedback runs are replayed
# open loop from the logged Po command (`wpam_mj.fitting.measured_fit`), which the PI changes every
# step: logged every 10 ms the replayed step runs drift by 0.08 mm RMS, every 2 ms by
# 0.009 mm, every 1 ms they replay exactly.
SAMPLE_DT = 0.001
SEED_MAX = 2**63 - 1  # numpy's generators take any non-negative integer; bound it


@dataclass(frozen=True)
class SynthTask:
    """One simulated experiment: kind "static", "step" or "sine" at `load` [N], sampled
    every `sample_dt` [s]; `ramp_time` [s] of the static ramps (each way)."""

    params: Params
    kind: str
    load: float
    dt: float
    sample_dt: float
    ramp_time: float = STATIC_RAMP_S

    @property
    def name(self) -> str:
        return f"{self.kind}_{self.load:g}N"

    @property
    def cost(self) -> float:
        seconds = {"static": 2.0 * self.ramp_time, "step": len(paper.STEP_LEVELS_MM)
                   * paper.STEP_HOLD_S, "sine": SineSpec(HOLDOUT_FREQ_HZ).duration}
        return seconds[self.kind] / self.dt

    def run(self) -> SimResult:
        p, load, dt, rec = self.params, self.load, self.dt, self.sample_dt
        if self.kind == "static":
            return static_loop(p, load, po_down=paper.PO_DOWN_STATIC_MPA * MPA,
                               ramp_time=self.ramp_time, dt=dt, record_dt=rec)
        if self.kind == "step":
            return step_run(p, load, "pi", dt=dt, record_dt=rec)
        return sine_run(p, load, "pi", SineSpec(HOLDOUT_FREQ_HZ), dt=dt, record_dt=rec)


def measured(r: SimResult, name: str, rng: np.random.Generator, noise_x: float,
             noise_p: float) -> Experiment:
    """What a rig would log of run `r`: gauges and x with Gaussian noise of standard
    deviation noise_x [m] and noise_p [Pa], commands exact (module docstring)."""
    n = len(r.time)
    feedback = bool(np.any(np.isfinite(r.x_ref)))
    # draw in a fixed order (x, pi, po) so a seed gives the same files
    x = r.x + noise_x * rng.standard_normal(n)
    pi = r.pi_reg + noise_p * rng.standard_normal(n)
    po = r.po_reg + noise_p * rng.standard_normal(n)
    return Experiment(name=name, load=r.load, time=r.time, pi=pi, po=po, x=x,
                      pi_cmd=r.pi_cmd, po_cmd=r.po_cmd, x_ref=r.x_ref if feedback else None)


def synth(params: Params, out: Path, *, loads: Sequence[float] = paper.LOADS_N,
          noise_mm: float = 0.05, noise_kpa: float = 1.0, seed: int = 0,
          sample_dt: float = SAMPLE_DT, dt: float = 1e-3, kinds: Sequence[str] = KINDS,
          ramp_time: float = STATIC_RAMP_S, jobs: int = 1,
          progress: bool = False) -> list[Path]:
    """Write the synthetic experiments (module docstring) into `out`; returns the paths.
    noise_mm [mm] and noise_kpa [kPa]: standard deviations of the x and gauge noise;
    seed: of the noise; sample_dt: logger period [s]; dt: physics step [s]; kinds: a
    subset of KINDS."""
    loads = tuple(check_load(v) for v in loads)
    dt = check_dt(dt)
    noise_x = check_range("--noise-mm", noise_mm, 0.0, 10.0, "mm") * MM
    noise_p = check_range("--noise-kpa", noise_kpa, 0.0, 100.0, "kPa") * 1e3
    seed = check_int("--seed", seed, 0, SEED_MAX)
    unknown = set(kinds) - set(KINDS)
    if unknown:
        raise ParameterError(f"unknown experiment kind(s) {sorted(unknown)}; valid: "
                             f"{', '.join(KINDS)}")
    tasks = [SynthTask(params, kind, load, dt, sample_dt, ramp_time)
             for kind in kinds for load in loads]
    runs = execute(tasks, jobs, progress=progress, desc="synth")
    rng = np.random.default_rng(seed)
    paths = []
    for task, r in zip(tasks, runs):
        folder = out / HOLDOUT_DIR if task.kind == "sine" else out
        exp = measured(r, task.name, rng, noise_x, noise_p)
        paths.append(exp.to_csv(folder / f"{task.name}.csv"))
    return paths
