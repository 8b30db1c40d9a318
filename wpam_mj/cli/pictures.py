"""Pictures of runs from the command line: `wpam render` (offscreen video), `wpam view`
(MuJoCo's interactive viewer, stepped live)."""

from __future__ import annotations

import argparse
from pathlib import Path

from wpam_mj.cli.arguments import frame_size, out_path
from wpam_mj.cli.runs import (RunFailed, liftable_loads, out_file, output_modules, run_id_of,
                              run_options, write_run_manifest)
from wpam_mj.control.controllers import CONTROLS, check_control
from wpam_mj.experiments.drives import EXPERIMENTS, SineSpec, simulate_for_render
from wpam_mj.infra.budget import check_video
from wpam_mj.errors import ParameterError, check_range


def add_parsers(add) -> None:
    """render, view."""
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
    p.add_argument("--size", type=frame_size, default=(640, 480), metavar="WxH",
                   help="frame size [px] (default: 640x480)")
    p.add_argument("--out", type=out_path, metavar="FILE.mp4|FILE.gif",
                   help="video file (default: out/render/<experiment>.mp4)")
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


def _cmd_render(args: argparse.Namespace) -> int:
    from wpam_mj.visualisation.encoders import check_fps  # noqa: PLC0415 (Pillow; only here)
    run = run_options(args)
    (load,) = liftable_loads((args.load,), [run.params])
    control = check_control(args.control)
    spec = SineSpec(args.freq)
    duration = None if args.duration is None else \
        check_range("--duration", args.duration, 0.0, 3600.0, "s", lo_open=True)
    out = args.out if args.out is not None else Path("out") / "render" / f"{args.experiment}.mp4"
    if out.suffix.lower() not in (".mp4", ".gif"):
        raise ParameterError(f"--out {out}: the video must end in .mp4 or .gif")
    fps = check_fps(args.fps, out.suffix.lower())
    out_file(out)
    result = simulate_for_render(run.params, load, args.experiment, control, spec,
                                 duration, run.dt)
    check_video(result.time[-1] - result.time[0], fps, args.size, out.suffix)
    settings = {"load_n": load, "experiment": args.experiment, "control": control,
                "freq_hz": spec.freq, "duration_s": duration, "fps": fps, "size": args.size,
                "dt_s": run.dt}
    rid = run_id_of(args, run.params, settings)
    from wpam_mj.visualisation.render import render_video  # noqa: PLC0415 (needs OpenGL; only here)
    try:
        path = render_video(result, run.params, out, fps=fps, size=args.size, run_id=rid)
    except RuntimeError as err:
        raise RunFailed(str(err)) from None
    _, writers = output_modules()
    manifest = write_run_manifest(args, out.parent, rid, run.params, settings,
                         {path: writers.run_metadata(result)})
    print(f"wrote {path} ({result.time[-1]:.2f} s of simulated time) and {manifest}")
    return 0


def _cmd_view(args: argparse.Namespace) -> int:
    from wpam_mj.visualisation import viewer  # noqa: PLC0415 (GLFW viewer; only here)

    run = run_options(args)
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
