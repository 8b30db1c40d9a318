"""`wpam`: the paper's experiments from the command line.

Subcommands (each has --help):
  static     open-loop Pi ramp up and down (paper Figs. 3, 8, 9)
  step       staircase target 0 -> 50 -> 0 mm (Figs. 12-15)
  table2     hysteresis-loop areas of Table 2, beside the paper's
  sweep      frequency response to a sinusoidal target (Figs. 17-19)
  reproduce  all of the above into one folder with report.md
  calibrate  fit the parameters the paper does not give
  render     offscreen video of a simulated run
  view       MuJoCo's interactive viewer on the muscle, stepped live (needs a display)
  linear     the paper's §3 linear model beside the simulated frequency response
  study      a design-space study from a study file, on local processes or Dask

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
from wpam_mj.experiments import (EXPERIMENTS, SINE_AMPLITUDE_MM, SINE_MEAN_MM, SineSpec,
                                 check_po, simulate_for_render)
from wpam_mj.model import check_dt, check_load
from wpam_mj.params import (CALIBRATION_FILE, MM, MPA, PRESETS, ParameterError, Params,
                            apply_overrides, check_range, load_toml, preset)
from wpam_mj.results import write_text_atomic
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
    _add_view_parser(add)
    _add_linear_parser(add("linear", "the paper's §3 linear model (and an extended one) "
                           "at an operating point: poles, margins, DC gains, and its Bode "
                           "plot beside the simulated frequency response", _cmd_linear))
    _add_study_parser(sub)
    return parser


def _add_view_parser(add) -> None:
    p = add("view", "MuJoCo's interactive viewer on the hung muscle, stepped live by the "
            "simulation loop; pull the load with Ctrl + right drag (needs a display)",
            _cmd_view)
    p.add_argument("--load", type=float, default=100.0, metavar="N",
                   help="hanging load [N] (default: 100)")
    p.add_argument("--control", choices=CONTROLS, default="pi",
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
    p.add_argument("--out", type=Path, metavar="DIR",
                   help="output folder (default: out/linear under the current folder)")


def _add_study_parser(sub) -> None:
    from wpam_mj.executors import SCHEDULER_ENV  # noqa: PLC0415 (the study's own modules)
    p = sub.add_parser("study", help="a design-space study: the runs of a study file "
                       "(grid, list, random or Latin-hypercube sample), one table row each",
                       description="Run a study file (see examples/ and the README) and "
                       "write study.csv (+ study.parquet with pyarrow) and plots/.")
    p.set_defaults(handler=_cmd_study)
    p.add_argument("spec", type=Path, metavar="SPEC.toml", help="the study file")
    p.add_argument("--out", type=Path, metavar="DIR",
                   help="output folder (default: out/study/<SPEC name>)")
    p.add_argument("--jobs", type=int, default=pool.default_jobs(), metavar="N",
                   help="local worker processes [count] (default: the number of CPUs, "
                        f"{pool.default_jobs()}); results do not depend on it")
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="run on the Dask cluster of this scheduler, e.g. tcp://host:8786 "
                        f"(default: ${SCHEDULER_ENV} if set, else local processes)")
    p.add_argument("--resume", action="store_true",
                   help="keep the runs an interrupted study in --out has finished")
    p.add_argument("--progress", action=argparse.BooleanOptionalAction, default=None,
                   help="progress bar with time left on stderr (default: when stderr is a "
                        "terminal)")


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


def _amplitude(name: str, mm: float) -> float:
    """A sine amplitude [m] from mm: the target must stay at or above 0 mm."""
    return check_range(name, mm, 0.0, SINE_MEAN_MM, "mm", lo_open=True) * MM


def _cmd_sweep(args: argparse.Namespace) -> int:
    summaries, writers = _output_modules()
    run = _run_options(args)
    loads = _loads(args.loads)
    amplitude = _amplitude("--amplitude", args.amplitude)
    freqs = tuple(SineSpec(f).freq for f in args.freqs)
    controllers = tuple(check_control(c) for c in args.controllers)
    if not controllers:
        raise ParameterError("--controllers: no controller given")
    out = _out_dir(args)
    key = studies.figure_run_key(loads, freqs, controllers)
    sw = studies.sweep(run.params, loads, freqs, controllers, keep=[key], dt=run.dt,
                       jobs=run.jobs, progress=run.progress, amplitude=amplitude)
    po_cap = run.params.controller.po_cap
    written = writers.write_sweep_outputs(out, sw, key, po_cap)
    if args.json:
        _print_json(sw.as_json())
    else:
        print(summaries.sweep_text(sw))
        print(summaries.checks_text(paper.sweep_checks(sw, po_cap)))
        _wrote(written)
    return 0


def _cmd_linear(args: argparse.Namespace) -> int:
    from wpam_mj import linear_study, plots  # noqa: PLC0415 (python-control, matplotlib: slow)
    run = _run_options(args)
    load = check_load(args.load)
    amplitudes = tuple(_amplitude("--amplitudes", a) for a in
                       (args.amplitudes or linear_study.AMPLITUDES_MM))
    out = _out_dir(args)
    (cmp,) = linear_study.compare(run.params, (load,), contraction=args.contraction * MM,
                                  amplitudes=amplitudes, dt=run.dt, jobs=run.jobs,
                                  progress=run.progress)
    stem = f"linear_{load:g}N"
    written = [plots.save_figure(cmp.plot(), out / f"{stem}.png"),
               write_text_atomic(out / f"{stem}.csv", cmp.csv_text())]
    if args.json:
        _print_json(cmp.as_json())
    else:
        print(cmp.text())
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


def _cmd_view(args: argparse.Namespace) -> int:
    from wpam_mj import viewer  # noqa: PLC0415 (GLFW viewer; only here)

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
    from wpam_mj import study  # noqa: PLC0415 (the study's own modules)
    from wpam_mj.executors import open_workers  # noqa: PLC0415
    spec = study.load_spec(args.spec)
    out = _writable_dir(args.out if args.out is not None
                        else Path("out") / "study" / args.spec.stem)
    progress = sys.stderr.isatty() if args.progress is None else args.progress
    start = time.perf_counter()
    with open_workers(pool.check_jobs(args.jobs), args.scheduler) as workers:
        res = study.run_study(spec, out, workers, resume=args.resume, progress=progress)
    flagged = sum(r["diverged"] or r["infeasible"] for r in res.rows)
    print(f"{len(res.rows)} runs ({res.ran} run now on {workers.where}, {res.reused} "
          f"resumed, {flagged} diverged or infeasible) in {time.perf_counter() - start:.1f} s")
    from wpam_mj.study_plots import save_study_plots  # noqa: PLC0415 (matplotlib: slow)
    _wrote([*res.files, *save_study_plots(spec, res.rows, out / "plots")])
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
