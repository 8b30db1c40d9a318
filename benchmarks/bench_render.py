"""Benchmark: render a 10 s run as a 640x480, 30 fps MP4 (target <= 3 s on 2 cores).

The run is simulated first (not timed); the figure is the wall time of `render_video`
(replay, rendering, overlay, H.264 encoding), best of --repeat runs. Also printed: the CPU
time of this process (main thread + llvmpipe's threads) and of the ffmpeg subprocess in
that run, and the load average: on a shared 2-core machine other jobs inflate the wall time.

    python benchmarks/bench_render.py [--repeat 3]
"""

from __future__ import annotations

import argparse
import resource
import tempfile
import time
from pathlib import Path

import mujoco
import numpy as np

import wpam_mj
from common import Figure, describe, print_table
from wpam_mj.control.controllers import pi_feedforward
from wpam_mj.physics.muscle import MuscleModel
from wpam_mj.units import MM
from wpam_mj.visualisation.gl import offscreen_context_class
from wpam_mj.visualisation.render import render_video

TARGET_S = 3.0  # s for 10 s of 640x480 at 30 fps (the project's rendering target, README)
DURATION_S = 10.0
FPS = 30
SIZE = (640, 480)


def make_run(params: wpam_mj.Params, load: float = 100.0,
             duration: float = DURATION_S) -> wpam_mj.SimResult:
    """A 10 s PI step run: 0 -> 20 mm at t = 1 s -> 40 mm at t = 5 s (100 N)."""
    dt = 1e-3
    t = np.arange(round(duration / dt)) * dt
    x_ref = np.where(t < 1.0, 0.0, np.where(t < 5.0, 20 * MM, 40 * MM))
    muscle = MuscleModel.from_params(params)
    pi = pi_feedforward(muscle, params, x_ref, load, params.controller.po_feedforward)
    drive = wpam_mj.Drive(pi_cmd=pi, po_cmd=np.zeros_like(t), x_ref=x_ref)
    return wpam_mj.simulation.simulate.simulate(params, load, drive, dt=dt, control="pi",
                                                engine="python")


def _children_cpu() -> float:
    """CPU time [s] of finished child processes (the ffmpeg encoder)."""
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def measure(repeats: int = 3, duration: float = DURATION_S,
            size: tuple[int, int] = SIZE) -> dict[str, float]:
    """Best wall time of render_video over `repeats` [s], with the CPU it used."""
    params = wpam_mj.preset()
    result = make_run(params, duration=duration)
    best = (float("inf"), 0.0, 0.0)
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "bench.mp4"
        for _ in range(repeats):
            w0, c0, f0 = time.perf_counter(), time.process_time(), _children_cpu()
            render_video(result, params, out, fps=FPS, size=size)
            best = min(best, (time.perf_counter() - w0, time.process_time() - c0,
                              _children_cpu() - f0))
        size_kb = out.stat().st_size / 1024
    wall, cpu, ffmpeg_cpu = best
    return {"wall": wall, "cpu": cpu, "ffmpeg_cpu": ffmpeg_cpu, "size_kb": size_kb}


def figures(repeats: int = 3, quick: bool = False) -> list[Figure]:
    """The render target; `quick`: 0.5 s at 64x48, and none where there is no OpenGL
    (run_all --quick: does it still run?)."""
    if quick:
        try:
            offscreen_context_class()
            with mujoco.Renderer(mujoco.MjModel.from_xml_string("<mujoco/>"), 16, 16) as r:
                r.render()
        except Exception as err:  # noqa: BLE001 (EGL/OSMesa/GLFW raise different types)
            print(f"render: skipped, no OpenGL context ({err})")
            return []
        return [Figure("render 0.5 s 64x48 MP4 [s]", measure(1, 0.5, (64, 48))["wall"], "")]
    m = measure(repeats)
    return [Figure(f"render {DURATION_S:g} s {SIZE[0]}x{SIZE[1]}@{FPS} MP4 [s]", m["wall"], "<=",
                   TARGET_S)]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3, help="timed renders (best is kept)")
    args = parser.parse_args(argv)
    m = measure(args.repeat)
    n = int(DURATION_S * FPS)
    print(f"render_video: {DURATION_S:g} s run, {SIZE[0]}x{SIZE[1]} px, {FPS} fps MP4 "
          f"({n} frames, {m['size_kb']:.0f} kB), best of {args.repeat}")
    print(describe())
    ok = print_table([
        Figure("wall time [s]", m["wall"], "<=", TARGET_S),
        Figure("wall time per frame [ms]", 1e3 * m["wall"] / n, ""),
        Figure("CPU in this process [s]", m["cpu"], ""),
        Figure("CPU of ffmpeg [s]", m["ffmpeg_cpu"], "")])
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
