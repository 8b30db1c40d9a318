"""Fit the simulator to measured experiments (`wpam fit`): replay, residuals, report.

Replay. Each experiment (`wpam_mj.fitting.measurements.Experiment`) runs through
`wpam_mj.simulation.simulate.simulate` on a grid of step dt from its first sample to its last. The
simulated rig starts at rest at its first inputs below (regulators settled on them,
chambers filled to them: `Drive.start_at_rest`), the state the rig was in when its log
began. (Filling vented chambers first would overshoot dP and leave the muscle
1-2 mm off where the friction catches it; holding the first pressures for a while would
let a muscle that the feedback was holding back creep off.) From the first sample on, what
drives it:

  * both commands recorded (pi_cmd_mpa, po_cmd_mpa): the commands, through the modelled
    regulators (dead time, lag, line restriction); this identifies the regulator and
    line parameters as well as the muscle;
  * otherwise: the measured regulator pressures, through an ideal regulator (no dead time,
    no lag: the measured outlet pressure is the set point), so the muscle and the lines
    are fitted but the regulators' own lag and dead time are not seen.

Feedback runs (x_ref recorded) are replayed open loop with the Po the controller
commanded (or, without commands, the Po measured): the fit identifies the muscle, not the
controller. A closed-loop replay would let the controller hide the muscle's errors (the
loop drives x to x_ref whatever the muscle parameters, so x would carry little
information about them) and would make the fit depend on the controller's gains. x_ref
is kept for the figures.

Commands and pressures are linearly interpolated from the samples onto the step grid;
the simulated x is interpolated back to the sample times. Residuals are x_sim - x_meas
in mm, every sample of every fitted file.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from wpam_mj.fitting import estimation
from wpam_mj.infra.budget import check_run
from wpam_mj.fitting.measurements import Experiment
from wpam_mj.simulation.context import DT_RANGE_S, RunContext, check_dt
from wpam_mj.physics.params import Params
from wpam_mj.errors import ParameterError
from wpam_mj.units import MM
from wpam_mj.infra.pool import open_workers
from wpam_mj.simulation.execution import SimulationTask, execute
from wpam_mj.simulation.results import SimResult
from wpam_mj.simulation.simulate import Drive, Run, simulate_run

# The rough first pass of `fit_data` replays at this multiple of dt (a 2 ms replay of
# 1 ms synthetic data biases the 7 default parameters by < 0.15 %). Both passes stop
# when an iteration lowers the cost by less than RELATIVE_COST_TOL of itself.
COARSE_DT_FACTOR = 2.0
RELATIVE_COST_TOL = 0.01


def replay_inputs(params: Params, exp: Experiment, dt: float) -> tuple[Params, Drive, np.ndarray]:
    """(params to simulate with, the drive, its time grid [s]) for `exp` (module doc)."""
    check_replay(exp, dt)
    n = int(np.floor((exp.time[-1] - exp.time[0]) / dt + 1e-9)) + 1
    grid = exp.time[0] + np.arange(n) * dt
    p_max = params.pneumatics.p_max
    if exp.has_commands:
        pi, po = exp.pi_cmd, exp.po_cmd
    else:
        pi, po = exp.pi, exp.po
        params = params.replace(pneumatics={"time_constant": 0.0, "dead_time": 0.0})
    pi, po = np.interp(grid, exp.time, pi), np.interp(grid, exp.time, po)
    pi_cmd, po_cmd = np.clip(pi, 0.0, p_max), np.clip(po, 0.0, p_max)
    if not params.outer_chamber:
        po_cmd = np.zeros(n)  # the bare RLAM: nothing for Po to fill
    return params, Drive(pi_cmd=pi_cmd, po_cmd=po_cmd, x_ref=np.full(n, np.nan),
                         start_at_rest=True), grid


def check_replay(exp: Experiment, dt: float) -> None:
    """A replay of `exp` at `dt` [s]: at least one step long (a run's two samples), within
    one run's budget (it records every step)."""
    if exp.duration < dt:
        raise ParameterError(f"{exp.path or exp.name}: its record spans {exp.duration:g} s, "
                             f"less than one step of its replay ({dt:g} s); a file needs at "
                             f"least {dt:g} s of samples")
    check_run(f"the replay of {exp.name}", exp.duration, dt, record_dt=dt)


def check_names(experiments: Sequence[Experiment]) -> None:
    """Every experiment once: a file's figure and RMS line are named after it, so the
    same file as data and hold-out, or two files of one name, would overwrite each other."""
    names = [e.name for e in experiments]
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise ParameterError(f"experiment {twice[0]!r} is given twice (as data and hold-out, "
                             "or two files of that name); each file's figure is named after "
                             "it: give each once, under its own name")


def replay(params: Params, exp: Experiment, dt: float = 1e-3, *,
           engine: str = "auto") -> np.ndarray:
    """Simulated contraction [m] at the sample times of `exp`."""
    task = ReplayTask(params, exp, check_dt(dt))
    return task.reduce([simulate_run(run, engine) for run in task.runs()])


@dataclass(frozen=True)
class ReplayTask(SimulationTask):
    """One replay (`replay`), a task of the execution layer."""

    params: Params
    experiment: Experiment
    dt: float

    @property
    def cost(self) -> float:
        return self.experiment.duration / self.dt

    def runs(self) -> list[Run]:
        """The replay at dt [s], which `replay` or `fit_data` checked."""
        p, drive, _ = replay_inputs(self.params, self.experiment, self.dt)
        return [Run.make(RunContext(p, self.dt, self.experiment.load, "open", self.dt), drive)]

    def reduce(self, results: list[SimResult]) -> np.ndarray:
        (r,) = results
        exp = self.experiment
        grid = exp.time[0] + np.arange(len(r.time)) * r.dt  # as `replay_inputs`
        return np.interp(exp.time, grid, r.x)


@dataclass(frozen=True)
class DataModel:
    """`estimation.ResidualModel` of measured experiments: x_sim - x_meas [mm]."""

    experiments: tuple[Experiment, ...]
    dt: float = 1e-3

    def tasks(self, params: Params) -> list[ReplayTask]:
        return [ReplayTask(params, e, self.dt) for e in self.experiments]

    def residuals(self, params: Params, results: list) -> np.ndarray:
        return np.concatenate([(x - e.x) / MM for x, e in zip(results, self.experiments)])


@dataclass(frozen=True)
class FileFit:
    """Measured against simulated for one file: x_sim [m] at the sample times, RMS [m]."""

    experiment: Experiment
    x_sim: np.ndarray
    held_out: bool

    @property
    def rms(self) -> float:
        return float(np.sqrt(np.mean((self.x_sim - self.experiment.x) ** 2)))

    def plot(self):
        """x against time and x against Pi, measured and simulated (`wpam_mj.fitting.figures`)."""
        from wpam_mj.fitting.figures import file_fit_figure  # noqa: PLC0415 (matplotlib)
        return file_fit_figure(self)

    def as_json(self) -> dict:
        return {"file": self.experiment.name, "load_n": self.experiment.load,
                "held_out": self.held_out, "rms_mm": self.rms / MM,
                "samples": int(self.experiment.time.size)}


@dataclass(frozen=True)
class DataFit:
    """A fit to measured data: the engine's result and every file replayed with it."""

    result: estimation.FitResult
    files: tuple[FileFit, ...]

    @property
    def params(self) -> Params:
        return self.result.params

    def rms(self, held_out: bool) -> float:
        """RMS of x_sim - x_meas over all samples of the fitted (or held-out) files [m];
        NaN when there are none."""
        errs = [f.x_sim - f.experiment.x for f in self.files if f.held_out == held_out]
        return float(np.sqrt(np.mean(np.concatenate(errs) ** 2))) if errs else float("nan")

    def as_json(self) -> dict:
        r = self.result
        return {"estimates": [e.as_json() for e in r.estimates],
                "correlation": r.correlation.tolist(),
                "files": [f.as_json() for f in self.files],
                "rms_fit_mm": self.rms(False) / MM,
                "rms_holdout_mm": None if np.isnan(self.rms(True)) else self.rms(True) / MM,
                "evaluations": r.nfev, "jacobians": r.njev, "message": r.message}


def fit_data(start: Params, experiments: Sequence[Experiment],
             free: Sequence[estimation.FreeParameter], *, holdout: Sequence[Experiment] = (),
             dt: float = 1e-3, jobs: int = 1, executor=None, max_nfev: int = 60,
             progress: bool = False) -> DataFit:
    """Fit `free` to `experiments` from `start`, then replay every file (fitted and
    held out) with the fitted parameters.

    Two passes (each a `estimation.fit`): a rough one on the open-loop experiments (no
    x_ref) at COARSE_DT_FACTOR x dt, stopped at RELATIVE_COST_TOL (their residuals
    change smoothly with the parameters, and the search from far away is most of the
    work), then every experiment at dt from there. Feedback runs replayed open loop are
    the roughest residuals: each slip moves with the parameters and shifts everything
    after it, so from far away they lead the search astray. Without open-loop
    experiments (or without feedback runs) the first pass is the whole fit's rough
    start on all of them.
    """
    if not experiments:
        raise ParameterError("no experiments to fit")
    dt = check_dt(dt)
    check_names((*experiments, *holdout))
    for e in (*experiments, *holdout):
        check_replay(e, dt)
    open_loop = [e for e in experiments if e.x_ref is None] or list(experiments)
    coarse = DataModel(tuple(open_loop), min(COARSE_DT_FACTOR * dt, DT_RANGE_S[1]))
    for e in coarse.experiments:
        check_replay(e, coarse.dt)
    model = DataModel(tuple(experiments), dt)
    everything = DataModel((*experiments, *holdout), dt)
    with open_workers(jobs if executor is None else executor) as ex:
        rough = estimation.fit(coarse, start, free, executor=ex, max_nfev=max_nfev,
                               ftol=RELATIVE_COST_TOL, xtol=1e-3, progress=progress)
        result = estimation.fit(model, rough.params, free, executor=ex, max_nfev=max_nfev,
                                ftol=RELATIVE_COST_TOL, xtol=1e-3, progress=progress)
        tasks = everything.tasks(result.params)
        x = execute(tasks, ex)
    files = tuple(FileFit(e, xs, i >= len(experiments))
                  for i, (e, xs) in enumerate(zip(everything.experiments, x)))
    return DataFit(result, files)


def params_toml(params: Params, base: Params, fit: DataFit | None = None,
                header: str = "") -> str:
    """TOML of every field of `params` that differs from `base` or was fitted (what
    `--config` needs on top of the same preset), estimates with 1-sigma as comments."""
    fitted = {e.name: e for e in fit.result.estimates} if fit else {}
    lines = [f"# {ln}" for ln in header.splitlines()] + ["# SI units.", ""]
    for section, values in params.as_dict().items():
        rows = []
        for key, v in values.items():
            name = f"{section}.{key}"
            if name in fitted or v != base.as_dict()[section][key]:
                note = f"  # +- {fitted[name].sigma:.3g} (1 sigma) {fitted[name].note}" \
                    if name in fitted else ""
                rows.append(f"{key} = {v!r}{note}".rstrip())
        if rows:
            lines += [f"[{section}]", *rows, ""]
    return "\n".join(lines)


def write_figures(fit: DataFit, folder: Path) -> list[Path]:
    """One PNG per file, `<file>.png` in `folder`."""
    from wpam_mj.experiments.figures import save_figure  # noqa: PLC0415 (matplotlib)
    return [save_figure(f.plot(), folder / f"{f.experiment.name}.png") for f in fit.files]
