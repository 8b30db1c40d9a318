"""One frame of a recorded state: the rig's scene model placed at the state's contraction,
the muscle drawn on it, a ruler and the load's label, rendered offscreen with the state
box on top; `StateFrames` draws live states the same way."""

from __future__ import annotations

import functools
import math
from collections.abc import Iterator
from dataclasses import dataclass

import mujoco
import numpy as np

from wpam_mj.paths import SCENE_XML
from wpam_mj.physics.params import Params
from wpam_mj.errors import ParameterError
from wpam_mj.units import MM
from wpam_mj.simulation.model import build_model
from wpam_mj.simulation.results import SimResult
from wpam_mj.visualisation import gl
from wpam_mj.visualisation.decor import MuscleDecor, add_geom
from wpam_mj.visualisation.overlay import StateBox, Text, font

SIZE_RANGE = (32, 4096)  # px, width and height
RULER_TICK = 10 * MM  # m between ruler ticks
_RULER = np.array([0.1, 0.1, 0.1, 1.0], np.float32)
_POINTER = np.array([0.9, 0.1, 0.1, 1.0], np.float32)
# video mesh quality (MJCF <quality>): 24 slices keep cylinders round at 640x480,
# 4 stacks are enough for the capsule ends, 1 quad per box face (no spot lights here)
_FAST_QUALITY = {"numslices": 24, "numstacks": 4, "numquads": 1}
_RULER_OFFSET = 0.02  # m: ruler stands this far outside site ruler_zero (+x)


def project(model: mujoco.MjModel, data: mujoco.MjData, camera: int, size: tuple[int, int],
            points: np.ndarray) -> np.ndarray:
    """Pixel coordinates (u right, v down) [px], shape (n, 2), of world points (n, 3) [m].

    Pinhole model of a fixed MuJoCo camera defined by its vertical field of view cam_fovy
    (it looks along its -z axis, y up), as drawn by mjv_updateScene/mjr_render; needs
    `mj_forward` first. Cameras given by sensorsize/focal intrinsics are not handled.
    """
    width, height = size
    pts = np.atleast_2d(np.asarray(points, dtype=float))
    rot = data.cam_xmat[camera].reshape(3, 3)
    cam = (pts - data.cam_xpos[camera]) @ rot  # camera frame coordinates
    if model.cam_projection[camera] == mujoco.mjtProjection.mjPROJ_ORTHOGRAPHIC:
        scale = np.full(len(pts), height / model.cam_fovy[camera])  # fovy is a length
    else:
        focal = 0.5 * height / math.tan(math.radians(model.cam_fovy[camera]) / 2.0)
        scale = focal / -cam[:, 2]
    return np.column_stack([0.5 * width + scale * cam[:, 0], 0.5 * height - scale * cam[:, 1]])


@dataclass(frozen=True)
class Sample:
    """The recorded state at one frame time (SI)."""

    t: float
    x: float
    x_ref: float
    pi: float
    po: float


def samples_at(result: SimResult, times: np.ndarray) -> Iterator[Sample]:
    """States at `times` [s]: x, Pi, Po linearly interpolated, the target held (a command)."""
    x, pi, po = (np.interp(times, result.time, getattr(result, f)) for f in ("x", "pi", "po"))
    held = np.clip(np.searchsorted(result.time, times, side="right") - 1, 0, None)
    for t, xk, xr, pik, pok in zip(times, x, result.x_ref[held], pi, po):
        yield Sample(float(t), float(xk), float(xr), float(pik), float(pok))


class Scene:
    """Scene model, renderer and fixed drawing constants for one video."""

    def __init__(self, load: float, params: Params, size: tuple[int, int],
                 camera: str, shadows: bool, fast: bool) -> None:
        width, height = size
        check_camera(camera)
        model = build_model(params, load, xml=SCENE_XML)  # drawn, never stepped: any dt
        # offscreen buffer of exactly the frame size: a larger one costs a full-buffer
        # clear per frame (4 ms at 1280x960 in llvmpipe)
        model.vis.global_.offwidth, model.vis.global_.offheight = width, height
        model.vis.quality.offsamples = 0
        if fast:  # coarser built-in meshes: cylinders at the default 28x16 cost ~0.4 ms each
            for name, value in _FAST_QUALITY.items():
                setattr(model.vis.quality, name, value)
        self.model, self.data = model, mujoco.MjData(model)
        self.size = size
        self.camera = model.camera(camera).id
        self.decor = MuscleDecor(params, line_px=max(1.0, 1.5 * height / 480))
        self.x_max = self.decor.x_max
        self.load_text = f"{load:.0f} N"
        self.option = mujoco.MjvOption()
        self.option.flags[mujoco.mjtVisFlag.mjVIS_TENDON] = False  # the sleeve replaces it
        self.text = Text(font(round(14 * height / 480)))
        self.small_text = Text(font(round(11 * height / 480)))

        # fixed in the world: bag ends' offsets, the ruler (read at x = 0)
        self.data.qpos[0] = 0.0
        mujoco.mj_forward(model, self.data)
        self.zero = self.data.site("ruler_zero").xpos.copy()
        self.n_ticks = math.floor(self.x_max / RULER_TICK + 1e-9) + 1
        ticks = self.zero + np.outer(np.arange(self.n_ticks), [0.0, 0.0, RULER_TICK])
        uv = project(model, self.data, self.camera, size, ticks + [_RULER_OFFSET + 0.006, 0, 0])
        tick_px = abs(uv[1, 1] - uv[0, 1]) if self.n_ticks > 1 else 1e9
        need = (self.small_text.font.getbbox("0")[3] + 2) / max(tick_px, 1e-9)
        every = next((k for k in (1, 2, 5, 10) if k >= need), 10)  # labels every k ticks
        self.ruler_labels = [
            (u, v, f"{k * RULER_TICK / MM:.0f}" + (" mm" if k == 0 else ""))
            for k, (u, v) in enumerate(uv) if k % every == 0]
        self._box = StateBox(self.text)

        # the GL context last: nothing after it may fail and leak it
        try:
            gl.offscreen_context_class()  # headless: EGL, chosen here and not on import
            self.renderer = mujoco.Renderer(model, height, width)
        except Exception as err:  # GL errors come in several types
            raise RuntimeError(f"cannot create an OpenGL context for offscreen rendering: "
                               f"{err}. {gl.backend_hint()}") from err
        self.renderer.scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = shadows
        self.renderer.scene.flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = False

    def close(self) -> None:
        self.renderer.close()

    # -- 3D: decor geoms added to the scene after mjv_updateScene ------------------------
    def _add(self, kind: int, size, pos, rgba: np.ndarray) -> None:
        add_geom(self.renderer.scene, kind, size, pos, rgba)

    def _ruler(self) -> None:
        """Fixed ruler (+x of site ruler_zero at x = 0), ticks every 10 mm, and the pointer."""
        x0, y0, z0 = self.zero
        xr = x0 + _RULER_OFFSET
        top = z0 + (self.n_ticks - 1) * RULER_TICK + 0.005
        self._add(mujoco.mjtGeom.mjGEOM_BOX, (0.002, 0.002, 0.5 * (top - z0 + 0.005)),
                  (xr + 0.002, y0, 0.5 * (top + z0 - 0.005)), _RULER)
        for k in range(self.n_ticks):
            half = 0.007 if k % 5 == 0 else 0.004
            self._add(mujoco.mjtGeom.mjGEOM_BOX, (half, 0.0015, 0.0006),
                      (xr - half, y0, z0 + k * RULER_TICK), _RULER)
        p = self.data.site("ruler_zero").xpos  # moves with the load
        self._add(mujoco.mjtGeom.mjGEOM_BOX, (0.5 * _RULER_OFFSET, 0.002, 0.001),
                  (p[0] + 0.5 * _RULER_OFFSET, p[1], p[2]), _POINTER)

    # -- 2D: text and boxes drawn onto the frame ------------------------------------------
    def _overlay(self, image: np.ndarray, s: Sample) -> None:
        (u, v), = project(self.model, self.data, self.camera, self.size,
                          self.data.geom("load_mass").xpos)
        self.text.stamp(image, u, v, self.load_text, (255, 255, 255), "mm")
        for u, v, label in self.ruler_labels:
            self.small_text.stamp(image, u, v, label, (20, 20, 20), "lm")
        self._box.draw(image, s)

    def frame(self, s: Sample) -> np.ndarray:
        """RGB image (height, width, 3) uint8 of the state `s` (a new array)."""
        m, d = self.model, self.data
        d.qpos[0] = s.x
        d.qvel[0] = 0.0
        mujoco.mj_forward(m, d)
        self.renderer.update_scene(d, camera=self.camera, scene_option=self.option)
        self.decor.draw(self.renderer.scene, m, d, s.x, s.pi, s.po,
                        eye=d.cam_xpos[self.camera])
        self._ruler()
        image = self.renderer.render()
        self._overlay(image, s)
        return image


def check_size(size, suffix: str) -> tuple[int, int]:
    try:
        width, height = size
        ok = all(isinstance(v, (int, np.integer)) for v in (width, height))
    except (TypeError, ValueError):
        ok = False
    if not ok:
        raise ParameterError(f"size = {size!r} must be a pair of integers (width, height) px")
    lo, hi = SIZE_RANGE
    for name, v in (("width", width), ("height", height)):
        if not lo <= v <= hi:
            raise ParameterError(f"size {name} = {v} px is outside the allowed range "
                                 f"[{lo}, {hi}] px")
        if suffix == ".mp4" and v % 2:
            raise ParameterError(f"size {name} = {v} px must be even for MP4 (yuv420p)")
    return int(width), int(height)


@functools.cache
def _scene_cameras() -> tuple[str, ...]:
    model = mujoco.MjModel.from_xml_path(str(SCENE_XML))
    return tuple(model.camera(i).name for i in range(model.ncam))


def check_camera(camera: str) -> None:
    if not isinstance(camera, str) or camera not in _scene_cameras():
        raise ParameterError(f"camera = {camera!r} is not in the scene; "
                             f"valid cameras: {', '.join(_scene_cameras())}")


class StateFrames:
    """Frames of single live states (an environment's), drawn as the video frames are.

    Owns one scene and GL context; `close` frees them.
    """

    def __init__(self, params: Params, load: float, *, size: tuple[int, int] = (640, 480),
                 camera: str = "front") -> None:
        self._scene = Scene(load, params, check_size(size, ""), camera, shadows=False,
                             fast=True)

    def set_load(self, load: float) -> None:
        """Label the hanging mass with `load` [N] (its drawn size does not change)."""
        self._scene.load_text = f"{load:.0f} N"

    def frame(self, t: float, x: float, x_ref: float, pi: float, po: float) -> np.ndarray:
        """RGB image (height, width, 3) uint8 at time t [s], contraction x and target
        x_ref [m], gauge pressures Pi and Po [Pa]."""
        return self._scene.frame(Sample(t, x, x_ref, pi, po))

    def close(self) -> None:
        self._scene.close()
