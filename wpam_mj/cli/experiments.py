"""The paper's experiments from the command line: `wpam static`, `step`, `table2`, `sweep`."""

from __future__ import annotations

import argparse
import dataclasses

from wpam_mj import paper
from wpam_mj.cli.arguments import (feedforward_model_option, float_list, json_option,
                                   loop_area_option, name_list, out_dir_option,
                                   ramp_time_option)
from wpam_mj.cli.runs import (amplitude_m, controller_model_of, controller_model_settings,
                              note_still_loads, flag_unsettled, liftable_loads, out_dir_of,
                              output_modules, params_of, print_json, run_id_of, run_options,
                              settled, write_run_manifest, wrote)
from wpam_mj.control.controllers import CONTROLS, check_control
from wpam_mj.experiments import paper_studies
from wpam_mj.experiments.drives import SINE_AMPLITUDE_MM, SINE_MEAN_MM, SineSpec, check_po
from wpam_mj.experiments.feasibility import load_moved
from wpam_mj.experiments.protocol import SHIPPED, table2_batch
from wpam_mj.physics.params import PRESETS
from wpam_mj.errors import ParameterError
from wpam_mj.units import MM, MPA
from wpam_mj.reproduction import findings
from wpam_mj.simulation.execution import execute


def add_parsers(add) -> None:
    """static, step, table2, sweep."""
    p = add("static", "open-loop static characteristic: slow Pi ramp up then down "
            "(paper Figs. 3, 8, 9); CSV, PNG and loop areas", _cmd_static)
    p.add_argument("--load", type=float, metavar="N",
                   help="hanging load [N] (default: each of the paper's 50, 100, 150 N)")
    p.add_argument("--po-down", type=float, default=0.0, metavar="MPA",
                   help="constant external pressure Po while Pi falls [MPa]: 0 = vented "
                        "(Fig. 8, default) or 0.005-0.5 (Fig. 9 uses 0.04)")
    p.add_argument("--compare-presets", action="store_true",
                   help=f"run {', '.join(PRESETS[:-1])} and {PRESETS[-1]} and overlay them "
                        "in one figure (paper Fig. 3)")
    ramp_time_option(p)
    json_option(p, "a JSON list of {preset, load_n [N], po_down_mpa [MPa], area_mpa_mm "
              "[MPa mm], load_moved}")
    out_dir_option(p, "static")

    p = add("step", "staircase target 0 -> 50 mm in 10 mm steps of 10 s, then back to 0 "
            "(paper Figs. 12-15); CSV and PNG", _cmd_step)
    p.add_argument("--load", type=float, default=100.0, metavar="N",
                   help="hanging load [N] (default: 100)")
    p.add_argument("--control", choices=CONTROLS, default="pi",
                   help="open: Po = 0; pi/pid: feedback on Po (default: pi)")
    json_option(p, "one JSON object: the run's settings, load_moved, plateaus_settled (x "
              "moved < 1 mm peak to peak where the means average) and its plateau means "
              "(target_mm, x_mm, error_mm, pi_mpa, po_mpa: chamber pressures)")
    feedforward_model_option(p, "nominal")
    out_dir_option(p, "step")

    p = add("table2", "hysteresis-loop areas of the paper's Table 2 (open loop with and "
            "without Po = 0.04 MPa, PI feedback; 50/100/150 N), beside the paper's",
            _cmd_table2)
    p.add_argument("--json", action="store_true",
                   help="print one JSON object (normalized areas, unit-free) on stdout")
    ramp_time_option(p)
    loop_area_option(p)
    feedforward_model_option(p, "nominal")
    out_dir_option(p, "table2")

    p = add("sweep", "frequency response to a sinusoid about 25 mm, 25 mm amplitude unless "
            "--amplitude (paper Figs. 17-19): gain, phase lag, max Po", _cmd_sweep)
    p.add_argument("--amplitude", type=float, default=SINE_AMPLITUDE_MM, metavar="MM",
                   help=f"amplitude of the sinusoidal target [mm], in (0, {SINE_MEAN_MM:g}] "
                        f"(default: the paper's {SINE_AMPLITUDE_MM:g})")
    p.add_argument("--loads", type=float_list, default=paper.LOADS_N,
                   metavar="N,N,...", help="hanging loads [N] (default: 50,100,150)")
    p.add_argument("--freqs", type=float_list, default=paper.SWEEP_FREQS_HZ,
                   metavar="HZ,HZ,...",
                   help="target frequencies [Hz], each > 0 (default: 0.1,0.2,0.25,0.5,1.0)")
    p.add_argument("--controllers", type=name_list, default=paper.SWEEP_CONTROLLERS,
                   metavar="C,C", help="feedback controllers, of " + ", ".join(CONTROLS)
                   + " (default: pi,pid)")
    p.add_argument("--json", action="store_true",
                   help="print a JSON list of {load_n [N], freq_hz [Hz], controller, gain [1],"
                        " phase_lag_deg [deg], po_max_mpa [MPa]} on stdout")
    feedforward_model_option(p, "nominal")
    out_dir_option(p, "sweep")


def _cmd_static(args: argparse.Namespace) -> int:
    _, writers = output_modules()
    run = run_options(args)
    names = PRESETS if args.compare_presets else (args.preset,)
    plist = [run.params if n == args.preset else params_of(args, n) for n in names]
    loads = liftable_loads(paper.LOADS_N if args.load is None else (args.load,), plist)
    po_down = check_po("--po-down", args.po_down * MPA, run.params)
    ramp_time = args.ramp_time  # ranged in run_options
    out = out_dir_of(args)
    loops = paper_studies.compare_presets(plist, loads, po_down, dt=run.dt,
                                    jobs=run.jobs_for(len(plist) * len(loads)),
                                    progress=run.progress, ramp_time=ramp_time)
    settings = {"presets": names, "loads_n": loads, "po_down_mpa": args.po_down,
                "ramp_time_s": ramp_time, "dt_s": run.dt}
    rid = run_id_of(args, run.params, settings)
    written = writers.write_static_outputs(out, loops, compare_presets=args.compare_presets,
                                           run_id=rid)
    manifest = write_run_manifest(args, out, rid, run.params, settings, written)
    moved = [load_moved(lp.result) for lp in loops]
    if args.json:
        print_json([{"preset": lp.preset, "load_n": lp.load, "po_down_mpa": lp.po_down / MPA,
                      "area_mpa_mm": lp.area_mpa_mm, "load_moved": m, "run_id": rid}
                     for lp, m in zip(loops, moved)])
    else:
        print(f"loop area of x against measured Pi (Po = {args.po_down:g} MPa while Pi "
              f"falls, {ramp_time:g} s ramps):")
        for lp in loops:
            print(f"  {lp.preset:>8} {lp.load:>6g} N: {lp.area_mpa_mm:.4g} MPa mm")
    note_still_loads([(f"static {lp.preset} {lp.load:g} N", m) for lp, m in zip(loops, moved)],
                args.json)
    if not args.json:
        wrote([*written, manifest])
    return 0


def _cmd_step(args: argparse.Namespace) -> int:
    tables, writers = output_modules()
    run = run_options(args)
    (load,) = liftable_loads((args.load,), [run.params])
    control = check_control(args.control)
    out = out_dir_of(args)
    params, _ = controller_model_of(args, run) if control != "open" else (run.params, ())
    (res,) = paper_studies.step_study(params, [(load, control)], dt=run.dt, jobs=1,
                                      progress=run.progress)
    settings = {"load_n": load, "control": control, "dt_s": run.dt,
                **controller_model_settings(args)}
    rid = run_id_of(args, run.params, settings)
    written = writers.write_step_outputs(out, res, run_id=rid)
    manifest = write_run_manifest(args, out, rid, run.params, settings, written)
    moved = load_moved(res.result)
    if args.json:
        print_json({"preset": res.preset, "load_n": res.load, "control": res.control,
                     "settle_s": res.settle, "load_moved": moved,
                     "plateaus_settled": settled(res), "run_id": rid,
                     "plateaus": [{"target_mm": tg / MM, "x_mm": x / MM,
                                   "error_mm": (x - tg) / MM, "pi_mpa": pi / MPA,
                                   "po_mpa": po / MPA}
                                  for tg, x, pi, po in zip(res.target, res.x_mean,
                                                           res.pi_mean, res.po_mean)]})
    else:
        print(tables.step_text(res))
    note_still_loads([(f"step {res.preset} {load:g} N {control}", moved)], args.json)
    flag_unsettled(f"step {res.preset} {load:g} N {control}", res, args.json)
    if not args.json:
        wrote([*written, manifest])
    return 0


def _cmd_table2(args: argparse.Namespace) -> int:
    tables, writers = output_modules()
    run = run_options(args)
    liftable_loads(paper.LOADS_N, [run.params], "Table 2 load")
    ramp_time = args.ramp_time  # ranged in run_options
    out = out_dir_of(args)
    loop_area = args.loop_area or SHIPPED.loop_method
    protocol = dataclasses.replace(SHIPPED, ramp_time=ramp_time, loop_method=loop_area)
    params, open_loops = controller_model_of(args, run, protocol)
    (t2,) = execute([table2_batch(params, protocol, dt=run.dt, open_loops=open_loops)],
                    run.jobs_for(3 * len(paper.LOADS_N)), progress=run.progress, desc="table 2")
    settings = {"ramp_time_s": ramp_time, "ramp_top_mpa": protocol.ramp_top / MPA,
                "dt_s": run.dt, "loop_area": loop_area,
                **controller_model_settings(args)}
    rid = run_id_of(args, run.params, settings)
    written = writers.write_table2_outputs(out, t2, run_id=rid)
    still = [(f"table2 open loop {lp.load:g} N, Po = {lp.po_down / MPA:g} MPa while Pi falls",
              load_moved(lp.result)) for lp in (*t2.open_loops, *t2.po_loops)]
    still += [(f"table2 PI {f.load:g} N", load_moved(f.result)) for f in t2.feedback_runs]
    moved = {name: m for name, m in still}
    written = {path: ({"load_moved": moved} if path.suffix in (".json", ".csv") else meta)
               for path, meta in written.items()}
    manifest = write_run_manifest(args, out, rid, run.params, settings, written)
    if args.json:
        print_json(t2.as_json())
    else:
        print(tables.table2_text(t2))
        print(findings.checks_text(findings.table2_checks(t2)))
    note_still_loads(still, args.json)
    if not args.json:
        wrote([*written, manifest])
    return 0


def _cmd_sweep(args: argparse.Namespace) -> int:
    tables, writers = output_modules()
    run = run_options(args)
    loads = liftable_loads(args.loads, [run.params], "--loads")
    amplitude = amplitude_m("--amplitude", args.amplitude)
    freqs = tuple(SineSpec(f).freq for f in args.freqs)
    controllers = tuple(check_control(c) for c in args.controllers)
    if not controllers:
        raise ParameterError("--controllers: no controller given; valid: "
                             + ", ".join(CONTROLS))
    out = out_dir_of(args)
    key = paper_studies.figure_run_key(loads, freqs, controllers)
    params, _ = controller_model_of(args, run)
    sw = paper_studies.sweep(params, loads, freqs, controllers, keep=[key], dt=run.dt,
                       jobs=run.jobs_for(len(loads) * len(freqs) * len(controllers)),
                       progress=run.progress, amplitude=amplitude)
    settings = {"loads_n": loads, "freqs_hz": freqs, "controllers": controllers,
                "amplitude_mm": amplitude / MM, "dt_s": run.dt,
                **controller_model_settings(args)}
    rid = run_id_of(args, run.params, settings)
    written = writers.write_sweep_outputs(out, sw, key, run_id=rid)
    manifest = write_run_manifest(args, out, rid, run.params, settings, written)
    if args.json:
        print_json(sw.as_json())
    else:
        print(tables.sweep_text(sw))
        print(findings.checks_text(findings.sweep_checks(sw)))
    note_still_loads([(f"sweep {point}", False) for point in writers.still_points(sw)], args.json)
    if not args.json:
        wrote([*written, manifest])
    return 0
