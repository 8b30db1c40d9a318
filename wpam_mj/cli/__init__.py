"""`wpam`: the paper's experiments from the command line.

Subcommands (each has --help):
  static     open-loop Pi ramp up and down (paper Figs. 3, 8, 9)
  step       staircase target 0 -> 50 -> 0 mm (Figs. 12-15)
  table2     hysteresis-loop areas of Table 2, beside the paper's
  sweep      frequency response to a sinusoidal target (Figs. 17-19)
  reproduce  all of the above into one folder with report.md
  calibrate  fit the parameters the paper does not give
  search     global search of the credible box and the protocol readings, and the
             feasibility map of the paper's findings (issue 20)
  fit        fit the parameters to your own measured experiments (CSV)
  synth      synthetic measurements in that CSV format
  render     offscreen video of a simulated run
  view       MuJoCo's interactive viewer on the muscle, stepped live (needs a display)
  linear     the paper's §3 linear model beside the simulated frequency response
  study      a design-space study from a study file, on local processes or Dask

Units at this edge: loads in N, pressures in MPa, lengths in mm, times in s, frequencies
in Hz (the library is SI inside). Exit status: 0 success, 1 the run failed (simulation
diverged, rendering or file system error), 2 bad arguments (one line on stderr), 130
interrupted (Ctrl-C), 143 terminated (SIGTERM), 129 hung up (SIGHUP), 141 stdout closed
early (e.g. `| head`).
static, step, table2, sweep, linear, reproduce and render write `manifest-<run id>.json`
beside their files (`wpam_mj.infra.manifest`).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import sys
import time
from concurrent.futures import BrokenExecutor
from pathlib import Path
from typing import Sequence

from wpam_mj import paper
from wpam_mj.version import __version__
from wpam_mj.physics.muscle_types import COMPARED_TYPES
from wpam_mj.reproduction import findings
from wpam_mj.infra import outputs
from wpam_mj.infra import pool
from wpam_mj.experiments import studies
from wpam_mj.infra.budget import check_video
from wpam_mj.experiments.feasibility import check_liftable, load_moved
from wpam_mj.control.controllers import CONTROLS, check_control
from wpam_mj.experiments.drives import (EXPERIMENTS, SINE_AMPLITUDE_MM, SINE_MEAN_MM, STATIC_RAMP_S,
                                 SineSpec, check_po, simulate_for_render)
from wpam_mj.simulation.model import check_dt, check_load
from wpam_mj.physics.params import (MM, MPA, PRESETS, ParameterError, Params,
                            apply_overrides, check_range, describe, load_toml, preset)
from wpam_mj.experiments.protocol import LOOP_METHODS, SHIPPED, Protocol, remeasure
from wpam_mj.simulation.results import write_text_atomic
from wpam_mj.simulation.simulate import SimulationDiverged
from wpam_mj.infra.streams import reopen_closed
from wpam_mj.infra.termination import Interrupted, exit_now, handle_signals, stopped_by_signal

RECORD_DT_S = 0.01  # the period every run records at (`wpam_mj.simulation.simulate.simulate`)
# --gain-reading: controller.command_scale [MPa/u] (docs/physics.md, the unitless gains)
GAIN_READINGS = {"mpa-per-mm": 1.0, "volts-5": 0.1, "volts-10": 0.05}
JOBS_PER_CPU = 4  # --jobs above this many per CPU is refused: no run gains from it


class UsageError(Exception):
    """Bad command-line arguments: exit status 2."""


class RunFailed(Exception):
    """The command could not complete (e.g. no OpenGL): exit status 1."""


class _Parser(argparse.ArgumentParser):
    """Reports errors as one line through `main` instead of usage text + SystemExit."""

    def error(self, message: str):  # type: ignore[override]
        raise UsageError(message)


# ------------------------------------------------------------------ argument types


def _float_list(text: str) -> tuple[float, ...]:
    try:
        values = tuple(float(v) for v in text.split(",") if v.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"{text!r} is not a comma-separated list of numbers") from None
    if not values:
        raise argparse.ArgumentTypeError("empty list")
    return _once(text, values)


def _name_list(text: str) -> tuple[str, ...]:
    return _once(text, tuple(v.strip() for v in text.split(",") if v.strip()))


def _once(text: str, values: tuple) -> tuple:
    """`values`, refused when one is repeated (each sweep point is run once)."""
    repeated = [v for i, v in enumerate(values) if v in values[:i]]
    if repeated:
        raise argparse.ArgumentTypeError(f"{text!r} repeats {repeated[0]!r}; give each "
                                         "value once")
    return values


def _ramp_top(text: str) -> float:
    """--ramp-top: "per-load" (0) or a Pi [MPa], returned in Pa."""
    if text == "per-load":
        return 0.0
    try:
        return float(text) * MPA
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is neither per-load nor a number") from None


def _out_path(text: str) -> Path:
    """An --out path; the empty string is refused (Path("") would mean the current folder)."""
    if not text.strip():
        raise argparse.ArgumentTypeError(f"{text!r} is empty; give a folder or file name")
    return Path(text)


def _size(text: str) -> tuple[int, int]:
    try:
        w, h = text.lower().split("x")
        return int(w), int(h)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not WIDTHxHEIGHT, e.g. 640x480") \
            from None


# ------------------------------------------------------------------ parser


def _common() -> argparse.ArgumentParser:
    common = _Parser(add_help=False)
    g = common.add_argument_group("model and run options")
    g.add_argument("--preset", choices=PRESETS, default="wpam",
                   help="muscle type: wpam (double chamber), rlam (no outer chamber), "
                        "mckibben (rubber tube) (default: wpam)")
    g.add_argument("--dt", type=float, default=1e-3, metavar="S",
                   help="physics time step [s] (default: 0.001)")
    g.add_argument("--config", type=Path, metavar="FILE.toml",
                   help="parameter overrides: TOML with sections braid, muscle, "
                        "pneumatics, controller; SI values (m, Pa, N, s)")
    g.add_argument("--jobs", type=int, default=pool.default_jobs(), metavar="N",
                   help=_JOBS_HELP)
    g.add_argument("--progress", action=argparse.BooleanOptionalAction, default=None,
                   help="progress bars on stderr (default: when stderr is a terminal)")
    return common


_JOBS_HELP = (f"parallel worker processes [count], 1 to {JOBS_PER_CPU} per CPU (default: the "
              f"number of CPUs, {pool.default_jobs()}); never more than the command has "
              "runs; results do not depend on it")


def _description() -> str:
    """The module docstring without its list of subcommands (argparse lists them)."""
    paragraphs = __doc__.split("\n\n")
    return "\n\n".join(p for p in paragraphs if not p.startswith("Subcommands"))


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="wpam", description=_description(),
                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--version", action="version", version=f"wpam-mj {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    common = [_common()]

    def add(name: str, help_: str, handler) -> argparse.ArgumentParser:
        p = sub.add_parser(name, help=help_, description=help_, parents=common)
        p.set_defaults(handler=handler)
        return p

    def out_dir(p: argparse.ArgumentParser, name: str) -> None:
        p.add_argument("--out", type=_out_path, metavar="DIR",
                       help=f"output folder (default: out/{name} under the current folder)")

    def ramp_time(p: argparse.ArgumentParser) -> None:
        p.add_argument("--ramp-time", type=float, default=STATIC_RAMP_S, metavar="S",
                       help="duration of each open-loop Pi ramp, up and then down [s], "
                            f"1-3600 (default: {STATIC_RAMP_S:g}; the paper does not state "
                            "its own)")

    def json_flag(p: argparse.ArgumentParser, what: str) -> None:
        p.add_argument("--json", action="store_true", help=f"print {what} on stdout")

    def loop_area_option(p) -> None:
        p.add_argument("--loop-area", choices=LOOP_METHODS, default=None,
                       help="loop area of the open-loop ramps: branches (every lobe of a "
                            "crossing loop counts) or shoelace (signed: lobes cancel) "
                            f"(default: the shipped {SHIPPED.loop_method})")

    def protocol_options(p: argparse.ArgumentParser) -> None:
        """The readings the paper does not state (wpam_mj.experiments.protocol; docs/physics.md)."""
        g = p.add_argument_group("protocol readings (the paper does not state them; "
                                 "defaults: the shipped reading)")
        g.add_argument("--ramp-top", type=_ramp_top, default=None, metavar="per-load|MPA",
                       help="top of the open-loop Pi ramps: per-load (the Pi whose "
                            "contracting branch reaches 50 mm) or one Pi [MPa] for every load")
        g.add_argument("--top-hold", type=float, default=None, metavar="S",
                       help="seconds Pi is held at its top with Po on before it falls "
                            "(0: Po switched on as Pi starts to fall)")
        loop_area_option(g)
        g.add_argument("--po-feedforward", type=float, default=None, metavar="MPA",
                       help="the Po [MPa] the Pi feedforward assumes "
                            "(controller.po_feedforward)")
        g.add_argument("--feedforward-friction", type=float, default=None, metavar="PHI",
                       help="the share of the friction band the Pi feedforward adds "
                            "(controller.feedforward_friction; 1: eq. 5's contracting branch)")
        g.add_argument("--gain-reading", choices=tuple(GAIN_READINGS), default=None,
                       help="unit of the paper's unitless gains: " + ", ".join(
                           f"{k} ({v:g} MPa/u)" for k, v in GAIN_READINGS.items()))

    p = add("static", "open-loop static characteristic: slow Pi ramp up then down "
            "(paper Figs. 3, 8, 9); CSV, PNG and loop areas", _cmd_static)
    p.add_argument("--load", type=float, metavar="N",
                   help="hanging load [N] (default: each of the paper's 50, 100, 150 N)")
    p.add_argument("--po-down", type=float, default=0.0, metavar="MPA",
                   help="constant external pressure Po while Pi falls [MPa]: 0 = vented "
                        "(Fig. 8, default) or 0.005-0.5 (Fig. 9 uses 0.04)")
    p.add_argument("--compare-presets", action="store_true",
                   help="run wpam, rlam and mckibben and overlay them in one figure "
                        "(paper Fig. 3)")
    ramp_time(p)
    json_flag(p, "a JSON list of {preset, load_n [N], po_down_mpa [MPa], area_mpa_mm "
              "[MPa mm], load_moved}")
    out_dir(p, "static")

    p = add("step", "staircase target 0 -> 50 mm in 10 mm steps of 10 s, then back to 0 "
            "(paper Figs. 12-15); CSV and PNG", _cmd_step)
    p.add_argument("--load", type=float, default=100.0, metavar="N",
                   help="hanging load [N] (default: 100)")
    p.add_argument("--control", choices=CONTROLS, default="pi",
                   help="open: Po = 0; pi/pid: feedback on Po (default: pi)")
    json_flag(p, "one JSON object: the run's settings, load_moved and its plateau means "
              "(target_mm, x_mm, error_mm, pi_mpa, po_mpa: chamber pressures)")
    out_dir(p, "step")

    p = add("table2", "hysteresis-loop areas of the paper's Table 2 (open loop with and "
            "without Po = 0.04 MPa, PI feedback; 50/100/150 N), beside the paper's",
            _cmd_table2)
    p.add_argument("--json", action="store_true",
                   help="print one JSON object (normalized areas, unit-free) on stdout")
    ramp_time(p)
    loop_area_option(p)
    out_dir(p, "table2")

    p = add("sweep", "frequency response to a sinusoid about 25 mm, 25 mm amplitude unless "
            "--amplitude (paper Figs. 17-19): gain, phase lag, max Po", _cmd_sweep)
    p.add_argument("--amplitude", type=float, default=SINE_AMPLITUDE_MM, metavar="MM",
                   help=f"amplitude of the sinusoidal target [mm], in (0, {SINE_MEAN_MM:g}] "
                        f"(default: the paper's {SINE_AMPLITUDE_MM:g})")
    p.add_argument("--loads", type=_float_list, default=paper.LOADS_N,
                   metavar="N,N,...", help="hanging loads [N] (default: 50,100,150)")
    p.add_argument("--freqs", type=_float_list, default=paper.SWEEP_FREQS_HZ,
                   metavar="HZ,HZ,...",
                   help="target frequencies [Hz], each > 0 (default: 0.1,0.2,0.25,0.5,1.0)")
    p.add_argument("--controllers", type=_name_list, default=paper.SWEEP_CONTROLLERS,
                   metavar="C,C", help="feedback controllers, of " + ", ".join(CONTROLS)
                   + " (default: pi,pid)")
    p.add_argument("--json", action="store_true",
                   help="print a JSON list of {load_n [N], freq_hz [Hz], controller, gain [1],"
                        " phase_lag_deg [deg], po_max_mpa [MPa]} on stdout")
    out_dir(p, "sweep")

    p = add("reproduce", "every experiment into one folder with report.md (figures, the "
            "paper's numbers beside ours, checks, parameters)", _cmd_reproduce)
    ramp_time(p)
    protocol_options(p)
    out_dir(p, "reproduce")

    p = add("search", "global search (differential evolution) of the credible parameter box "
            "and the protocol readings on every finding of the paper; writes the best "
            "point and the pairwise feasibility map of the findings", _cmd_search)
    p.add_argument("--out", type=_out_path, metavar="DIR",
                   help="output folder (default: out/search): journal.jsonl, best.toml, "
                        "best.txt, feasibility.md, feasibility.png")
    p.add_argument("--seed", type=int, default=20, help="seed of the search (default: 20)")
    p.add_argument("--popsize", type=int, default=2, metavar="K",
                   help="population K x 15 points (default: 2)")
    p.add_argument("--maxiter", type=int, default=3, metavar="N",
                   help="generations after the first population (default: 3: about 145 "
                        "points, 12 min on two free cores; docs/physics.md used 5)")
    p.add_argument("--resume", action="store_true",
                   help="continue an interrupted search in --out: journaled points are "
                        "replayed, not run again (a finished search replays in seconds)")
    p.add_argument("--map-only", action="store_true",
                   help="run nothing: the best point and the feasibility map of the points "
                        "journaled in --out so far (e.g. while the search still runs)")

    p = add("calibrate", "fit the parameters the paper does not give (braid angle, Kf, "
            "friction, axial area, regulators) to its Table 2 and findings", _cmd_calibrate)
    p.add_argument("--out", type=_out_path, metavar="FILE",
                   help="calibrated parameter TOML (SI units) for --config (default: "
                        "calibrated.toml in the current folder; the shipped values are "
                        "models/wpam/calibrated.toml in the package)")
    p.add_argument("--resume", action="store_true",
                   help="continue an interrupted calibration to the same --out: the "
                        "evaluations it journaled are replayed, not run again")
    p.add_argument("--samples", type=int, default=0, metavar="N",
                   help="score N random parameter sets of the plausible ranges first and "
                        "start from the best of them and the preset (default: 0)")
    p.add_argument("--seed", type=int, default=7,
                   help="seed of the random samples (default: 7)")
    ramp_time(p)
    protocol_options(p)
    p.add_argument("--max-steps", type=int, default=6, metavar="N",
                   help="most least-squares steps, each ~10 parameter sets (default: 6)")

    p = add("render", "simulate one run, then write an offscreen video of it", _cmd_render)
    p.add_argument("--load", type=float, default=100.0, metavar="N",
                   help="hanging load [N] (default: 100)")
    p.add_argument("--experiment", choices=EXPERIMENTS, default="step",
                   help="step: staircase; sweep: sinusoid at --freq; static: open-loop Pi "
                        "ramp (default: step)")
    p.add_argument("--control", choices=CONTROLS, default="pi",
                   help="controller for step and sweep (default: pi)")
    p.add_argument("--freq", type=float, default=0.5, metavar="HZ",
                   help="target frequency for --experiment sweep [Hz], > 0 (default: 0.5)")
    p.add_argument("--duration", type=float, metavar="S",
                   help="video length [s] (default: the whole run)")
    p.add_argument("--fps", type=float, default=30.0, metavar="FPS",
                   help="frames per second [1/s] (default: 30)")
    p.add_argument("--size", type=_size, default=(640, 480), metavar="WxH",
                   help="frame size [px] (default: 640x480)")
    p.add_argument("--out", type=_out_path, metavar="FILE.mp4|FILE.gif",
                   help="video file (default: out/render/<experiment>.mp4)")
    _add_view_parser(add)
    _add_linear_parser(add("linear", "the paper's §3 linear model (and an extended one) "
                           "at an operating point: poles, margins, DC gains, and its Bode "
                           "plot beside the simulated frequency response", _cmd_linear))
    _add_study_parser(sub)
    _add_fit_parser(add)
    _add_synth_parser(add)
    return parser


def _add_view_parser(add) -> None:
    p = add("view", "MuJoCo's interactive viewer on the hung muscle, stepped live by the "
            "simulation loop; pull the load with Ctrl + right drag (needs a display)",
            _cmd_view)
    p.add_argument("--load", type=float, default=100.0, metavar="N",
                   help="hanging load [N] (default: 100)")
    from wpam_mj.visualisation.viewer import VIEW_CONTROLS  # noqa: PLC0415 (pi_ff needs the target ahead)
    p.add_argument("--control", choices=VIEW_CONTROLS, default="pi",
                   help="Po controller; End cycles it in the viewer (default: pi)")
    p.add_argument("--target", default="step", metavar="step|sine|MM",
                   help="target: the 0-50-0 mm staircase, a 25 mm sine about 25 mm at "
                        "0.2 Hz, or a fixed contraction [mm]; Up/Down/Home change it "
                        "(default: step)")
    p.add_argument("--duration", type=float, metavar="S",
                   help="close after this much simulated time [s] (default: when the "
                        "window is closed)")


def _add_linear_parser(p: argparse.ArgumentParser) -> None:
    p.add_argument("--load", type=float, default=100.0, metavar="N",
                   help="hanging load [N] (default: 100)")
    p.add_argument("--contraction", type=float, default=SINE_MEAN_MM, metavar="MM",
                   help=f"operating contraction [mm] (default: {SINE_MEAN_MM:g}, the mean "
                        "the simulated sweeps always run about)")
    p.add_argument("--amplitudes", type=_float_list, default=None, metavar="MM,MM",
                   help="amplitudes of the simulated sweeps [mm] (default: the paper's 25 "
                        "and a small one, 5)")
    p.add_argument("--json", action="store_true",
                   help="print one JSON object (operating point, poles, margins, DC gains, "
                        "comparison rows) on stdout")
    p.add_argument("--out", type=_out_path, metavar="DIR",
                   help="output folder (default: out/linear under the current folder)")


def _add_study_parser(sub) -> None:
    from wpam_mj.infra.executors import SCHEDULER_ENV  # noqa: PLC0415 (the study's own modules)
    p = sub.add_parser("study", help="a design-space study: the runs of a study file "
                       "(grid, list, random or Latin-hypercube sample), one table row each",
                       description="Run a study file (see examples/ and the README) and "
                       "write study.csv (+ study.parquet with pyarrow) and plots/.")
    p.set_defaults(handler=_cmd_study)
    p.add_argument("spec", type=Path, metavar="SPEC.toml", help="the study file")
    p.add_argument("--out", type=_out_path, metavar="DIR",
                   help="output folder (default: out/study/<SPEC name>)")
    p.add_argument("--jobs", type=int, default=pool.default_jobs(), metavar="N",
                   help=_JOBS_HELP)
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="run on the Dask cluster of this scheduler, e.g. tcp://host:8786 "
                        f"(default: ${SCHEDULER_ENV} if set, else local processes)")
    p.add_argument("--resume", action="store_true",
                   help="keep the runs an interrupted study in --out has finished")
    p.add_argument("--progress", action=argparse.BooleanOptionalAction, default=None,
                   help="progress bar with time left on stderr (default: when stderr is a "
                        "terminal)")
    for name in ("--preset", "--dt", "--config"):  # refused in _cmd_study, with the reason
        p.add_argument(name, help=argparse.SUPPRESS)


# ------------------------------------------------------------------ helpers


@dataclasses.dataclass(frozen=True)
class _Run:
    """Options shared by every command, validated."""

    params: Params
    dt: float
    jobs: int
    progress: bool

    def jobs_for(self, tasks: int) -> int:
        """Worker processes for `tasks` runs: no more than there are runs."""
        return max(1, min(self.jobs, tasks))


def _params(args: argparse.Namespace, name: str | None = None) -> Params:
    """The preset `name` (default --preset) with the --config overrides applied."""
    params = preset(name or args.preset)
    if args.config is not None:
        overrides = load_toml(args.config)  # its errors name the file
        try:
            params = apply_overrides(params, overrides)
        except (TypeError, ValueError) as err:  # ParameterError, or a wrongly typed value
            raise ParameterError(f"--config {args.config}: {err}") from None
    return params


def _jobs(jobs: int) -> int:
    """--jobs: 1 to JOBS_PER_CPU per CPU (more only costs memory: every run is one task)."""
    jobs = pool.check_jobs(jobs)
    most = JOBS_PER_CPU * pool.default_jobs()
    if jobs > most:
        raise ParameterError(f"--jobs {jobs} is outside the allowed range [1, {most}] "
                             f"({JOBS_PER_CPU} per CPU)")
    return jobs


def _run_options(args: argparse.Namespace) -> _Run:
    params = _params(args)
    dt = check_dt(args.dt, divides=RECORD_DT_S, name="--dt")
    jobs = _jobs(args.jobs)
    progress = sys.stderr.isatty() if args.progress is None else args.progress
    return _Run(params, dt, jobs, progress)


def _protocol(args: argparse.Namespace, params: Params) -> tuple[Params, Protocol]:
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


def _protocol_settings(protocol: Protocol) -> dict:
    return {"ramp_top_mpa": protocol.ramp_top / MPA, "ramp_time_s": protocol.ramp_time,
            "top_hold_s": protocol.top_hold, "loop_area": protocol.loop_method}


def _writable_dir(path: Path) -> Path:
    """Create `path` if needed, make sure files can be written in it, and hold it for this
    command alone (`wpam_mj.infra.outputs`: removed again if the command fails unused)."""
    return outputs.claim(path)


def _out_dir(args: argparse.Namespace) -> Path:
    return _writable_dir(args.out if args.out is not None else Path("out") / args.command)


def _out_file(path: Path) -> Path:
    if path.is_dir():
        raise ParameterError(f"--out {path} is a folder; give a file name")
    _writable_dir(path.parent)
    return path


def _output_modules():
    """`summaries` and `writers` (matplotlib): imported only by commands that write
    figures, so that --help and argument errors stay quick."""
    from wpam_mj.experiments import tables as summaries
    from wpam_mj.experiments import writers  # noqa: PLC0415
    return summaries, writers


def _loads(values: Sequence[float], params_list: Sequence[Params],
           name: str = "--load") -> tuple[float, ...]:
    """Loads [N] in range that every parameter set lifts to the top target (50 mm)."""
    loads = tuple(check_load(v) for v in values)
    for params in params_list:
        check_liftable(params, loads, name)
    return loads


def _print_json(obj) -> None:
    print(json.dumps(obj, indent=2))


def _wrote(paths: Sequence[Path]) -> None:
    for p in paths:
        print(f"wrote {p}")


def _run_id(args: argparse.Namespace, params: Params, settings: dict) -> str:
    """The id of this run (`wpam_mj.infra.manifest.run_id`): only result-defining settings."""
    from wpam_mj.infra import manifest  # noqa: PLC0415
    return manifest.run_id(args.command, params, settings)


def _manifest(args: argparse.Namespace, out: Path, rid: str, params: Params, settings: dict,
              files) -> Path:
    """Write the run's manifest beside its files (`wpam_mj.infra.manifest.write_manifest`)."""
    from wpam_mj.infra import manifest  # noqa: PLC0415
    return manifest.write_manifest(out, rid, args.command, params, files, settings=settings,
                                   argv=getattr(args, "argv", None))


def _flag_still(what: Sequence[tuple[str, bool]], to_stderr: bool) -> None:
    """One line for each run whose load never moved (its numbers mean nothing)."""
    from wpam_mj.experiments.feasibility import MOVE_MIN_MM  # noqa: PLC0415
    for name, moved in what:
        if not moved:
            print(f"note: {name}: the load never moved (x spanned < {MOVE_MIN_MM:g} mm); "
                  "this run's numbers mean nothing",
                  file=sys.stderr if to_stderr else sys.stdout)


# ------------------------------------------------------------------ commands


def _cmd_static(args: argparse.Namespace) -> int:
    _, writers = _output_modules()
    run = _run_options(args)
    names = PRESETS if args.compare_presets else (args.preset,)
    plist = [run.params if n == args.preset else _params(args, n) for n in names]
    loads = _loads(paper.LOADS_N if args.load is None else (args.load,), plist)
    po_down = check_po("--po-down", args.po_down * MPA, run.params)
    ramp_time = studies.check_ramp_time(args.ramp_time)
    out = _out_dir(args)
    loops = studies.compare_presets(plist, loads, po_down, dt=run.dt,
                                    jobs=run.jobs_for(len(plist) * len(loads)),
                                    progress=run.progress, ramp_time=ramp_time)
    settings = {"presets": names, "loads_n": loads, "po_down_mpa": args.po_down,
                "ramp_time_s": ramp_time, "dt_s": run.dt}
    rid = _run_id(args, run.params, settings)
    written = writers.write_static_outputs(out, loops, compare_presets=args.compare_presets,
                                           run_id=rid)
    manifest = _manifest(args, out, rid, run.params, settings, written)
    moved = [load_moved(lp.result) for lp in loops]
    if args.json:
        _print_json([{"preset": lp.preset, "load_n": lp.load, "po_down_mpa": lp.po_down / MPA,
                      "area_mpa_mm": lp.area_mpa_mm, "load_moved": m, "run_id": rid}
                     for lp, m in zip(loops, moved)])
    else:
        print(f"loop area of x against measured Pi (Po = {args.po_down:g} MPa while Pi "
              f"falls, {ramp_time:g} s ramps):")
        for lp in loops:
            print(f"  {lp.preset:>8} {lp.load:>6g} N: {lp.area_mpa_mm:.4g} MPa mm")
    _flag_still([(f"static {lp.preset} {lp.load:g} N", m) for lp, m in zip(loops, moved)],
                args.json)
    if not args.json:
        _wrote([*written, manifest])
    return 0


def _cmd_step(args: argparse.Namespace) -> int:
    summaries, writers = _output_modules()
    run = _run_options(args)
    (load,) = _loads((args.load,), [run.params])
    control = check_control(args.control)
    out = _out_dir(args)
    (res,) = studies.step_study(run.params, [(load, control)], dt=run.dt, jobs=1,
                                progress=run.progress)
    settings = {"load_n": load, "control": control, "dt_s": run.dt}
    rid = _run_id(args, run.params, settings)
    written = writers.write_step_outputs(out, res, run_id=rid)
    manifest = _manifest(args, out, rid, run.params, settings, written)
    moved = load_moved(res.result)
    if args.json:
        _print_json({"preset": res.preset, "load_n": res.load, "control": res.control,
                     "settle_s": res.settle, "load_moved": moved, "run_id": rid,
                     "plateaus": [{"target_mm": tg / MM, "x_mm": x / MM,
                                   "error_mm": (x - tg) / MM, "pi_mpa": pi / MPA,
                                   "po_mpa": po / MPA}
                                  for tg, x, pi, po in zip(res.target, res.x_mean,
                                                           res.pi_mean, res.po_mean)]})
    else:
        print(summaries.step_text(res))
    _flag_still([(f"step {res.preset} {load:g} N {control}", moved)], args.json)
    if not args.json:
        _wrote([*written, manifest])
    return 0


def _cmd_table2(args: argparse.Namespace) -> int:
    summaries, writers = _output_modules()
    run = _run_options(args)
    _loads(paper.LOADS_N, [run.params], "Table 2 load")
    ramp_time = studies.check_ramp_time(args.ramp_time)
    out = _out_dir(args)
    t2 = studies.table2(run.params, dt=run.dt, jobs=run.jobs_for(3 * len(paper.LOADS_N)),
                        progress=run.progress, ramp_time=ramp_time)
    loop_area = args.loop_area or SHIPPED.loop_method
    t2 = remeasure(t2, loop_area)
    settings = {"ramp_time_s": ramp_time, "dt_s": run.dt, "loop_area": loop_area}
    rid = _run_id(args, run.params, settings)
    written = writers.write_table2_outputs(out, t2, run_id=rid)
    still = [(f"table2 open loop {lp.load:g} N, Po = {lp.po_down / MPA:g} MPa while Pi falls",
              load_moved(lp.result)) for lp in (*t2.open_loops, *t2.po_loops)]
    still += [(f"table2 PI {f.load:g} N", load_moved(f.result)) for f in t2.feedback_runs]
    moved = {name: m for name, m in still}
    written = {path: ({"load_moved": moved} if path.suffix in (".json", ".csv") else meta)
               for path, meta in written.items()}
    manifest = _manifest(args, out, rid, run.params, settings, written)
    if args.json:
        _print_json(t2.as_json())
    else:
        print(summaries.table2_text(t2))
        print(findings.checks_text(findings.table2_checks(t2)))
    _flag_still(still, args.json)
    if not args.json:
        _wrote([*written, manifest])
    return 0


def _amplitude(name: str, mm: float) -> float:
    """A sine amplitude [m] from mm: the target must stay at or above 0 mm."""
    return check_range(name, mm, 0.0, SINE_MEAN_MM, "mm", lo_open=True) * MM


def _cmd_sweep(args: argparse.Namespace) -> int:
    summaries, writers = _output_modules()
    run = _run_options(args)
    loads = _loads(args.loads, [run.params], "--loads")
    amplitude = _amplitude("--amplitude", args.amplitude)
    freqs = tuple(SineSpec(f).freq for f in args.freqs)
    controllers = tuple(check_control(c) for c in args.controllers)
    if not controllers:
        raise ParameterError("--controllers: no controller given; valid: "
                             + ", ".join(CONTROLS))
    out = _out_dir(args)
    key = studies.figure_run_key(loads, freqs, controllers)
    sw = studies.sweep(run.params, loads, freqs, controllers, keep=[key], dt=run.dt,
                       jobs=run.jobs_for(len(loads) * len(freqs) * len(controllers)),
                       progress=run.progress, amplitude=amplitude)
    po_cap = run.params.controller.po_cap
    settings = {"loads_n": loads, "freqs_hz": freqs, "controllers": controllers,
                "amplitude_mm": amplitude / MM, "dt_s": run.dt}
    rid = _run_id(args, run.params, settings)
    written = writers.write_sweep_outputs(out, sw, key, po_cap, run_id=rid)
    manifest = _manifest(args, out, rid, run.params, settings, written)
    if args.json:
        _print_json(sw.as_json())
    else:
        print(summaries.sweep_text(sw))
        print(findings.checks_text(findings.sweep_checks(sw, po_cap)))
    _flag_still([(f"sweep {point}", False) for point in writers.still_points(sw)], args.json)
    if not args.json:
        _wrote([*written, manifest])
    return 0


def _cmd_linear(args: argparse.Namespace) -> int:
    from wpam_mj.design import linear_study
    from wpam_mj.experiments import figures as plots  # noqa: PLC0415 (python-control, matplotlib: slow)
    run = _run_options(args)
    load = check_load(args.load)
    amplitudes = tuple(_amplitude("--amplitudes", a) for a in
                       (args.amplitudes or linear_study.AMPLITUDES_MM))
    out = _out_dir(args)
    (cmp,) = linear_study.compare(run.params, (load,), contraction=args.contraction * MM,
                                  amplitudes=amplitudes, dt=run.dt, jobs=run.jobs,
                                  progress=run.progress)
    settings = {"load_n": load, "contraction_mm": args.contraction,
                "amplitudes_mm": [a / MM for a in amplitudes], "dt_s": run.dt}
    rid = _run_id(args, run.params, settings)
    stem = f"linear_{load:g}N"
    written = [plots.save_figure(cmp.plot(), out / f"{stem}.png", run_id=rid),
               write_text_atomic(out / f"{stem}.csv", cmp.csv_text())]
    manifest = _manifest(args, out, rid, run.params, settings, written)
    if args.json:
        _print_json(cmp.as_json())
    else:
        print(cmp.text())
        _wrote([*written, manifest])
    return 0


def _cmd_reproduce(args: argparse.Namespace) -> int:
    summaries, _ = _output_modules()
    from wpam_mj.reproduction.reproduce import reproduce  # noqa: PLC0415 (matplotlib: slow import)
    run = _run_options(args)
    params, protocol = _protocol(args, run.params)
    compare = [params if n == args.preset else _params(args, n) for n in COMPARED_TYPES]
    _loads(paper.LOADS_N, [params], "reproduce load")
    out = _out_dir(args)
    settings = {"compare_presets": COMPARED_TYPES, "dt_s": run.dt, **_protocol_settings(protocol)}
    rid = _run_id(args, params, settings)
    start = time.perf_counter()
    rep = reproduce(out, params, dt=run.dt, jobs=run.jobs, progress=run.progress,
                    compare=compare, run_id=rid, protocol=protocol)
    manifest = _manifest(args, out, rid, params, settings, rep.files)
    print(summaries.table2_text(rep.table2))
    print(findings.checks_text(rep.checks))
    print(f"wrote {rep.report} and {manifest} ({time.perf_counter() - start:.1f} s)")
    return 0


def _cmd_calibrate(args: argparse.Namespace) -> int:
    if args.preset != "wpam":
        raise ParameterError(f"--preset {args.preset}: calibrate fits the wpam preset "
                             "(start from other values with --config)")
    run = _run_options(args)  # the search starts from the preset plus --config
    start, protocol = _protocol(args, run.params)
    out = _out_file(Path("calibrated.toml") if args.out is None else args.out)
    from wpam_mj.reproduction.calibrate import calibrate  # noqa: PLC0415 (scipy.optimize: slow import)
    readings = {} if protocol == SHIPPED else {"protocol": protocol}  # as before: none
    result = calibrate(out=out, jobs=run.jobs, dt=run.dt, progress=run.progress,
                       start=start, samples=args.samples, seed=args.seed,
                       max_nfev=args.max_steps, resume=args.resume, **readings)
    print(result.table())
    print(f"wrote {out} (use it with --config {out})")
    return 0


def _cmd_search(args: argparse.Namespace) -> int:
    if args.preset != "wpam":
        raise ParameterError(f"--preset {args.preset}: search explores the wpam preset")
    run = _run_options(args)  # the search's shipped point: the preset plus --config
    out = _writable_dir(Path("out") / "search" if args.out is None else args.out)
    from wpam_mj.reproduction import search  # noqa: PLC0415 (scipy, matplotlib: slow imports)
    if args.map_only:
        written = search.write_outputs(out, search.load_records(out), run.params)
    else:
        written = search.write_search(out, base=run.params, seed=args.seed,
                                      popsize=args.popsize, maxiter=args.maxiter,
                                      jobs=run.jobs, resume=args.resume, progress=run.progress)
    for path in written:
        print(f"wrote {path}")
    return 0


def _cmd_render(args: argparse.Namespace) -> int:
    from wpam_mj.visualisation.render import check_fps  # noqa: PLC0415 (needs OpenGL; only here)
    run = _run_options(args)
    (load,) = _loads((args.load,), [run.params])
    control = check_control(args.control)
    spec = SineSpec(args.freq)
    duration = None if args.duration is None else \
        check_range("--duration", args.duration, 0.0, 3600.0, "s", lo_open=True)
    out = args.out if args.out is not None else Path("out") / "render" / f"{args.experiment}.mp4"
    if out.suffix.lower() not in (".mp4", ".gif"):
        raise ParameterError(f"--out {out}: the video must end in .mp4 or .gif")
    fps = check_fps(args.fps, out.suffix.lower())
    _out_file(out)
    result = simulate_for_render(run.params, load, args.experiment, control, spec,
                                 duration, run.dt)
    check_video(result.time[-1] - result.time[0], fps, args.size, out.suffix)
    settings = {"load_n": load, "experiment": args.experiment, "control": control,
                "freq_hz": spec.freq, "duration_s": duration, "fps": fps, "size": args.size,
                "dt_s": run.dt}
    rid = _run_id(args, run.params, settings)
    from wpam_mj.visualisation.render import render_video  # noqa: PLC0415 (needs OpenGL; only here)
    try:
        path = render_video(result, run.params, out, fps=fps, size=args.size, run_id=rid)
    except RuntimeError as err:
        raise RunFailed(str(err)) from None
    _, writers = _output_modules()
    manifest = _manifest(args, out.parent, rid, run.params, settings,
                         {path: writers.run_metadata(result)})
    print(f"wrote {path} ({result.time[-1]:.2f} s of simulated time) and {manifest}")
    return 0


def _cmd_view(args: argparse.Namespace) -> int:
    from wpam_mj.visualisation import viewer  # noqa: PLC0415 (GLFW viewer; only here)

    run = _run_options(args)
    target = args.target
    if target not in ("step", "sine"):
        try:
            target = float(target) * 1e-3  # mm -> m
        except ValueError:
            raise ParameterError(f"--target {args.target!r} must be step, sine or a "
                                 "contraction in mm") from None
    try:
        trace = viewer.view(run.params, load=args.load, control=check_control(args.control),
                            target=target, dt=run.dt, duration=args.duration)
    except viewer.ViewerUnavailable as err:
        raise RunFailed(str(err)) from None
    if len(trace.time):
        print(f"viewed {trace.time[-1]:.1f} s of simulated time")
    return 0


def _cmd_study(args: argparse.Namespace) -> int:
    from wpam_mj.design import study  # noqa: PLC0415 (the study's own modules)
    from wpam_mj.infra.executors import open_workers  # noqa: PLC0415
    given = [f"--{n}" for n in ("preset", "dt", "config") if getattr(args, n) is not None]
    if given:
        raise ParameterError(f"{', '.join(given)}: a study file sets its own preset, dt and "
                             "parameters (preset = \"rlam\", dt = 5e-4, [fixed] "
                             "\"section.field\" = value)")
    jobs = _jobs(args.jobs)
    spec = study.load_spec(args.spec)
    out = _writable_dir(args.out if args.out is not None
                        else Path("out") / "study" / args.spec.stem)
    progress = sys.stderr.isatty() if args.progress is None else args.progress
    start = time.perf_counter()
    with open_workers(jobs, args.scheduler) as workers:
        res = study.run_study(spec, out, workers, resume=args.resume, progress=progress)
    flagged = sum(r["diverged"] or r["infeasible"] for r in res.rows)
    print(f"{len(res.rows)} runs ({res.ran} run now on {workers.where}, {res.reused} "
          f"resumed, {flagged} diverged or infeasible) in {time.perf_counter() - start:.1f} s")
    from wpam_mj.design.figures import save_study_plots  # noqa: PLC0415 (matplotlib: slow)
    _wrote([*res.files, *save_study_plots(spec, res.rows, out / "plots")])
    return 0


# ------------------------------------------------------------------ fit and synth


def _add_fit_parser(add) -> None:
    from wpam_mj.fitting import measurements  # noqa: PLC0415 (its docstring is the format)
    p = add("fit", "fit the model to your own measured experiments (CSV files, format "
            "below): estimates with 1-sigma, RMS per file, a PNG per file", _cmd_fit)
    p.formatter_class = argparse.RawDescriptionHelpFormatter  # keep the format's layout
    p.epilog = measurements.__doc__.split("\n\nInside,")[0]
    p.add_argument("--data", nargs="+", required=True, metavar="FILE_OR_DIR",
                   help="measurement CSV files, or folders of them (their *.csv)")
    p.add_argument("--holdout", nargs="+", default=[], metavar="FILE_OR_DIR",
                   help="experiments replayed with the fitted values but not fitted")
    p.add_argument("--free", type=_name_list, metavar="NAME,NAME,...",
                   help="parameters to fit, as section.field (default: those the paper does "
                        "not give: braid angle, Kf, mu, F_f0, A_ax, both line conductances)")
    p.add_argument("--bounds", type=_name_list, default=(), metavar="NAME=LO:HI,...",
                   help="override the bounds of free parameters [SI] (default: their "
                        "plausible ranges, listed in the package's models/README.md)")
    p.add_argument("--out", type=_out_path, default=Path("out") / "fit" / "params.toml",
                   metavar="FILE.toml",
                   help="fitted parameters, a --config file for the same --preset; the "
                        "figures go next to it (default: out/fit/params.toml)")
    p.add_argument("--randomize-out", type=_out_path, metavar="FILE.toml",
                   help="also write domain-randomisation ranges (estimate +- k sigma) for "
                        "wpam_mj.environments.dm_env_task.make_env(randomize=FILE)")
    p.add_argument("--randomize-k", type=float, default=2.0, metavar="K",
                   help="ranges span +- K sigma [1] (default: 2)")
    p.add_argument("--max-evals", type=int, default=60, metavar="N",
                   help="most residual evaluations of each of the two passes [count] "
                        "(default: 60)")
    p.add_argument("--json", action="store_true",
                   help="print one JSON object (estimates SI, RMS in mm) on stdout")


def _bounds(items: Sequence[str]) -> dict[str, tuple[float, float]]:
    out = {}
    for item in items:
        name, _, rng = item.partition("=")
        lo, _, hi = rng.partition(":")
        try:
            out[name.strip()] = (float(lo), float(hi))
        except ValueError:
            raise ParameterError(f"--bounds {item!r}: expected NAME=LO:HI, e.g. "
                                 "muscle.friction_coeff=0.05:0.4") from None
    return out


def _cmd_fit(args: argparse.Namespace) -> int:
    run = _run_options(args)  # the search starts from the preset plus --config
    if not 0 < args.max_evals <= 10000:
        raise ParameterError(f"--max-evals = {args.max_evals} must be in [1, 10000]")
    k = check_range("--randomize-k", args.randomize_k, 0.0, 10.0, "")
    from wpam_mj.fitting import measured_fit as datafit
    from wpam_mj.fitting import estimation as fitting  # noqa: PLC0415 (scipy.optimize: slow import)
    from wpam_mj.fitting.measurements import experiment_files, read_experiment  # noqa: PLC0415
    data = [read_experiment(f, run.params) for f in experiment_files(args.data)]
    held = [read_experiment(f, run.params) for f in experiment_files(args.holdout)] \
        if args.holdout else []
    names = args.free or fitting.default_free()
    bounds = _bounds(args.bounds)
    for name in bounds:
        if name not in names:
            raise ParameterError(f"--bounds {name}: not a free parameter (free: "
                                 f"{', '.join(names)})")
    free = [fitting.FreeParameter.of(n, bounds.get(n)) for n in names]
    out = _out_file(args.out)
    if args.randomize_out is not None:
        _out_file(args.randomize_out)
    result = datafit.fit_data(run.params, data, free, holdout=held, dt=run.dt,
                              jobs=run.jobs, max_nfev=args.max_evals, progress=run.progress)
    header = (f"Fitted by `wpam fit --preset {args.preset}` to "
              + ", ".join(e.name for e in data) + f"; use with --preset {args.preset}.")
    written = [write_text_atomic(out, datafit.params_toml(result.params, preset(args.preset),
                                                          result, header))]
    if args.randomize_out is not None:
        from wpam_mj.fitting.randomize import ParameterRanges  # noqa: PLC0415
        ranges = ParameterRanges.from_estimates(result.result.estimates, k)
        written.append(write_text_atomic(args.randomize_out, ranges.toml(
            f"wpam fit: estimates +- {k:g} sigma, clipped to the fit bounds.")))
    written += datafit.write_figures(result, out.parent)
    if args.json:
        _print_json(result.as_json())
        return 0
    units = {name: unit for name, _, unit, _ in describe(run.params)}
    print(result.result.table(lambda name: units[name]))
    for f in result.files:
        print(f"  {f.experiment.name:<24} {'held out' if f.held_out else 'fitted':<9} "
              f"RMS {f.rms / MM:.4f} mm")
    held_rms = result.rms(True)
    print(f"RMS over fitted files {result.rms(False) / MM:.4f} mm"
          + ("" if math.isnan(held_rms) else f", held out {held_rms / MM:.4f} mm")
          + f" ({result.result.nfev} evaluations; {result.result.message})")
    _wrote(written)
    return 0


def _add_synth_parser(add) -> None:
    p = add("synth", "write synthetic measurements (the CSV format of `wpam fit`) from the "
            "simulator: static ramps and PI staircases, PI sine runs in holdout/", _cmd_synth)
    p.add_argument("--out", type=_out_path, default=Path("out") / "synth", metavar="DIR",
                   help="output folder (default: out/synth)")
    p.add_argument("--loads", type=_float_list, default=paper.LOADS_N, metavar="N,N,...",
                   help="hanging loads [N] (default: 50,100,150)")
    p.add_argument("--noise-mm", type=float, default=0.0, metavar="MM",
                   help="standard deviation of the noise on x [mm] (default: 0)")
    p.add_argument("--noise-kpa", type=float, default=0.0, metavar="KPA",
                   help="standard deviation of the noise on the gauges [kPa] (default: 0)")
    p.add_argument("--seed", type=int, default=0, help="seed of the noise (default: 0)")
    p.add_argument("--sample-ms", type=float, default=1.0, metavar="MS",
                   help="logger sample period [ms], a multiple of --dt (default: 1)")


def _cmd_synth(args: argparse.Namespace) -> int:
    run = _run_options(args)
    out = _writable_dir(args.out)
    sample_dt = check_range("--sample-ms", args.sample_ms, 0.001, 1000.0, "ms") * 1e-3
    from wpam_mj.fitting.synthetic import synth  # noqa: PLC0415
    paths = synth(run.params, out, loads=_loads(args.loads, [run.params], "--loads"),
                  noise_mm=args.noise_mm,
                  noise_kpa=args.noise_kpa, seed=args.seed, sample_dt=sample_dt, dt=run.dt,
                  jobs=run.jobs, progress=run.progress)
    _wrote(paths)
    return 0


# ------------------------------------------------------------------ entry point


def _one_line(err: BaseException) -> str:
    return " ".join(str(err).split()) or type(err).__name__


def main(argv: Sequence[str] | None = None) -> int:
    """Run the `wpam` command line; returns the exit status."""
    closed = reopen_closed()  # `wpam ... >&-`: before any file takes descriptor 1
    code = 1
    with handle_signals():  # also over the cleanup: a second signal cannot interrupt it
        try:
            code = _main(argv)
        finally:
            outputs.release(failed=code != 0)
    if code == 0 and "stdout" in closed:
        code = 141  # as for a reader gone before the first line (below)
    if argv is None and stopped_by_signal():  # the process's own command line
        exit_now(code)  # cleanup is done; skip the interpreter's ~1 s teardown
    return code


def _main(argv: Sequence[str] | None) -> int:
    parser = build_parser()
    args = None
    try:
        args = parser.parse_args(argv)
        args.argv = list(sys.argv[1:] if argv is None else argv)
        code = args.handler(args)
        sys.stdout.flush()  # a closed pipe shows here, not at interpreter exit
        return code
    except SystemExit as exc:  # --help, --version
        return exc.code if isinstance(exc.code, int) else 0
    except (UsageError, ParameterError) as err:
        print(f"wpam: error: {_one_line(err)}", file=sys.stderr)
        return 2
    except (SimulationDiverged, RunFailed, BrokenExecutor) as err:
        print(f"wpam: error: {_one_line(err)}", file=sys.stderr)
        return 1
    except BrokenPipeError:  # stdout piped into e.g. `head`, which has exited: quietly,
        # with the status a POSIX tool killed by SIGPIPE has (128 + 13)
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # no flush error
        return 141
    except OSError as err:
        print(f"wpam: error: {_one_line(err)}", file=sys.stderr)
        return 1
    except KeyboardInterrupt as stop:  # SIGINT, SIGTERM, SIGHUP (`wpam_mj.infra.termination`)
        stop = stop if isinstance(stop, Interrupted) else Interrupted()
        print(f"wpam: {stop.message}", file=sys.stderr)
        return stop.status


if __name__ == "__main__":
    sys.exit(main())
