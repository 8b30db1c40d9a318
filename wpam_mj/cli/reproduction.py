"""Reproducing the paper from the command line: `wpam reproduce`, `search`, `calibrate`."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from wpam_mj import paper
from wpam_mj.cli.arguments import (feedforward_model_option, name_list, named_values,
                                   out_dir_option, out_path, protocol_options,
                                   ramp_time_option, scheduler_option)
from wpam_mj.cli.runs import (controller_model_settings, liftable_loads, out_dir_of,
                              out_file, output_modules, params_of, protocol_of,
                              protocol_settings, run_id_of, run_options, writable_dir,
                              write_run_manifest)
from wpam_mj.experiments.protocol import SHIPPED
from wpam_mj.infra.pool import Cluster
from wpam_mj.physics.muscle_types import COMPARED_TYPES
from wpam_mj.errors import ParameterError
from wpam_mj.reproduction import findings


def add_parsers(add) -> None:
    """reproduce, search, calibrate."""
    p = add("reproduce", "every experiment into one folder with report.md (figures, the "
            "paper's numbers beside ours, checks, parameters)", _cmd_reproduce)
    ramp_time_option(p)
    protocol_options(p)
    out_dir_option(p, "reproduce")
    p.add_argument("--robustness", type=int, default=0, metavar="N",
                   help="also check every finding on N plants sampled within the "
                        "uncertainty of every unmeasured value (Latin hypercube; "
                        "robustness.csv/json/png and a report.md section; default: 0)")
    robustness_options(p)
    feedforward_model_option(p, "calibrated")

    p = add("robustness", "the paper's findings over plants sampled within the uncertainty "
            "of every unmeasured plant value, the controller's model fitted to each plant's "
            "own open-loop loops (or nominal): the fraction of plants holding each finding "
            "(split by whether the feedforward's Pi over-contracts the plant), the "
            "deviations that decide it, and the spread of Table 2's cells",
            _cmd_robustness)
    p.add_argument("--samples", type=int, default=32, metavar="N",
                   help="plants to sample (default: 32)")
    robustness_options(p)
    feedforward_model_option(p, "calibrated")
    ramp_time_option(p)
    protocol_options(p)
    out_dir_option(p, "robustness")

    p = add("search", "global search of the credible parameter box and the Pi ramp top on "
            "every finding of the paper (a quasi-static screen, then differential evolution "
            "on the simulated findings); writes the best point, the convergence and the "
            "pairwise feasibility map of the findings", _cmd_search)
    p.add_argument("--out", type=out_path, metavar="DIR",
                   help="output folder (default: out/search): journal.jsonl, best.toml, "
                        "best.txt, convergence.csv, convergence.png, feasibility.md, "
                        "feasibility.png")
    p.add_argument("--seed", type=int, default=20, help="seed of the search (default: 20)")
    p.add_argument("--popsize", type=int, default=None, metavar="K",
                   help="population K x the searched coordinates (7; with --free, their count) "
                        "(default: 3)")
    p.add_argument("--maxiter", type=int, default=None, metavar="N",
                   help="generations after the first population (default: 8: at most 190 "
                        "points, those the screen rejects scored in milliseconds; "
                        "docs/physics.md gives the time)")
    p.add_argument("--objective", choices=("cost", "checks", "findings"), default="cost",
                   help="what the search minimises: calibrate's cost (default), the summed "
                        "shortfall of the paper's checks and settled PI steps (checks), or "
                        "of those and Po rising with load (findings) (docs/physics.md); "
                        "each replays any journal")
    p.add_argument("--free", metavar="NAMES",
                   help="a local search instead: only these dynamic readings (comma-"
                        "separated, e.g. pneumatics.outer_conductance,controller."
                        "po_feedforward), around the --config point, without the static "
                        "fit (the Po row's plant stays the point's)")
    p.add_argument("--radius", type=float, default=None, metavar="R",
                   help="with --free: the box is +-R of each range around the point "
                        "(default: 0.25)")
    p.add_argument("--resume", action="store_true",
                   help="continue an interrupted search in --out: journaled points are "
                        "replayed, not run again (a finished search replays in seconds); "
                        "the same --seed, --popsize, --free, --radius, --robust, "
                        "--feedforward-model and --config as the journal's (more --maxiter "
                        "extends it)")
    p.add_argument("--robust", type=int, default=0, metavar="K",
                   help="score each point as the worst over itself and K plants sampled "
                        "within +-5 %% of its unmeasured values (each with the controller's "
                        "model --feedforward-model says), so the search optimises what "
                        "survives the plant's "
                        "uncertainty; K times the runs (default: 0)")
    p.add_argument("--map-only", action="store_true",
                   help="run nothing: the best point and the feasibility map of the points "
                        "journaled in --out so far (e.g. while the search still runs)")
    feedforward_model_option(p, "calibrated", ramp_time=False)
    scheduler_option(p)

    p = add("calibrate", "fit the parameters the paper does not give (braid angle, Kf, "
            "friction, axial area, regulators) to its Table 2 and findings", _cmd_calibrate)
    p.add_argument("--out", type=out_path, metavar="FILE",
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
    ramp_time_option(p)
    protocol_options(p)
    p.add_argument("--max-steps", type=int, default=6, metavar="N",
                   help="most least-squares steps, each ~10 parameter sets (default: 6)")
    p.add_argument("--robust", type=int, default=0, metavar="K",
                   help="fit each parameter set on itself and K plants sampled within +-5 %% "
                        "of its unmeasured values, their residuals together, so that the fit "
                        "is what survives the plant's uncertainty (default: 0)")
    feedforward_model_option(p, "calibrated", ramp_time=False)
    scheduler_option(p)


def robustness_options(p) -> None:
    from wpam_mj.reproduction.robustness import DEFAULT_REL  # noqa: PLC0415
    p.add_argument("--robustness-seed", type=int, default=0, metavar="S",
                   help="seed of the plant sample (default: 0)")
    p.add_argument("--robustness-rel", type=float, default=DEFAULT_REL, metavar="R",
                   help="each unmeasured value within +-R of its nominal value "
                        f"(default: {DEFAULT_REL:g})")
    p.add_argument("--uncertainty", type=name_list, default=(), metavar="NAME=R,...",
                   help="the values you measured, each with its own relative half-width "
                        "(e.g. braid.braid_angle=0.01 for a braid angle known to +-1 %%; "
                        "0: known exactly); the others keep --robustness-rel")


def robustness_sample(args: argparse.Namespace, n: int) -> dict:
    """The keywords of `robustness.robustness` that the robustness options give."""
    return dict(n=n, seed=args.robustness_seed, rel=args.robustness_rel,
                measured=measured_of(args), feedforward=args.feedforward_model,
                calibration_ramp_time=args.calibration_ramp_time)


def measured_of(args: argparse.Namespace) -> dict[str, float]:
    """--uncertainty NAME=R items as {name: R} (checked where the sample is drawn)."""
    return named_values(args.uncertainty, "--uncertainty",
                        "NAME=R, e.g. braid.braid_angle=0.01")


def _cmd_robustness(args: argparse.Namespace) -> int:
    from wpam_mj.reproduction.robustness import (robustness,  # noqa: PLC0415 (slow imports)
                                                 write_robustness)
    run = run_options(args)
    params, protocol = protocol_of(args, run.params)
    out = out_dir_of(args)
    start = time.perf_counter()
    result = robustness(params, **robustness_sample(args, args.samples), dt=run.dt,
                        jobs=run.jobs, progress=run.progress, protocol=protocol)
    written = write_robustness(out, result)
    print(result.markdown())
    print(f"wrote {', '.join(str(p) for p in written)} ({time.perf_counter() - start:.1f} s)")
    return 0


def _cmd_reproduce(args: argparse.Namespace) -> int:
    tables, _ = output_modules()
    from wpam_mj.reproduction.reproduce import reproduce  # noqa: PLC0415 (matplotlib: slow import)
    run = run_options(args)
    params, protocol = protocol_of(args, run.params)
    compare = [params if n == args.preset else params_of(args, n) for n in COMPARED_TYPES]
    liftable_loads(paper.LOADS_N, [params], "reproduce load")
    out = out_dir_of(args)
    settings = {"compare_presets": COMPARED_TYPES, "dt_s": run.dt,
                **controller_model_settings(args), **protocol_settings(protocol)}
    rid = run_id_of(args, params, settings)
    start = time.perf_counter()
    rep = reproduce(out, params, dt=run.dt, jobs=run.jobs, progress=run.progress,
                    compare=compare, run_id=rid, protocol=protocol,
                    feedforward=args.feedforward_model,
                    calibration_ramp_time=args.calibration_ramp_time,
                    robustness_sample=robustness_sample(args, args.robustness))
    manifest = write_run_manifest(args, out, rid, params, settings, rep.files)
    print(tables.table2_text(rep.table2))
    print(findings.checks_text(rep.checks))
    print(f"wrote {rep.report} and {manifest} ({time.perf_counter() - start:.1f} s)")
    return 0


def _cmd_calibrate(args: argparse.Namespace) -> int:
    if args.preset != "wpam":
        raise ParameterError(f"--preset {args.preset}: calibrate fits the wpam preset "
                             "(start from other values with --config)")
    run = run_options(args)  # the search starts from the preset plus --config
    start, protocol = protocol_of(args, run.params)
    out = out_file(Path("calibrated.toml") if args.out is None else args.out)
    from wpam_mj.reproduction.calibrate import calibrate  # noqa: PLC0415 (scipy.optimize: slow import)
    options = {} if protocol == SHIPPED else {"protocol": protocol}  # as before: none
    if args.robust:
        options["robust"] = args.robust
    if args.feedforward_model != "calibrated":
        options["feedforward"] = args.feedforward_model
    jobs = run.jobs if args.scheduler is None else Cluster(args.scheduler)
    result = calibrate(out=out, jobs=jobs, dt=run.dt, progress=run.progress,
                       start=start, samples=args.samples, seed=args.seed,
                       max_nfev=args.max_steps, resume=args.resume, **options)
    print(result.table())
    print(f"wrote {out} (use it with --config {out})")
    return 0


def _cmd_search(args: argparse.Namespace) -> int:
    if args.preset != "wpam":
        raise ParameterError(f"--preset {args.preset}: search explores the wpam preset")
    run = run_options(args)  # the search's shipped point: the preset plus --config
    out = writable_dir(Path("out") / "search" if args.out is None else args.out)
    from wpam_mj.reproduction import search_outputs  # noqa: PLC0415 (scipy, matplotlib: slow)
    free = None if args.free is None else [n.strip() for n in args.free.split(",")]
    if free is not None and not all(free):
        raise ParameterError(f"--free {args.free!r}: give parameter names separated by "
                             "commas")
    if args.map_only:
        written = search_outputs.write_map(out, run.params, args.objective, free,
                                           args.radius)
    else:
        sizes = {k: v for k, v in (("popsize", args.popsize), ("maxiter", args.maxiter))
                 if v is not None}
        jobs = run.jobs if args.scheduler is None else Cluster(args.scheduler)
        written = search_outputs.write_search(out, base=run.params, seed=args.seed, jobs=jobs,
                                              resume=args.resume, progress=run.progress,
                                              objective=args.objective, free=free,
                                              radius=args.radius, robust=args.robust,
                                              feedforward=args.feedforward_model, **sizes)
    for path in written:
        print(f"wrote {path}")
    return 0
