"""What one run may ask for: simulated time and memory, checked before anything is built.

Every input can be inside its own range and still ask for absurd work together (a 1e-6 Hz
sine is 5e6 s of simulation; a 3600 s ramp at a 10 us step is 7e8 steps). A run holds its
drive (commands per physics step) and its record (every field per recorded sample) in
memory, so both are estimated from the duration, the step and the record period, and a
run beyond either bound is refused in one line naming the bound, before any allocation.
"""

from __future__ import annotations

import math

from wpam_mj.errors import ParameterError

MAX_RUN_S = 10_000.0  # our choice: the longest protocol (two 3600 s static ramps) with room
MAX_RUN_BYTES = 2 * 1024 ** 3  # our choice: one run per worker fits a small machine's memory
DRIVE_BYTES_PER_STEP = 80  # measured 34-61 B per physics step (commands, targets, temporaries)
RECORD_BYTES_PER_SAMPLE = 12 * 8  # the record's 12 float64 fields (loop_contract.REC_FIELDS)


def check_duration(what: str, duration: float, hint: str = "") -> float:
    """`duration` [s] of simulated time, refused above `MAX_RUN_S` (a NaN too)."""
    if not duration <= MAX_RUN_S:
        raise ParameterError(f"{what} lasts {duration:.4g} s of simulated time; one run may "
                             f"last at most {MAX_RUN_S:g} s" + (f" ({hint})" if hint else ""))
    return duration


def run_bytes(duration: float, dt: float, record_dt: float) -> float:
    """Estimated peak memory [bytes] of one run."""
    return (duration / dt + 1) * DRIVE_BYTES_PER_STEP + \
        (duration / record_dt + 1) * RECORD_BYTES_PER_SAMPLE


def check_run(what: str, duration: float, dt: float, record_dt: float = 0.01) -> float:
    """`duration` [s], refused when it is longer than `MAX_RUN_S` or when its steps at
    `dt` [s] and samples every `record_dt` [s] would need more than `MAX_RUN_BYTES`."""
    check_duration(what, duration)
    need = run_bytes(duration, dt, record_dt)
    if need > MAX_RUN_BYTES:
        most = math.floor(MAX_RUN_BYTES / run_bytes(1.0, dt, record_dt))
        raise ParameterError(
            f"{what} at dt = {dt:g} s takes {duration / dt:.3g} steps and about "
            f"{need / 1024 ** 3:.3g} GB; one run may use at most "
            f"{MAX_RUN_BYTES / 1024 ** 3:g} GB ({most:g} s at this dt): use a larger dt or "
            "a shorter run")
    return duration


def check_video(duration: float, fps: float, size: tuple[int, int], suffix: str) -> None:
    """A video of `duration` [s] at `fps` and `size` (width, height) [px]: a GIF holds
    every frame in memory (one byte per pixel) before it is written, so it is bounded as
    one run is; an MP4 is streamed to its encoder."""
    if suffix.lower() != ".gif":
        return
    frames = math.floor(duration * fps) + 1
    need = frames * size[0] * size[1]
    if need > MAX_RUN_BYTES:
        most = MAX_RUN_BYTES / (fps * size[0] * size[1])
        raise ParameterError(
            f"a GIF of {frames} frames of {size[0]}x{size[1]} px needs about "
            f"{need / 1024 ** 3:.3g} GB; at most {MAX_RUN_BYTES / 1024 ** 3:g} GB "
            f"({most:.4g} s at {fps:g} fps): use --duration, a smaller --size or .mp4")
