"""Video files from frames: H.264 MP4 through ffmpeg (fed from a second thread) and GIF
through Pillow, each with the run's id in its comment."""

from __future__ import annotations

import os
import queue
import threading
from collections.abc import Iterator
from pathlib import Path

import numpy as np
from PIL import Image

from wpam_mj.errors import ParameterError, check_range

FORMATS = (".mp4", ".gif")
FPS_RANGE = {".mp4": (1.0, 120.0), ".gif": (1.0, 50.0)}  # GIF: 10 ms delay resolution
_X264_PRESET = "ultrafast"  # see write_mp4


def check_fps(fps: float, suffix: str = ".mp4") -> float:
    """Frames per second for a video ending in `suffix`, within `FPS_RANGE` (the range the
    messages state is the range applied)."""
    return check_range("fps", fps, *FPS_RANGE[suffix], "frames/s")


def check_suffix(out: str | Path) -> str:
    if not isinstance(out, (str, os.PathLike)) or not str(out):
        raise ParameterError(f"out = {out!r} must be a file name ending in "
                             + " or ".join(FORMATS))
    suffix = Path(out).suffix.lower()
    if suffix not in FORMATS:
        raise ParameterError(f"out = {str(out)!r} has extension {suffix or '(none)'!r}; "
                             f"allowed extensions: {', '.join(FORMATS)}")
    return suffix


def write_mp4(path: Path, frames: Iterator[np.ndarray], fps: float,
               comment: str | None) -> None:
    import imageio.v2 as imageio  # only when writing video

    # macro_block_size=2: keep the exact size (even dimensions are checked above).
    # x264 preset: ffmpeg shares the 2 cores with the renderer. Measured for 300 frames of
    # 640x480: medium 2.4 s CPU / 285 kB, veryfast 1.3 s / 283 kB, ultrafast 0.9 s / 1 MB.
    with imageio.get_writer(path, format="FFMPEG", mode="I", fps=fps, codec="libx264",
                            pixelformat="yuv420p", quality=7, macro_block_size=2,
                            ffmpeg_log_level="error",
                            output_params=["-preset", _X264_PRESET, *(
                                [] if comment is None else ["-metadata", f"comment={comment}"])]
                            ) as writer:
        _pipelined(frames, writer.append_data)


def _pipelined(frames: Iterator[np.ndarray], consume, depth: int = 4) -> None:
    """Call consume(frame) for each frame in a second thread, in order.

    Writing a frame to ffmpeg's pipe blocks while ffmpeg encodes; in a thread (the write
    releases the GIL) it overlaps with rendering the next frames.
    """
    pending: queue.Queue = queue.Queue(maxsize=depth)
    errors: list[BaseException] = []

    def work() -> None:
        while (frame := pending.get()) is not None:
            if not errors:
                try:
                    consume(frame)
                except BaseException as err:  # noqa: BLE001 (re-raised by the caller)
                    errors.append(err)

    worker = threading.Thread(target=work, name="wpam-video-writer", daemon=True)
    worker.start()
    try:
        for frame in frames:
            if errors:
                break
            pending.put(frame)
    finally:
        pending.put(None)
        worker.join()
    if errors:
        raise errors[0]


def write_gif(path: Path, frames: Iterator[np.ndarray], fps: float,
               comment: str | None) -> None:
    images = [Image.fromarray(f).convert("P", palette=Image.Palette.ADAPTIVE, colors=255)
              for f in frames]
    # GIF delays are in 1/100 s; Pillow merges identical consecutive frames, which the
    # changing time stamp in the overlay prevents.
    images[0].save(path, format="GIF", save_all=True, append_images=images[1:],
                   duration=round(1000.0 / fps), loop=0,
                   **({} if comment is None else {"comment": comment}))
