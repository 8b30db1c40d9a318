"""Fitting from the command line: `wpam fit` (to your own measured experiments), `wpam synth`
(synthetic measurements in the same format)."""

from __future__ import annotations

import argparse
import math
from pathlib import Path
from typing import Sequence

from wpam_mj import paper
from wpam_mj.cli.arguments import float_list, name_list, named_values, out_path
from wpam_mj.cli.runs import liftable_loads, out_file, print_json, run_options, writable_dir, wrote
from wpam_mj.infra.files import write_text_atomic
from wpam_mj.physics.params import describe, preset
from wpam_mj.errors import ParameterError, check_range
from wpam_mj.units import MM


def add_parsers(add) -> None:
    """fit, synth."""
    from wpam_mj.fitting import measurements  # noqa: PLC0415 (its docstring is the format)
    p = add("fit", "fit the model to your own measured experiments (CSV files, format "
            "below): estimates with 1-sigma, RMS per file, a PNG per file", _cmd_fit)
    p.formatter_class = argparse.RawDescriptionHelpFormatter  # keep the format's layout
    p.epilog = measurements.__doc__.split("\n\nInside,")[0]
    p.add_argument("--data", nargs="+", required=True, metavar="FILE_OR_DIR",
                   help="measurement CSV files, or folders of them (their *.csv)")
    p.add_argument("--holdout", nargs="+", default=[], metavar="FILE_OR_DIR",
                   help="experiments replayed with the fitted values but not fitted")
    p.add_argument("--free", type=_free_names, metavar="NAME,NAME,...",
                   help="parameters to fit, as section.field (default: those the paper does "
                        "not give: braid angle, Kf, mu, F_f0, A_ax, both line conductances)")
    p.add_argument("--bounds", type=name_list, default=(), metavar="NAME=LO:HI,...",
                   help="override the bounds of free parameters [SI] (default: their "
                        "plausible ranges, listed in the package's models/README.md)")
    p.add_argument("--out", type=out_path, default=Path("out") / "fit" / "params.toml",
                   metavar="FILE.toml",
                   help="fitted parameters, a --config file for the same --preset; the "
                        "figures go next to it (default: out/fit/params.toml)")
    p.add_argument("--randomize-out", type=out_path, metavar="FILE.toml",
                   help="also write domain-randomisation ranges (estimate +- k sigma) for "
                        "wpam_mj.environments.dm_env_task.make_env(randomize=FILE)")
    p.add_argument("--randomize-k", type=float, default=2.0, metavar="K",
                   help="ranges span +- K sigma [1] (default: 2)")
    p.add_argument("--max-evals", type=int, default=60, metavar="N",
                   help="most residual evaluations of each of the two passes [count] "
                        "(default: 60)")
    p.add_argument("--json", action="store_true",
                   help="print one JSON object (estimates SI, RMS in mm) on stdout")
    p = add("synth", "write synthetic measurements (the CSV format of `wpam fit`) from the "
            "simulator: static ramps and PI staircases, PI sine runs in holdout/", _cmd_synth)
    p.add_argument("--out", type=out_path, default=Path("out") / "synth", metavar="DIR",
                   help="output folder (default: out/synth)")
    p.add_argument("--loads", type=float_list, default=paper.LOADS_N, metavar="N,N,...",
                   help="hanging loads [N] (default: 50,100,150)")
    p.add_argument("--noise-mm", type=float, default=0.0, metavar="MM",
                   help="standard deviation of the noise on x [mm] (default: 0)")
    p.add_argument("--noise-kpa", type=float, default=0.0, metavar="KPA",
                   help="standard deviation of the noise on the gauges [kPa] (default: 0)")
    p.add_argument("--seed", type=int, default=0, help="seed of the noise (default: 0)")
    p.add_argument("--sample-ms", type=float, default=1.0, metavar="MS",
                   help="logger sample period [ms], a multiple of --dt (default: 1)")


def _free_names(text: str) -> tuple[str, ...]:
    names = name_list(text)
    if not names:
        raise argparse.ArgumentTypeError(f"{text!r} names no parameter; give section.field "
                                         "names separated by commas (e.g. "
                                         "muscle.friction_coeff), or leave --free out for "
                                         "the default set")
    return names


def _bounds(items: Sequence[str], params) -> dict[str, tuple[float, float]]:
    """--bounds NAME=LO:HI items, each bound inside the parameter's allowed range."""
    def lo_hi(text: str) -> tuple[float, float]:
        lo, _, hi = text.partition(":")
        return float(lo), float(hi)

    out = named_values(items, "--bounds", "NAME=LO:HI, e.g. muscle.friction_coeff=0.05:0.4",
                       lo_hi)
    for item in items:
        name = item.partition("=")[0].strip()
        for bound in out[name]:
            try:
                params.with_values({name: bound})
            except ParameterError as err:
                raise ParameterError(f"--bounds {item}: {err}") from None
    return out


def _cmd_fit(args: argparse.Namespace) -> int:
    run = run_options(args)  # the search starts from the preset plus --config
    if not 0 < args.max_evals <= 10000:
        raise ParameterError(f"--max-evals = {args.max_evals} must be in [1, 10000]")
    k = check_range("--randomize-k", args.randomize_k, 0.0, 10.0, "")
    from wpam_mj.fitting import estimation  # noqa: PLC0415 (scipy.optimize: slow import)
    from wpam_mj.fitting import measured_fit
    from wpam_mj.fitting.measurements import experiment_files, read_experiment  # noqa: PLC0415
    data = [read_experiment(f, run.params) for f in experiment_files(args.data)]
    held = [read_experiment(f, run.params) for f in experiment_files(args.holdout)] \
        if args.holdout else []
    names = args.free or estimation.default_free()
    bounds = _bounds(args.bounds, run.params)
    for name in bounds:
        if name not in names:
            raise ParameterError(f"--bounds {name}: not a free parameter (free: "
                                 f"{', '.join(names)})")
    free = [estimation.FreeParameter.of(n, bounds.get(n)) for n in names]
    out = out_file(args.out)
    if args.randomize_out is not None:
        out_file(args.randomize_out)
    result = measured_fit.fit_data(run.params, data, free, holdout=held, dt=run.dt,
                                   jobs=run.jobs, max_nfev=args.max_evals, progress=run.progress)
    header = (f"Fitted by `wpam fit --preset {args.preset}` to "
              + ", ".join(e.name for e in data) + f"; use with --preset {args.preset}.")
    written = [write_text_atomic(out, measured_fit.params_toml(result.params, preset(args.preset),
                                                               result, header))]
    if args.randomize_out is not None:
        from wpam_mj.fitting.randomize import ParameterRanges  # noqa: PLC0415
        ranges = ParameterRanges.from_estimates(result.result.estimates, k)
        written.append(write_text_atomic(args.randomize_out, ranges.toml(
            f"wpam fit: estimates +- {k:g} sigma, clipped to the fit bounds.")))
    written += measured_fit.write_figures(result, out.parent)
    if args.json:
        print_json(result.as_json())
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
    wrote(written)
    return 0


def _cmd_synth(args: argparse.Namespace) -> int:
    run = run_options(args)
    out = writable_dir(args.out)
    sample_dt = check_range("--sample-ms", args.sample_ms, 0.001, 1000.0, "ms") * 1e-3
    from wpam_mj.fitting.synthetic import synth  # noqa: PLC0415
    paths = synth(run.params, out, loads=liftable_loads(args.loads, [run.params], "--loads"),
                  noise_mm=args.noise_mm,
                  noise_kpa=args.noise_kpa, seed=args.seed, sample_dt=sample_dt, dt=run.dt,
                  jobs=run.jobs, progress=run.progress)
    wrote(paths)
    return 0
