"""`wpam`: the paper's experiments from the command line.

Subcommands (each has --help):
  static     open-loop Pi ramp up and down (paper Figs. 3, 8, 9)
  step       staircase target 0 -> 50 -> 0 mm (Figs. 12-15)
  table2     hysteresis-loop areas of Table 2, beside the paper's
  sweep      frequency response to a sinusoidal target (Figs. 17-19)
  reproduce  all of the above into one folder with report.md
  calibrate  fit the parameters the paper does not give
  fit        fit the parameters to your own measured experiments (CSV)
  synth      synthetic measurements in that CSV format
  render     offscreen video of a simulated run

Units at this edge: loads in N, pressures in MPa, lengths in mm, times in s, frequencies
in Hz (the library is SI inside). Exit status: 0 success, 1 the run failed (simulation
diverged, rendering or file system error), 2 bad arguments (one line on stderr).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import sys
import tempfile
import time
from pathlib import Path
from typing import Sequence

from wpam_mj import __version__, paper, studies
from wpam_mj.control import CONTROLS, check_control
from wpam_mj.experiments import SineSpec, check_po, sine_run, static_loop, step_run
from wpam_mj.model import check_dt, check_load
from wpam_mj.paper import STEP_HOLD_S, STEP_LEVELS_MM
from wpam_mj.params import (CALIBRATION_FILE, MM, MPA, PRESETS, ParameterError, Params,
                            apply_overrides, check_range, describe, load_toml, preset)
from wpam_mj.results import SimResult, write_text_atomic
from wpam_mj.simulate import SimulationDiverged

EXPERIMENTS = ("step", "sweep", "static")  # for `wpam render`


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
    g.add_argument("--jobs", type=int, default=studies.default_jobs(), metavar="N",
                   help="parallel worker processes [count] (default: the number of CPUs, "
                        f"{studies.default_jobs()}); results do not depend on it")
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
    _add_fit_parser(add)
    _add_synth_parser(add)
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
    jobs = studies.check_jobs(args.jobs)
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
    """`plots` and `report` (matplotlib): imported only by commands that write figures,
    so that --help and argument errors stay quick."""
    from wpam_mj import plots, report  # noqa: PLC0415
    return plots, report


def _loads(values: Sequence[float]) -> tuple[float, ...]:
    return tuple(check_load(v) for v in values)


def _print_json(obj) -> None:
    print(json.dumps(obj, indent=2))


def _wrote(paths: Sequence[Path]) -> None:
    for p in paths:
        print(f"wrote {p}")


# ------------------------------------------------------------------ commands


def _cmd_static(args: argparse.Namespace) -> int:
    plots, report = _output_modules()
    run = _run_options(args)
    loads = _loads(paper.LOADS_N if args.load is None else (args.load,))
    po_down = check_po("--po-down", args.po_down * MPA, run.params)
    names = PRESETS if args.compare_presets else (args.preset,)
    plist = [run.params if n == args.preset else _params(args, n) for n in names]
    out = _out_dir(args)
    loops = studies.compare_presets(plist, loads, po_down, dt=run.dt, jobs=run.jobs,
                                    progress=run.progress)
    written = [lp.result.to_csv(out / report.static_csv_name(lp)) for lp in loops]
    po = "" if po_down == 0.0 else f"_po{args.po_down:g}MPa"
    stem = "static_presets" if args.compare_presets else f"static_{args.preset}"
    written.append(plots.save_figure(plots.static_figure(loops), out / f"{stem}{po}.png"))
    print(f"loop area of x against measured Pi (Po = {args.po_down:g} MPa while Pi falls):")
    for lp in loops:
        print(f"  {lp.preset:>8} {lp.load:>6g} N: {lp.area_mpa_mm:.4g} MPa mm")
    _wrote(written)
    return 0


def _cmd_step(args: argparse.Namespace) -> int:
    plots, report = _output_modules()
    run = _run_options(args)
    load = check_load(args.load)
    control = check_control(args.control)
    out = _out_dir(args)
    (res,) = studies.step_study(run.params, [(load, control)], dt=run.dt, jobs=1,
                                progress=run.progress)
    name = report.step_csv_name(res)
    written = [res.result.to_csv(out / name),
               plots.save_figure(plots.step_figure([res.result]),
                                 out / name.replace(".csv", ".png"))]
    print(report.step_text(res))
    _wrote(written)
    return 0


def _cmd_table2(args: argparse.Namespace) -> int:
    plots, report = _output_modules()
    run = _run_options(args)
    out = _out_dir(args)
    t2 = studies.table2(run.params, dt=run.dt, jobs=run.jobs, progress=run.progress)
    written = [*report.write_table2(out, t2),
               plots.save_figure(plots.table2_figure(t2), out / "table2.png")]
    if args.json:
        _print_json(t2.as_json())
    else:
        print(report.table2_text(t2))
        print(report.checks_text(report.table2_checks(t2)))
        _wrote(written)
    return 0


def _cmd_sweep(args: argparse.Namespace) -> int:
    plots, report = _output_modules()
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
    load, freq, ctrl = key
    written = [
        *report.write_sweep(out, sw),
        plots.save_figure(plots.sweep_figure(sw), out / "sweep_gain_phase.png"),
        sw.series[key].to_csv(out / report.sine_csv_name(key)),
        plots.save_figure(plots.sine_figure(sw.series[key], freq, run.params.controller.po_cap),
                          out / report.sine_csv_name(key).replace(".csv", ".png")),
    ]
    if args.json:
        _print_json(sw.as_json())
    else:
        print(report.sweep_text(sw))
        print(report.checks_text(report.sweep_checks(sw, run.params.controller.po_cap)))
        _wrote(written)
    return 0


def _cmd_reproduce(args: argparse.Namespace) -> int:
    _, report = _output_modules()
    run = _run_options(args)
    compare = [run.params if n == args.preset else _params(args, n)
               for n in ("mckibben", "rlam", "wpam")]
    out = _out_dir(args)
    start = time.perf_counter()
    rep = report.reproduce(out, run.params, dt=run.dt, jobs=run.jobs, progress=run.progress,
                           compare=compare)
    print(report.table2_text(rep.table2))
    print(report.checks_text(rep.checks))
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


def simulate_for_render(params: Params, load: float, experiment: str, control: str,
                        spec: SineSpec, duration: float | None, dt: float) -> SimResult:
    """Run `experiment` for at least `duration` [s] (when it can be shortened) and
    truncate the result to `duration` (None: the whole run)."""
    if experiment == "step":
        levels = STEP_LEVELS_MM if duration is None else \
            STEP_LEVELS_MM[:max(1, math.ceil(duration / STEP_HOLD_S))]
        result = step_run(params, load, control, levels_mm=levels, dt=dt)
    elif experiment == "sweep":
        if duration is not None:  # as many cycles as the video shows, from rest
            spec = dataclasses.replace(spec, settle_cycles=0,
                                       cycles=max(1, math.ceil(duration * spec.freq)))
        result = sine_run(params, load, control, spec, dt=dt)
    elif experiment == "static":
        result = static_loop(params, load, dt=dt)
    else:
        raise ParameterError(f"unknown experiment {experiment!r}; valid: "
                             + ", ".join(EXPERIMENTS))
    if duration is not None:
        keep = result.time <= duration + 1e-9
        result = dataclasses.replace(result, **{k: v[keep]
                                                for k, v in result.arrays().items()})
    return result


# ------------------------------------------------------------------ fit and synth


def _add_fit_parser(add) -> None:
    p = add("fit", "fit the model to your own measured experiments (CSV files, format in "
            "docs/fitting.md): estimates with 1-sigma, RMS per file, a PNG per file",
            _cmd_fit)
    p.add_argument("--data", nargs="+", required=True, metavar="FILE_OR_DIR",
                   help="measurement CSV files, or folders of them (their *.csv)")
    p.add_argument("--holdout", nargs="+", default=[], metavar="FILE_OR_DIR",
                   help="experiments replayed with the fitted values but not fitted")
    p.add_argument("--free", type=_name_list, metavar="NAME,NAME,...",
                   help="parameters to fit, as section.field (default: those the paper does "
                        "not give: braid angle, Kf, mu, F_f0, A_ax, both line conductances)")
    p.add_argument("--bounds", type=_name_list, default=(), metavar="NAME=LO:HI,...",
                   help="override the bounds of free parameters [SI] (default: their "
                        "plausible ranges, docs/fitting.md)")
    p.add_argument("--out", type=Path, default=Path("out") / "fit" / "params.toml",
                   metavar="FILE.toml",
                   help="fitted parameters, a --config file for the same --preset; the "
                        "figures go next to it (default: out/fit/params.toml)")
    p.add_argument("--randomize-out", type=Path, metavar="FILE.toml",
                   help="also write domain-randomisation ranges (estimate +- k sigma) for "
                        "wpam_mj.env.make_env(randomize=FILE)")
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
    from wpam_mj import datafit, fitting  # noqa: PLC0415 (scipy.optimize: slow import)
    from wpam_mj.measurements import experiment_files, read_experiment  # noqa: PLC0415
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
        from wpam_mj.randomize import ParameterRanges  # noqa: PLC0415
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
    p.add_argument("--out", type=Path, default=Path("out") / "synth", metavar="DIR",
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
    from wpam_mj.synth import synth  # noqa: PLC0415
    paths = synth(run.params, out, loads=_loads(args.loads), noise_mm=args.noise_mm,
                  noise_kpa=args.noise_kpa, seed=args.seed, sample_dt=sample_dt, dt=run.dt,
                  jobs=run.jobs, progress=run.progress)
    _wrote(paths)
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
