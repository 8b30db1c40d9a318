"""What every `wpam` command shares once its arguments are read: the validated run
options, parameters and protocol readings, output folders and files, the run's id and
manifest, and what it prints."""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path
from typing import Sequence

from wpam_mj.cli.arguments import GAIN_READINGS, JOBS_PER_CPU
from wpam_mj.experiments.drives import SINE_MEAN_MM
from wpam_mj.experiments.feasibility import check_liftable
from wpam_mj.experiments.paper_studies import RAMP_TIME_RANGE_S
from wpam_mj.experiments.protocol import SHIPPED, Protocol
from wpam_mj.infra import outputs, pool
from wpam_mj.physics.params import Params, apply_overrides, preset
from wpam_mj.errors import ParameterError, check_range, load_toml
from wpam_mj.units import MM, MPA
from wpam_mj.simulation.context import check_dt, check_load

RECORD_DT_S = 0.01  # the period every run records at (`wpam_mj.simulation.simulate.simulate`)


class RunFailed(Exception):
    """The command could not complete (e.g. no OpenGL): exit status 1."""


@dataclasses.dataclass(frozen=True)
class RunOptions:
    """Options shared by every command, validated."""

    params: Params
    dt: float
    jobs: int
    progress: bool

    def jobs_for(self, tasks: int) -> int:
        """Worker processes for `tasks` runs: no more than there are runs."""
        return max(1, min(self.jobs, tasks))


def params_of(args: argparse.Namespace, name: str | None = None) -> Params:
    """The preset `name` (default --preset) with the --config overrides applied."""
    params = preset(name or args.preset)
    if args.config is not None:
        overrides = load_toml(args.config)  # its errors name the file
        try:
            params = apply_overrides(params, overrides)
        except (TypeError, ValueError) as err:  # ParameterError, or a wrongly typed value
            raise ParameterError(f"--config {args.config}: {err}") from None
    return params


def jobs_option(jobs: int) -> int:
    """--jobs: 1 to JOBS_PER_CPU per CPU (more only costs memory: every run is one task)."""
    jobs = pool.check_jobs(jobs)
    most = JOBS_PER_CPU * pool.default_jobs()
    if jobs > most:
        raise ParameterError(f"--jobs {jobs} is outside the allowed range [1, {most}] "
                             f"({JOBS_PER_CPU} per CPU)")
    return jobs


def run_options(args: argparse.Namespace) -> RunOptions:
    params = params_of(args)
    dt = check_dt(args.dt, divides=RECORD_DT_S, name="--dt")
    for option in ("ramp_time", "calibration_ramp_time"):  # where the command takes them
        if getattr(args, option, None) is not None:
            check_range("--" + option.replace("_", "-"), getattr(args, option),
                        *RAMP_TIME_RANGE_S, "s")
    jobs = jobs_option(args.jobs)
    progress = sys.stderr.isatty() if args.progress is None else args.progress
    return RunOptions(params, dt, jobs, progress)


def controller_model_of(args: argparse.Namespace, run: RunOptions,
                        protocol: Protocol = SHIPPED) -> tuple[Params, tuple]:
    """`run.params` with the controller's equilibrium model --feedforward-model asks for,
    and the open-loop ramps a calibration ran on the plant (none for "nominal")."""
    if args.feedforward_model == "nominal":
        return run.params, ()
    from wpam_mj.reproduction.feedforward_fit import calibrate_one  # noqa: PLC0415
    fit = calibrate_one(run.params, protocol, run.dt, run.jobs_for(6), run.progress,
                        args.calibration_ramp_time)
    return fit.params, fit.loops


def controller_model_settings(args: argparse.Namespace) -> dict:
    """The manifest settings of --feedforward-model and --calibration-ramp-time."""
    return {"feedforward_model": args.feedforward_model,
            "calibration_ramp_time_s": args.calibration_ramp_time}


def protocol_of(args: argparse.Namespace, params: Params) -> tuple[Params, Protocol]:
    """The parameters with the controller's readings of --po-feedforward,
    --feedforward-friction and --gain-reading, and the static ramps' `Protocol`."""
    readings = {"controller.po_feedforward": None if args.po_feedforward is None
                else args.po_feedforward * MPA,
                "controller.feedforward_friction": args.feedforward_friction,
                "controller.command_scale": GAIN_READINGS.get(args.gain_reading)}
    params = params.with_values({k: v for k, v in readings.items() if v is not None})
    given = {"ramp_top": args.ramp_top, "ramp_time": args.ramp_time,
             "top_hold": args.top_hold, "loop_method": args.loop_area}
    return params, dataclasses.replace(SHIPPED, **{k: v for k, v in given.items()
                                                   if v is not None})


def protocol_settings(protocol: Protocol) -> dict:
    return {"ramp_top_mpa": protocol.ramp_top / MPA, "ramp_time_s": protocol.ramp_time,
            "top_hold_s": protocol.top_hold, "loop_area": protocol.loop_method}


def writable_dir(path: Path) -> Path:
    """Create `path` if needed, make sure files can be written in it, and hold it for this
    command alone (`wpam_mj.infra.outputs`: removed again if the command fails unused)."""
    return outputs.claim(path)


def out_dir_of(args: argparse.Namespace) -> Path:
    return writable_dir(args.out if args.out is not None else Path("out") / args.command)


def out_file(path: Path) -> Path:
    if path.is_dir():
        raise ParameterError(f"--out {path} is a folder; give a file name")
    writable_dir(path.parent)
    return path


def output_modules():
    """`tables` and `writers` (matplotlib): imported only by commands that write
    figures, so that --help and argument errors stay quick."""
    from wpam_mj.experiments import tables
    from wpam_mj.experiments import writers  # noqa: PLC0415
    return tables, writers


def liftable_loads(values: Sequence[float], params_list: Sequence[Params],
           name: str = "--load") -> tuple[float, ...]:
    """Loads [N] in range that every parameter set lifts to the top target (50 mm)."""
    loads = tuple(check_load(v) for v in values)
    for params in params_list:
        check_liftable(params, loads, name)
    return loads


def print_json(obj) -> None:
    print(json.dumps(obj, indent=2))


def wrote(paths: Sequence[Path]) -> None:
    for p in paths:
        print(f"wrote {p}")


def run_id_of(args: argparse.Namespace, params: Params, settings: dict) -> str:
    """The id of this run (`wpam_mj.infra.manifest.run_id`): only result-defining settings."""
    from wpam_mj.infra import manifest  # noqa: PLC0415
    return manifest.run_id(args.command, params, settings)


def write_run_manifest(args: argparse.Namespace, out: Path, rid: str, params: Params,
                       settings: dict, files) -> Path:
    """Write the run's manifest beside its files (`wpam_mj.infra.manifest.write_manifest`)."""
    from wpam_mj.infra import manifest  # noqa: PLC0415
    path = manifest.write_manifest(out, rid, args.command, params, files, settings=settings,
                                   argv=getattr(args, "argv", None))
    others = manifest.mark_overwritten(out, rid)
    if others:
        print(f"note: this run rewrote files that {', '.join(p.name for p in others)} listed "
              "(marked there as overwritten by this run)", file=sys.stderr)
    return path


def note_still_loads(what: Sequence[tuple[str, bool]], to_stderr: bool) -> None:
    """One line for each run (or group of runs) whose load never moved (its numbers mean
    nothing)."""
    from wpam_mj.experiments.feasibility import MOVE_MIN_MM  # noqa: PLC0415
    for name, moved in what:
        if not moved:
            print(f"note: {name}: the load never moved (x spanned < {MOVE_MIN_MM:g} mm); "
                  "its numbers mean nothing",
                  file=sys.stderr if to_stderr else sys.stdout)


UNSETTLED_PP_MM = 1.0  # our choice: a tenth of the staircase's 10 mm step


def settled(run) -> bool:
    """Whether a step run (`StepRun`) came to rest on its plateaus: x moves less than
    `UNSETTLED_PP_MM` peak to peak over the window its plateau means average."""
    return run.worst_peak_to_peak(run.settle) / MM < UNSETTLED_PP_MM


def flag_unsettled(name: str, run, to_stderr: bool) -> None:
    """One line for a step run that never settled (a limit cycle): its plateau means are
    averages of an oscillation, not settled values."""
    if not settled(run):
        print(f"note: {name}: x never settled on its plateaus (it still moves "
              f"{run.worst_peak_to_peak(run.settle) / MM:.3g} mm peak to peak over the last "
              f"{run.settle:g} s of one; at least {UNSETTLED_PP_MM:g} mm: a limit cycle); its "
              "plateau means are averages of that oscillation",
              file=sys.stderr if to_stderr else sys.stdout)


def amplitude_m(name: str, mm: float) -> float:
    """A sine amplitude [m] from mm: the target must stay at or above 0 mm."""
    return check_range(name, mm, 0.0, SINE_MEAN_MM, "mm", lo_open=True) * MM
