"""Design studies from the command line: `wpam linear` (the linear models beside the
simulation), `wpam study` (a design-space study from a study file)."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from wpam_mj.cli.arguments import JOBS_HELP, float_list, out_path, scheduler_option
from wpam_mj.cli.runs import (amplitude_m, note_still_loads, jobs_option, out_dir_of, print_json,
                              run_id_of, run_options, writable_dir, write_run_manifest, wrote)
from wpam_mj.experiments.drives import SINE_MEAN_MM
from wpam_mj.infra import pool
from wpam_mj.infra.files import write_text_atomic
from wpam_mj.errors import ParameterError
from wpam_mj.units import MM
from wpam_mj.simulation.context import check_load


def add_parsers(add, sub) -> None:
    """linear, and study (whose file sets its own model and run options)."""
    p = add("linear", "the paper's §3 linear model (and an extended one) at an operating "
            "point: poles, margins, DC gains, and its Bode plot beside the simulated "
            "frequency response", _cmd_linear)
    p.add_argument("--load", type=float, default=100.0, metavar="N",
                   help="hanging load [N] (default: 100)")
    p.add_argument("--contraction", type=float, default=SINE_MEAN_MM, metavar="MM",
                   help=f"operating contraction [mm] (default: {SINE_MEAN_MM:g}, the mean "
                        "the simulated sweeps always run about)")
    p.add_argument("--amplitudes", type=float_list, default=None, metavar="MM,MM",
                   help="amplitudes of the simulated sweeps [mm] (default: the paper's 25 "
                        "and a small one, 5)")
    p.add_argument("--json", action="store_true",
                   help="print one JSON object (operating point, poles, margins, DC gains, "
                        "comparison rows) on stdout")
    p.add_argument("--out", type=out_path, metavar="DIR",
                   help="output folder (default: out/linear under the current folder)")
    p = sub.add_parser("study", help="a design-space study: the runs of a study file "
                       "(grid, list, random or Latin-hypercube sample), one table row each",
                       description="Run a study file (see examples/ and the README) and "
                       "write study.csv (+ study.parquet with pyarrow) and plots/.")
    p.set_defaults(handler=_cmd_study)
    p.add_argument("spec", type=Path, metavar="SPEC.toml", help="the study file")
    p.add_argument("--out", type=out_path, metavar="DIR",
                   help="output folder (default: out/study/<SPEC name>)")
    p.add_argument("--jobs", type=int, default=pool.default_jobs(), metavar="N",
                   help=JOBS_HELP)
    scheduler_option(p)
    p.add_argument("--resume", action="store_true",
                   help="keep the runs an interrupted study in --out has finished")
    p.add_argument("--progress", action=argparse.BooleanOptionalAction, default=None,
                   help="progress bar with time left on stderr (default: when stderr is a "
                        "terminal)")
    for name in ("--preset", "--dt", "--config"):  # refused in _cmd_study, with the reason
        p.add_argument(name, help=argparse.SUPPRESS)


def _cmd_linear(args: argparse.Namespace) -> int:
    from wpam_mj.design import linear_study
    from wpam_mj.experiments import figures, writers  # noqa: PLC0415 (control, matplotlib: slow)
    run = run_options(args)
    load = check_load(args.load)
    amplitudes = tuple(amplitude_m("--amplitudes", a) for a in
                       (args.amplitudes or linear_study.AMPLITUDES_MM))
    out = out_dir_of(args)
    (cmp,) = linear_study.compare(run.params, (load,), contraction=args.contraction * MM,
                                  amplitudes=amplitudes, dt=run.dt, jobs=run.jobs,
                                  progress=run.progress)
    settings = {"load_n": load, "contraction_mm": args.contraction,
                "amplitudes_mm": [a / MM for a in amplitudes], "dt_s": run.dt}
    rid = run_id_of(args, run.params, settings)
    stem = f"linear_{load:g}N"
    still = cmp.still_points()
    figure = writers.mark_still_on_figure(cmp.plot(), still)
    written = {figures.save_figure(figure, out / f"{stem}.png", run_id=rid): {},
               write_text_atomic(out / f"{stem}.csv", cmp.csv_text()): {"load_moved": not still}}
    manifest = write_run_manifest(args, out, rid, run.params, settings, written)
    if args.json:
        print_json(cmp.as_json())
    else:
        print(cmp.text())
    note_still_loads([(f"linear {point}", False) for point in still], args.json)
    if not args.json:
        wrote([*written, manifest])
    return 0


def _cmd_study(args: argparse.Namespace) -> int:
    from wpam_mj.design import study, study_spec  # noqa: PLC0415 (the study's own modules)
    from wpam_mj.infra.pool import open_workers  # noqa: PLC0415
    given = [f"--{n}" for n in ("preset", "dt", "config") if getattr(args, n) is not None]
    if given:
        raise ParameterError(f"{', '.join(given)}: a study file sets its own preset, dt and "
                             "parameters (preset = \"rlam\", dt = 5e-4, [fixed] "
                             "\"section.field\" = value)")
    jobs = jobs_option(args.jobs)
    spec = study_spec.load_spec(args.spec)
    out = writable_dir(args.out if args.out is not None
                        else Path("out") / "study" / args.spec.stem)
    progress = sys.stderr.isatty() if args.progress is None else args.progress
    start = time.perf_counter()
    with open_workers(jobs, args.scheduler) as workers:
        res = study.run_study(spec, out, workers, resume=args.resume, progress=progress)
    flagged = sum(r["diverged"] or r["infeasible"] for r in res.rows)
    print(f"{len(res.rows)} runs ({res.ran} run now on {workers.where}, {res.reused} "
          f"resumed, {flagged} diverged or infeasible) in {time.perf_counter() - start:.1f} s")
    from wpam_mj.design.figures import save_study_plots  # noqa: PLC0415 (matplotlib: slow)
    wrote([*res.files, *save_study_plots(spec, res.rows, out / "plots")])
    return 0
