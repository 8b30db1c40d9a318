"""Offscreen rendering: files read back, frames follow the load, runs render identically."""

from __future__ import annotations

import dataclasses
import itertools
import math
import os
import subprocess
import sys
import threading

import imageio.v2 as imageio
import mujoco
import numpy as np
import pytest

import wpam_mj
import wpam_mj.visualisation.gl
from wpam_mj.visualisation import render
from wpam_mj.simulation.context import RunContext
from wpam_mj.simulation.model import build_model
from wpam_mj.errors import ParameterError
from wpam_mj.units import MM, MPA
from wpam_mj.paths import SCENE_XML
from wpam_mj.simulation.results import SimResult

PARAMS = wpam_mj.preset()
SIZE = (320, 240)  # px: small frames keep the tests fast
STEP = 40 * MM  # m: contraction of the synthetic step


@pytest.fixture(scope="module")
def gl() -> None:
    """Skip (with the reason) where no offscreen OpenGL context can be made."""
    try:
        # headless: EGL, as wpam_mj.visualisation.render chooses
        wpam_mj.visualisation.gl.offscreen_context_class()
        with mujoco.Renderer(mujoco.MjModel.from_xml_string("<mujoco/>"), 16, 16) as r:
            r.render()
    except Exception as err:  # noqa: BLE001 (EGL/OSMesa/GLFW raise different types)
        pytest.skip(f"no OpenGL context ({wpam_mj.visualisation.gl.backend_hint()}): {err}")


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc/self/maps")
def test_importing_the_package_chooses_no_gl_backend() -> None:
    """PyTorch's triton segfaults with EGL loaded: importing must neither set MUJOCO_GL nor
    load libEGL; the backend is chosen where offscreen rendering starts."""
    code = ("import os, wpam_mj, wpam_mj.environments.dm_env_task, wpam_mj.environments.gym_env\n"
            "maps = open('/proc/self/maps').read()\n"
            "print(os.environ.get('MUJOCO_GL'), 'libEGL' in maps)")
    env = {k: v for k, v in os.environ.items() if k not in ("MUJOCO_GL", "PYOPENGL_PLATFORM")}
    out = subprocess.run([sys.executable, "-W", "error::UserWarning", "-c", code], env=env,
                         capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["None", "False"], out.stderr


def synthetic(x: np.ndarray, *, record_dt: float = 0.01, pi: float = 0.0,
              po: float = 0.02 * MPA, load: float = 100.0) -> SimResult:
    """A SimResult with contraction x [m] sampled every record_dt [s] (no simulation)."""
    n = len(x)
    series = {f.name: np.zeros(n) for f in dataclasses.fields(SimResult)}  # every array
    series.update(time=np.arange(n) * record_dt, x=np.asarray(x, float),
                  x_ref=np.full(n, STEP), pi=np.full(n, pi), po=np.full(n, po),
                  context=RunContext(PARAMS, 1e-3, load, "pi"))
    return SimResult(**series)


def ramp(n: int = 100) -> SimResult:
    """0.99 s ramp from x = 0 to STEP."""
    return synthetic(np.linspace(0.0, STEP, n))


def test_frame_times_cover_the_run() -> None:
    assert len(render.frame_times(np.arange(1000) * 0.01, 30)) == 300  # 0..9.99 s
    assert len(render.frame_times(np.arange(1001) * 0.01, 30)) == 301  # 0..10 s
    np.testing.assert_allclose(np.diff(render.frame_times(np.arange(100) * 0.01, 30)), 1 / 30)


def test_mp4_reads_back_with_frame_count_and_size(gl, tmp_path) -> None:
    out = render.render_video(ramp(), PARAMS, tmp_path / "run.mp4", fps=30, size=SIZE)
    frames = imageio.mimread(out, memtest=False)
    assert len(frames) == 30, "frames in 0..0.99 s at 30 fps"
    assert frames[0].shape == (SIZE[1], SIZE[0], 3)
    assert not list(tmp_path.glob(".run.mp4*")), "temporary file left behind"


def test_gif_reads_back_with_frame_count_and_size(gl, tmp_path) -> None:
    out = render.render_video(ramp(), PARAMS, tmp_path / "run.gif", fps=10, size=SIZE)
    frames = imageio.mimread(out)
    assert len(frames) == 10
    assert frames[0].shape[:2] == (SIZE[1], SIZE[0])


def test_still_frame_png(gl, tmp_path) -> None:
    out = render.still_frame(ramp(), PARAMS, 0.5, tmp_path / "still.png", size=SIZE)
    assert imageio.imread(out).shape[:2] == (SIZE[1], SIZE[0])


def test_frames_differ_as_the_load_moves(gl) -> None:
    frames = list(render.render_frames(ramp(), PARAMS, fps=30, size=SIZE))
    # below the text box: only the scene changes there
    lower = [f[SIZE[1] // 3:] for f in frames]
    changed = [np.any(a != b) for a, b in itertools.pairwise(lower)]
    assert all(changed), f"{changed.count(False)} consecutive frame pairs are identical"


def _load_row(image: np.ndarray) -> float:
    """Image row [px] of the centroid of the load's brown (material 'mass') pixels."""
    rgb = image.astype(float)
    r, g, b = rgb[..., 0], rgb[..., 1], rgb[..., 2]
    mask = (r > 60) & (g > 0.45 * r) & (g < 0.75 * r) & (b > 0.15 * r) & (b < 0.5 * r)
    assert mask.sum() > 200, "load not found in the frame"
    return float(np.nonzero(mask)[0].mean())


def test_load_moves_up_by_the_projected_contraction(gl) -> None:
    # x = 0 for 0.5 s, then STEP: first and last frame show the two positions
    x = np.where(np.arange(100) < 50, 0.0, STEP)
    frames = list(render.render_frames(synthetic(x), PARAMS, fps=10, size=(640, 480)))
    shift = _load_row(frames[0]) - _load_row(frames[-1])  # > 0: up in the image

    # pinhole camera: a vertical displacement dz at depth d moves f dz / d pixels,
    # f = (H / 2) / tan(fovy / 2)
    model = build_model(PARAMS, 100.0, 1e-3, xml=SCENE_XML)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    cam = model.camera("front").id
    view_axis = -data.cam_xmat[cam].reshape(3, 3)[:, 2]
    depth = float((data.geom("load_mass").xpos - data.cam_xpos[cam]) @ view_axis)
    focal = 0.5 * 480 / math.tan(math.radians(model.cam_fovy[cam]) / 2)
    expected = focal * STEP / depth
    assert shift > 0, f"load moved down in the image by {-shift:.1f} px on contraction"
    assert shift == pytest.approx(expected, rel=0.2), (
        f"load image shift {shift:.1f} px, expected {expected:.1f} px")


@pytest.mark.parametrize("threads", [1, 2, 3])
def test_same_run_renders_identical_frames(gl, threads) -> None:
    """Identical on a second render, and whatever the number of render threads."""
    a = list(render.render_frames(ramp(), PARAMS, fps=30, size=SIZE, threads=1))
    b = list(render.render_frames(ramp(), PARAMS, fps=30, size=SIZE, threads=threads))
    assert len(a) == len(b) == 30
    assert all(np.array_equal(u, v) for u, v in zip(a, b))


def test_closing_threaded_frames_early_stops_the_threads(gl) -> None:
    frames = render.render_frames(ramp(), PARAMS, fps=30, size=SIZE, threads=2)
    next(frames)
    frames.close()
    assert not [t for t in threading.enumerate() if t.name.startswith("wpam-render")]


@pytest.mark.parametrize("kwargs, message", [
    ({"fps": 0}, "fps = 0"),
    ({"fps": 200}, "[1, 120]"),
    ({"size": (641, 480)}, "even"),
    ({"size": (640, 8)}, "[32, 4096]"),
    ({"size": (640.0, 480)}, "pair of integers"),
    ({"camera": "top"}, "valid cameras: front, side"),
    ({"threads": 0}, "threads = 0 must be an integer in [1, 16]"),
])
def test_bad_options_raise_parameter_error(tmp_path, kwargs, message) -> None:
    with pytest.raises(ParameterError) as err:
        render.render_video(ramp(10), PARAMS, tmp_path / "x.mp4", **kwargs)
    assert message in str(err.value)


def test_bad_extension_and_gif_fps(tmp_path) -> None:
    with pytest.raises(ParameterError, match=r"'\.avi'.*\.mp4, \.gif"):
        render.render_video(ramp(10), PARAMS, tmp_path / "x.avi")
    with pytest.raises(ParameterError, match=r"fps = 60.*\[1, 50\]"):
        render.render_video(ramp(10), PARAMS, tmp_path / "x.gif", fps=60)


def test_render_frames_validates_before_iterating() -> None:
    with pytest.raises(ParameterError, match="valid cameras"):
        render.render_frames(ramp(10), PARAMS, camera="top")


@pytest.mark.parametrize("name", sorted(wpam_mj.MUSCLE_TYPES))
def test_the_outer_bag_is_drawn_only_on_a_muscle_type_that_has_one(name):
    """The bag is the decor's one cylinder (the sleeve is a capsule, the threads lines);
    drawn into a bare MjvScene, no GL needed."""
    from wpam_mj.visualisation.decor import MuscleDecor
    params = wpam_mj.preset(name)
    model = build_model(params, 100.0, xml=SCENE_XML)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    scene = mujoco.MjvScene(model, maxgeom=2000)
    MuscleDecor(params).draw(scene, model, data, 0.02, 0.2 * MPA, 0.04 * MPA)
    kinds = [scene.geoms[i].type for i in range(scene.ngeom)]
    assert kinds.count(mujoco.mjtGeom.mjGEOM_CAPSULE) == 1
    assert kinds.count(mujoco.mjtGeom.mjGEOM_CYLINDER) == int(params.outer_chamber)
