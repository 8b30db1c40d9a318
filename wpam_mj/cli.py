"""`wpam`: the paper's experiments from the command line.

Subcommands (each has --help):
  static     open-loop Pi ramp up and down (paper Figs. 3, 8, 9)
  step       staircase target 0 -> 50 -> 0 mm (Figs. 12-15)
  table2     hysteresis-loop areas of Table 2, beside the paper's
  sweep      frequency response to a sinusoidal target (Figs. 17-19)
  reproduce  all of the above into one folder with report.md
  calibrate  fit the parameters the paper does not give
  render     offscreen video of a simulated run

Units at this edge: loads in N, pressures in MPa, lengths in mm, times in s, frequencies
in Hz (the library is SI inside). Exit status: 0 success, 1 the run failed (simulation
diverged, rendering or file system error), 2 bad arguments (one line on stderr).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import tempfile
import time
from pathlib import Path
from typing import Sequence

from wpam_mj import __version__, paper, pool, studies
from wpam_mj.control import CONTROLS, check_control
from wpam_mj.experiments import EXPERIMENTS, SineSpec, check_po, simulate_for_render
from wpam_mj.model import check_dt, check_load
from wpam_mj.params import (CALIBRATION_FILE, MPA, PRESETS, ParameterError, Params, apply_overrides,
                            check_range, load_toml, preset)
from wpam_mj.simulate import SimulationDiverged


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
    return values


def _name_list(text: str) -> tuple[str, ...]:
    return tuple(v.strip() for v in text.split(",") if v.strip())


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
                   help="parallel worker processes [count] (default: the number of CPUs, "
                        f"{pool.default_jobs()}); results do not depend on it")
    g.add_argument("--progress", action=argparse.BooleanOptionalAction, default=None,
                   help="progress bars on stderr (default: when stderr is a terminal)")
    return common


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="wpam", description=__doc__,
                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--version", action="version", version=f"wpam-mj {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    common = [_common()]

    def add(name: str, help_: str, handler) -> argparse.ArgumentParser:
        p = sub.add_parser(name, help=help_, description=help_, parents=common)
        p.set_defaults(handler=handler)
        return p

    def out_dir(p: argparse.ArgumentParser, name: str) -> None:
        p.add_argument("--out", type=Path, metavar="DIR",
                       help=f"output folder (default: out/{name} under the current folder)")

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
    out_dir(p, "static")

    p = add("step", "staircase target 0 -> 50 mm in 10 mm steps of 10 s, then back to 0 "
            "(paper Figs. 12-15); CSV and PNG", _cmd_step)
    p.add_argument("--load", type=float, default=100.0, metavar="N",
                   help="hanging load [N] (default: 100)")
    p.add_argument("--control", choices=CONTROLS, default="pi",
                   help="open: Po = 0; pi/pid: feedback on Po (default: pi)")
    out_dir(p, "step")

    p = add("table2", "hysteresis-loop areas of the paper's Table 2 (open loop with and "
            "without Po = 0.04 MPa, PI feedback; 50/100/150 N), beside the paper's",
            _cmd_table2)
    p.add_argument("--json", action="store_true",
                   help="print one JSON object (normalized areas, unit-free) on stdout")
    out_dir(p, "table2")

    p = add("sweep", "frequency response to a 25 mm sinusoid about 25 mm (paper Figs. "
            "17-19): gain, phase lag, max Po", _cmd_sweep)
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
    out_dir(p, "reproduce")

    p = add("calibrate", "fit the parameters the paper does not give (braid angle, Kf, "
            "friction, axial area, regulators) to its Table 2 and findings", _cmd_calibrate)
    p.add_argument("--out", type=Path, metavar="FILE",
                   help="calibrated parameter TOML (SI units) (default: "
                        f"{CALIBRATION_FILE}, which every command then uses)")

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
    p.add_argument("--out", type=Path, metavar="FILE.mp4|FILE.gif",
                   help="video file (default: out/render/<experiment>.mp4)")
    return parser


# ------------------------------------------------------------------ helpers


@dataclasses.dataclass(frozen=True)
class _Run:
    """Options shared by every command, validated."""

    params: Params
    dt: float
    jobs: int
    progress: bool


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


def _run_options(args: argparse.Namespace) -> _Run:
    params = _params(args)
    dt = check_dt(args.dt)
    jobs = pool.check_jobs(args.jobs)
    progress = sys.stderr.isatty() if args.progress is None else args.progress
    return _Run(params, dt, jobs, progress)


def _writable_dir(path: Path) -> Path:
    """Create `path` if needed and make sure files can be written in it."""
    try:
        path.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=path):
            pass
    except OSError as err:
        raise ParameterError(f"--out {path}: cannot write there "
                             f"({err.strerror or err})") from None
    return path


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
    from wpam_mj import summaries, writers  # noqa: PLC0415
    return summaries, writers


def _loads(values: Sequence[float]) -> tuple[float, ...]:
    return tuple(check_load(v) for v in values)


def _print_json(obj) -> None:
    print(json.dumps(obj, indent=2))


def _wrote(paths: Sequence[Path]) -> None:
    for p in paths:
        print(f"wrote {p}")


# ------------------------------------------------------------------ commands


def _cmd_static(args: argparse.Namespace) -> int:
    _, writers = _output_modules()
    run = _run_options(args)
    loads = _loads(paper.LOADS_N if args.load is None else (args.load,))
    po_down = check_po("--po-down", args.po_down * MPA, run.params)
    names = PRESETS if args.compare_presets else (args.preset,)
    plist = [run.params if n == args.preset else _params(args, n) for n in names]
    out = _out_dir(args)
    loops = studies.compare_presets(plist, loads, po_down, dt=run.dt, jobs=run.jobs,
                                    progress=run.progress)
    written = writers.write_static_outputs(out, loops, compare_presets=args.compare_presets)
    print(f"loop area of x against measured Pi (Po = {args.po_down:g} MPa while Pi falls):")
    for lp in loops:
        print(f"  {lp.preset:>8} {lp.load:>6g} N: {lp.area_mpa_mm:.4g} MPa mm")
    _wrote(written)
    return 0


def _cmd_step(args: argparse.Namespace) -> int:
    summaries, writers = _output_modules()
    run = _run_options(args)
    load = check_load(args.load)
    control = check_control(args.control)
    out = _out_dir(args)
    (res,) = studies.step_study(run.params, [(load, control)], dt=run.dt, jobs=1,
                                progress=run.progress)
    written = writers.write_step_outputs(out, res)
    print(summaries.step_text(res))
    _wrote(written)
    return 0


def _cmd_table2(args: argparse.Namespace) -> int:
    summaries, writers = _output_modules()
    run = _run_options(args)
    out = _out_dir(args)
    t2 = studies.table2(run.params, dt=run.dt, jobs=run.jobs, progress=run.progress)
    written = writers.write_table2_outputs(out, t2)
    if args.json:
        _print_json(t2.as_json())
    else:
        print(summaries.table2_text(t2))
        print(summaries.checks_text(paper.table2_checks(t2)))
        _wrote(written)
    return 0


def _cmd_sweep(args: argparse.Namespace) -> int:
    summaries, writers = _output_modules()
    run = _run_options(args)
    loads = _loads(args.loads)
    freqs = tuple(SineSpec(f).freq for f in args.freqs)
    controllers = tuple(check_control(c) for c in args.controllers)
    if not controllers:
        raise ParameterError("--controllers: no controller given")
    out = _out_dir(args)
    key = studies.figure_run_key(loads, freqs, controllers)
    sw = studies.sweep(run.params, loads, freqs, controllers, keep=[key], dt=run.dt,
                       jobs=run.jobs, progress=run.progress)
    po_cap = run.params.controller.po_cap
    written = writers.write_sweep_outputs(out, sw, key, po_cap)
    if args.json:
        _print_json(sw.as_json())
    else:
        print(summaries.sweep_text(sw))
        print(summaries.checks_text(paper.sweep_checks(sw, po_cap)))
        _wrote(written)
    return 0


def _cmd_reproduce(args: argparse.Namespace) -> int:
    summaries, _ = _output_modules()
    from wpam_mj.reproduce import reproduce  # noqa: PLC0415 (matplotlib: slow import)
    run = _run_options(args)
    compare = [run.params if n == args.preset else _params(args, n)
               for n in ("mckibben", "rlam", "wpam")]
    out = _out_dir(args)
    start = time.perf_counter()
    rep = reproduce(out, run.params, dt=run.dt, jobs=run.jobs, progress=run.progress,
                    compare=compare)
    print(summaries.table2_text(rep.table2))
    print(summaries.checks_text(rep.checks))
    print(f"wrote {rep.report} ({time.perf_counter() - start:.1f} s)")
    return 0


def _cmd_calibrate(args: argparse.Namespace) -> int:
    if args.preset != "wpam":
        raise ParameterError(f"--preset {args.preset}: calibrate fits the wpam preset "
                             "(start from other values with --config)")
    run = _run_options(args)  # the search starts from the preset plus --config
    out = _out_file(CALIBRATION_FILE if args.out is None else args.out)
    from wpam_mj.calibrate import calibrate  # noqa: PLC0415 (scipy.optimize: slow import)
    result = calibrate(out=out, jobs=run.jobs, dt=run.dt, progress=run.progress,
                       start=run.params)
    print(result.table())
    return 0


def _cmd_render(args: argparse.Namespace) -> int:
    run = _run_options(args)
    load = check_load(args.load)
    control = check_control(args.control)
    spec = SineSpec(args.freq)
    duration = None if args.duration is None else \
        check_range("--duration", args.duration, 0.0, 3600.0, "s", lo_open=True)
    check_range("--fps", args.fps, 0.0, 1000.0, "1/s", lo_open=True)
    out = args.out if args.out is not None else Path("out") / "render" / f"{args.experiment}.mp4"
    if out.suffix.lower() not in (".mp4", ".gif"):
        raise ParameterError(f"--out {out}: the video must end in .mp4 or .gif")
    _out_file(out)
    result = simulate_for_render(run.params, load, args.experiment, control, spec,
                                 duration, run.dt)
    from wpam_mj.render import render_video  # noqa: PLC0415 (needs OpenGL; only here)
    try:
        path = render_video(result, run.params, out, fps=args.fps, size=args.size)
    except RuntimeError as err:
        raise RunFailed(str(err)) from None
    print(f"wrote {path} ({result.time[-1]:.2f} s of simulated time)")
    return 0


# ------------------------------------------------------------------ entry point


def _one_line(err: BaseException) -> str:
    return " ".join(str(err).split()) or type(err).__name__


def main(argv: Sequence[str] | None = None) -> int:
    """Run the `wpam` command line; returns the exit status."""
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
        return args.handler(args)
    except SystemExit as exc:  # --help, --version
        return exc.code if isinstance(exc.code, int) else 0
    except (UsageError, ParameterError) as err:
        print(f"wpam: error: {_one_line(err)}", file=sys.stderr)
        return 2
    except (SimulationDiverged, RunFailed) as err:
        print(f"wpam: error: {_one_line(err)}", file=sys.stderr)
        return 1
    except BrokenPipeError:  # stdout piped into e.g. `head`, which has exited
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # no flush error
        return 1
    except OSError as err:
        print(f"wpam: error: {_one_line(err)}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("wpam: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
