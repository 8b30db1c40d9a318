"""Offscreen video of a simulated run, replayed from the recorded states.

This module puts the pieces together: `scene` draws one frame (`decor` the muscle,
`overlay` the text), `encoders` write the video file. Rendering happens after the
simulation: for each frame time the recorded contraction x is interpolated and written to
``qpos`` of a scene model, `mujoco.mj_forward` places the bodies, and `mujoco.Renderer`
draws the frame. Nothing here steps the physics, so rendering can never change a result.

What a frame shows (models/wpam/scene.xml, camera "front" by default):
  * the frame beam, load cell and end fittings of the MJCF model;
  * the braided sleeve as a capsule whose diameter follows the braid geometry D(x)
    (`wpam_mj.physics.geometry.BraidGeometry.diameter`) with its threads drawn as helices
    of the pantograph's n turns, coloured by the inner pressure Pi (beige 0 -> red 0.5 MPa);
  * on a muscle type with an outer chamber, the translucent outer bag spanning the two
    fittings, tinted by the outer pressure Po (clear 0 -> blue at the paper's Po cap,
    `wpam_mj.paper.PO_CAP_MPA`);
  * the hanging mass labelled with its weight [N];
  * a ruler fixed beside the load with a tick every 10 mm from the load's x = 0 position
    (site ``ruler_zero``) and a red pointer that moves with the load;
  * a text box with t [s], x and target [mm], Pi and Po [MPa].
SI inside; mm and MPa only in the drawn text.

Speed: shadows and multisampling dominate the cost of software (llvmpipe/EGL) rendering
(docs/mujoco_notes.md), so videos are drawn without shadows and with
``offsamples = 0`` (set in scene.xml), and with coarser built-in meshes. What is left is
mostly pixel fill (clear, backdrop, read-back: ~4 ms of a 640x480 frame on one core), so
frames are drawn by two threads, each with its own scene and GL context (MuJoCo's GL
calls release the GIL), while a third thread feeds ffmpeg.
"""

from __future__ import annotations

import math
import os
import queue
import threading
from collections.abc import Iterator
from pathlib import Path

import numpy as np
from PIL import Image, PngImagePlugin

from wpam_mj.infra import budget
from wpam_mj.infra.files import write_atomic
from wpam_mj.infra.manifest import png_metadata, video_comment
from wpam_mj.physics.params import Params
from wpam_mj.errors import ParameterError, check_range
from wpam_mj.simulation.results import SimResult
from wpam_mj.visualisation.encoders import (FPS_RANGE, check_fps, check_suffix, write_gif,
                                            write_mp4)
from wpam_mj.visualisation.scene import Sample, Scene, check_camera, check_size, samples_at

__all__ = ["FPS_RANGE", "check_fps", "frame_times", "render_frames", "render_video",
           "still_frame"]


def frame_times(time: np.ndarray, fps: float) -> np.ndarray:
    """Frame instants [s], shape (n_frames,): time[0] + k / fps up to time[-1].

    n_frames = floor((time[-1] - time[0]) fps) + 1, so a run recorded over 0..9.99 s
    gives 300 frames at 30 fps.
    """
    t0, t1 = float(time[0]), float(time[-1])
    n = math.floor((t1 - t0) * fps + 1e-9) + 1
    return t0 + np.arange(n) / fps


def _check_inputs(result: SimResult, params: Params, shadows: bool = False) -> None:
    """The run to draw: a SimResult (its series share one length, see `SimResult`) whose
    time increases and whose drawn state (x, Pi, Po) is finite, and its Params."""
    if not isinstance(result, SimResult):
        raise ParameterError(f"result = {type(result).__name__} must be a SimResult "
                             "(e.g. from wpam_mj.experiments.drives.step_run)")
    if not isinstance(params, Params):
        raise ParameterError(f"params = {type(params).__name__} must be a Params "
                             "(e.g. wpam_mj.preset())")
    if not isinstance(shadows, (bool, np.bool_)):
        raise ParameterError(f"shadows = {shadows!r} must be True or False")
    for name in ("time", "x", "pi", "po"):
        series = getattr(result, name)
        if not np.all(np.isfinite(series)):
            raise ParameterError(f"result.{name} has NaN or infinite values at sample "
                                 f"{int(np.flatnonzero(~np.isfinite(series))[0])}")
    if len(result.time) > 1 and not np.all(np.diff(result.time) > 0):
        raise ParameterError("result.time must be strictly increasing")


def render_frames(result: SimResult, params: Params, *, fps: float = 30,
                  size: tuple[int, int] = (640, 480), camera: str = "front",
                  shadows: bool = False, threads: int | None = None) -> Iterator[np.ndarray]:
    """Yield the frames of a video of `result`: RGB uint8 arrays (height, width, 3).

    Frames are at `frame_times(result.time, fps)`; states between records are linearly
    interpolated. `threads` render threads (default: one per core, at most 2) each own a
    scene and GL context and draw every `threads`-th frame; the frames do not depend on
    it. Close the generator (or exhaust it) to free the contexts.
    """
    fps = check_fps(fps)
    size = check_size(size, "")
    _check_inputs(result, params, shadows)
    check_camera(camera)
    threads = _check_threads(threads)
    samples = list(samples_at(result, frame_times(result.time, fps)))

    def scene() -> Scene:
        return Scene(result.load, params, size, camera, shadows, fast=True)

    if threads == 1 or len(samples) == 1:
        return _frames(scene, samples)
    return _threaded_frames(scene, samples, threads)


def _check_threads(threads: int | None) -> int:
    if threads is None:
        return min(2, os.cpu_count() or 1)
    if isinstance(threads, bool) or not isinstance(threads, int) or not 1 <= threads <= 16:
        raise ParameterError(f"threads = {threads!r} must be an integer in [1, 16]")
    return threads


def _frames(new_scene, samples: list[Sample]) -> Iterator[np.ndarray]:
    scene = new_scene()
    try:
        for s in samples:
            yield scene.frame(s)
    finally:
        scene.close()


def _threaded_frames(new_scene, samples: list[Sample], threads: int,
                     depth: int = 2) -> Iterator[np.ndarray]:
    """Frames in order, drawn by `threads` threads; thread k draws frames k, k + threads, ...

    The GL calls release the GIL, so software GL runs in parallel. Each thread creates,
    uses and frees its own scene (an EGL context is current in one thread only). A
    failure in a thread is re-raised here; closing the generator stops the threads.
    """
    stop = threading.Event()
    outboxes = [queue.Queue(maxsize=depth) for _ in range(threads)]

    def put(box: queue.Queue, item) -> bool:
        while not stop.is_set():
            try:
                box.put(item, timeout=0.05)
                return True
            except queue.Full:
                continue
        return False

    def work(k: int) -> None:
        box = outboxes[k]
        try:
            scene = new_scene()
        except BaseException as err:  # noqa: BLE001 (re-raised by the consumer)
            put(box, err)
            return
        try:
            for s in samples[k::threads]:
                if not put(box, scene.frame(s)):
                    return
        except BaseException as err:  # noqa: BLE001 (re-raised by the consumer)
            put(box, err)
        finally:
            scene.close()

    workers = [threading.Thread(target=work, args=(k,), name=f"wpam-render-{k}", daemon=True)
               for k in range(threads)]
    for w in workers:
        w.start()
    try:
        for i in range(len(samples)):
            item = outboxes[i % threads].get()
            if isinstance(item, BaseException):
                raise item
            yield item
    finally:
        stop.set()
        for w in workers:
            w.join()


def render_video(result: SimResult, params: Params, out: str | Path, *, fps: float = 30,
                 size: tuple[int, int] = (640, 480), camera: str = "front",
                 shadows: bool = False, threads: int | None = None,
                 run_id: str | None = None) -> Path:
    """Write a video of a simulated run; returns the path written.

    Args:
      result: the run (its load and time step are used to build the scene).
      params: the parameters it was simulated with (braid geometry for the sleeve).
      out: ``.mp4`` (H.264 via imageio-ffmpeg) or ``.gif`` (Pillow), written atomically.
      fps: frames per second: [1, 120] for MP4, [1, 50] for GIF.
      size: (width, height) [px], each in [32, 4096]; even for MP4.
      camera: a camera of models/wpam/scene.xml ("front", "side").
      shadows: draw shadows (about 4x slower in software rendering).
      threads: render threads, see `render_frames`.
      run_id: the run's id (`wpam_mj.infra.manifest.run_id`), written into the file's comment.
    """
    suffix = check_suffix(out)
    fps = check_fps(fps, suffix)
    size = check_size(size, suffix)
    _check_inputs(result, params, shadows)
    budget.check_video(float(result.time[-1] - result.time[0]), fps, size, suffix)
    comment = None if run_id is None else video_comment(run_id)
    frames = render_frames(result, params, fps=fps, size=size, camera=camera,
                           shadows=shadows, threads=threads)
    try:
        if suffix == ".mp4":
            return write_atomic(out, lambda p: write_mp4(p, frames, fps, comment))
        return write_atomic(out, lambda p: write_gif(p, frames, fps, comment))
    finally:
        frames.close()


def still_frame(result: SimResult, params: Params, t: float, out_png: str | Path, *,
                size: tuple[int, int] = (640, 480), camera: str = "front",
                shadows: bool = False, run_id: str | None = None) -> Path:
    """Write one PNG of the run at time `t` [s] (e.g. the README picture).

    Drawn with MuJoCo's default mesh quality (videos use a coarser one for speed).
    `run_id` (`wpam_mj.infra.manifest.run_id`) goes into the PNG's metadata.
    """
    _check_inputs(result, params, shadows)
    info = PngImagePlugin.PngInfo()
    for key, value in ({} if run_id is None else png_metadata(run_id)).items():
        info.add_text(key, value)
    t = check_range("t", t, float(result.time[0]), float(result.time[-1]), "s")
    if not isinstance(out_png, (str, os.PathLike)) or Path(out_png).suffix.lower() != ".png":
        raise ParameterError(f"out_png = {str(out_png)!r} must end in .png")
    size = check_size(size, "")
    scene = Scene(result.load, params, size, camera, shadows, fast=False)
    try:
        image = scene.frame(next(samples_at(result, np.array([t]))))
    finally:
        scene.close()
    return write_atomic(out_png, lambda p: Image.fromarray(image).save(p, format="PNG",
                                                                      pnginfo=info))
