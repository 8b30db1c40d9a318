"""Offscreen video of a simulated run, replayed from the recorded states.

Rendering happens after the simulation: for each frame time the recorded contraction x
is interpolated and written to ``qpos`` of a scene model, `mujoco.mj_forward` places the
bodies, and `mujoco.Renderer` draws the frame. Nothing here steps the physics, so
rendering can never change a result.

What a frame shows (models/wpam/scene.xml, camera "front" by default):
  * the frame beam, load cell and end fittings of the MJCF model;
  * the braided sleeve as a capsule whose diameter follows the braid geometry D(x)
    (`wpam_mj.physics.geometry.BraidGeometry.diameter`) with its threads drawn as helices of the
    pantograph's n turns, coloured by the inner pressure Pi (beige 0 -> red 0.5 MPa);
  * the translucent outer bag spanning the two fittings, tinted by the outer pressure Po
    (clear 0 -> blue at the paper's Po cap, `wpam_mj.paper.PO_CAP_MPA`);
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

import functools
import math
import os
import queue
import threading
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np
from PIL import Image, ImageDraw, ImageFont, PngImagePlugin

from wpam_mj import paper
from wpam_mj.infra import budget
from wpam_mj.visualisation import gl
from wpam_mj.display import fmt
from wpam_mj.physics.geometry import BraidGeometry
from wpam_mj.infra.manifest import png_metadata, video_comment
from wpam_mj.simulation.model import build_model
from wpam_mj.physics.params import MM, MPA, ParameterError, Params, check_range
from wpam_mj.paths import SCENE_XML
from wpam_mj.simulation.results import SimResult, write_atomic

FORMATS = (".mp4", ".gif")
FPS_RANGE = {".mp4": (1.0, 120.0), ".gif": (1.0, 50.0)}  # GIF: 10 ms delay resolution
SIZE_RANGE = (32, 4096)  # px, width and height
PI_COLOUR_RANGE = (0.0, 0.5 * MPA)  # Pa: ITV2031 range (paper §2.3)
PO_COLOUR_RANGE = (0.0, paper.PO_CAP_MPA * MPA)  # Pa: Po cap (paper §4.2)
RULER_TICK = 10 * MM  # m between ruler ticks

# colours, RGBA in 0..1
_SLEEVE_LOW = np.array([0.88, 0.82, 0.62, 1.0], np.float32)  # Pi = 0
_SLEEVE_HIGH = np.array([0.80, 0.12, 0.10, 1.0], np.float32)  # Pi = 0.5 MPa
_BAG_LOW = np.array([0.80, 0.88, 0.95, 0.15], np.float32)  # Po = 0
_BAG_HIGH = np.array([0.15, 0.45, 0.95, 0.35], np.float32)  # Po at the cap
_THREAD = np.array([0.22, 0.18, 0.14, 1.0], np.float32)
_RULER = np.array([0.1, 0.1, 0.1, 1.0], np.float32)
_POINTER = np.array([0.9, 0.1, 0.1, 1.0], np.float32)

_THREADS_PER_HAND = 3  # helices drawn in each winding direction
_SEGMENTS_PER_TURN = 10
# video mesh quality (MJCF <quality>): 24 slices keep cylinders round at 640x480,
# 4 stacks are enough for the capsule ends, 1 quad per box face (no spot lights here)
_FAST_QUALITY = {"numslices": 24, "numstacks": 4, "numquads": 1}
_X264_PRESET = "ultrafast"  # see _write_mp4
_EYE = np.eye(3).ravel()
_ZERO3 = np.zeros(3)
_RULER_OFFSET = 0.02  # m: ruler stands this far outside site ruler_zero (+x)


def pressure_colour(p: float, lo_hi: tuple[float, float], low: np.ndarray,
                    high: np.ndarray) -> np.ndarray:
    """Linear colour map: RGBA (4,) float32 for pressure `p` [Pa] in `lo_hi` [Pa]."""
    lo, hi = lo_hi
    s = min(max((p - lo) / (hi - lo), 0.0), 1.0)
    return (low + s * (high - low)).astype(np.float32)


def frame_times(time: np.ndarray, fps: float) -> np.ndarray:
    """Frame instants [s], shape (n_frames,): time[0] + k / fps up to time[-1].

    n_frames = floor((time[-1] - time[0]) fps) + 1, so a run recorded over 0..9.99 s
    gives 300 frames at 30 fps.
    """
    t0, t1 = float(time[0]), float(time[-1])
    n = math.floor((t1 - t0) * fps + 1e-9) + 1
    return t0 + np.arange(n) / fps


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
class _Sample:
    """The recorded state at one frame time (SI)."""

    t: float
    x: float
    x_ref: float
    pi: float
    po: float


def _samples(result: SimResult, times: np.ndarray) -> Iterator[_Sample]:
    """States at `times` [s]: x, Pi, Po linearly interpolated, the target held (a command)."""
    x, pi, po = (np.interp(times, result.time, getattr(result, f)) for f in ("x", "pi", "po"))
    held = np.clip(np.searchsorted(result.time, times, side="right") - 1, 0, None)
    for t, xk, xr, pik, pok in zip(times, x, result.x_ref[held], pi, po):
        yield _Sample(float(t), float(xk), float(xr), float(pik), float(pok))


def _reserve(scene: mujoco.MjvScene, n: int) -> int:
    if scene.ngeom + n > scene.maxgeom:
        raise RuntimeError(f"render scene full: {scene.ngeom} + {n} > {scene.maxgeom}")
    first = scene.ngeom
    scene.ngeom += n
    return first


def add_geom(scene: mujoco.MjvScene, kind: int, size, pos, rgba: np.ndarray) -> None:
    """Append an axis-aligned decor geom; `size` as in MJCF (capsule/cylinder: r, half-length)."""
    g = scene.geoms[_reserve(scene, 1)]
    mujoco.mjv_initGeom(g, kind, np.asarray(size, float), np.asarray(pos, float), _EYE, rgba)
    g.category = mujoco.mjtCatBit.mjCAT_DECOR


def add_lines(scene: mujoco.MjvScene, starts: np.ndarray, ends: np.ndarray, rgba: np.ndarray,
              width_px: float) -> None:
    """Append line segments starts[i] -> ends[i], arrays (n, 3) [m]."""
    first = _reserve(scene, len(starts))
    line = mujoco.mjtGeom.mjGEOM_LINE
    for i, (a, b) in enumerate(zip(starts, ends), first):
        g = scene.geoms[i]
        mujoco.mjv_initGeom(g, line, _ZERO3, _ZERO3, _EYE, rgba)
        mujoco.mjv_connector(g, line, width_px, a, b)


class MuscleDecor:
    """The braided sleeve (diameter D(x), threads, coloured by Pi) and the translucent outer
    bag (coloured by Po), appended as decor geoms to any `mujoco.MjvScene`: the video frames
    and the live viewer (`wpam_mj.visualisation.viewer`) draw the same muscle. Needs the scene
    model's
    sites muscle_top/muscle_bottom and geoms top_fitting/bottom_fitting, after mj_forward.
    """

    def __init__(self, params: Params, line_px: float = 1.5) -> None:
        self.geometry = BraidGeometry.from_params(params.braid)
        self.bag_radius = 0.5 * params.braid.outer_bag_diameter
        self.x_max = self.geometry.max_contraction
        self.line_px = line_px

    def draw(self, scene: mujoco.MjvScene, model: mujoco.MjModel, data: mujoco.MjData,
             x: float, pi: float, po: float, eye: np.ndarray | None = None) -> None:
        """Bag, sleeve and threads at contraction x [m] and gauge pressures Pi, Po [Pa];
        with the camera position `eye` [m], only the threads facing it."""
        self._bag(scene, model, data, po)
        self._muscle(scene, data, x, pi, eye)

    def _muscle(self, scene, data, x: float, pi: float, eye) -> None:
        top = data.site("muscle_top").xpos
        bottom = data.site("muscle_bottom").xpos
        r = 0.5 * self.geometry.diameter(min(max(x, 0.0), self.x_max))
        length = float(top[2] - bottom[2])
        half = max(0.5 * length - r, 1e-4)  # capsule: cylinder part + rounded ends = L
        mid = 0.5 * (top + bottom)
        add_geom(scene, mujoco.mjtGeom.mjGEOM_CAPSULE, (r, half, 0.0), mid,
                 pressure_colour(pi, PI_COLOUR_RANGE, _SLEEVE_LOW, _SLEEVE_HIGH))
        # Threads of the pantograph: n turns over the active length L (Chou & Hannaford
        # 1996, eq. 2) in both winding directions, drawn on the cylindrical part.
        turns = self.geometry.turns * (2.0 * half) / max(length, 1e-9)
        nseg = max(2, math.ceil(turns * _SEGMENTS_PER_TURN))
        frac = np.arange(nseg + 1) / nseg
        start = 2.0 * np.pi * np.arange(_THREADS_PER_HAND) / _THREADS_PER_HAND
        angle = np.concatenate([start[:, None] + 2.0 * np.pi * turns * frac,
                                start[:, None] - 2.0 * np.pi * turns * frac])  # (threads, n+1)
        # vertices just outside the capsule so that the chords between them are too and the
        # depth test keeps the threads visible
        rr = 1.01 * r / math.cos(math.pi * turns / nseg)
        normal = np.stack([np.cos(angle), np.sin(angle), np.zeros_like(angle)], -1)
        pts = np.stack([mid[0] + rr * normal[..., 0], mid[1] + rr * normal[..., 1],
                        np.broadcast_to(mid[2] - half + 2.0 * half * frac, angle.shape)], -1)
        # only segments with an end on the side facing the camera: the opaque sleeve hides
        # the others, and each geom costs ~15 us of software GL
        keep = np.ones((angle.shape[0], nseg), dtype=bool)
        if eye is not None:
            facing = np.einsum("tnk,tnk->tn", normal, eye - pts) > 0
            keep = facing[:, :-1] | facing[:, 1:]
        add_lines(scene, pts[:, :-1][keep], pts[:, 1:][keep], _THREAD, self.line_px)

    def _bag(self, scene, m, d, po: float) -> None:
        """Outer bag: from the top face of the upper fitting to the bottom face of the lower."""
        z_top = d.geom("top_fitting").xpos[2] + m.geom("top_fitting").size[1]
        z_bot = d.geom("bottom_fitting").xpos[2] - m.geom("bottom_fitting").size[1]
        mid = d.site("muscle_top").xpos.copy()
        mid[2] = 0.5 * (z_top + z_bot)
        add_geom(scene, mujoco.mjtGeom.mjGEOM_CYLINDER,
                 (self.bag_radius, 0.5 * (z_top - z_bot), 0.0), mid,
                 pressure_colour(po, PO_COLOUR_RANGE, _BAG_LOW, _BAG_HIGH))


class _Scene:
    """Scene model, renderer and fixed drawing constants for one video."""

    def __init__(self, load: float, params: Params, size: tuple[int, int],
                 camera: str, shadows: bool, fast: bool) -> None:
        width, height = size
        _check_camera(camera)
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
        self.text = _Text(_font(round(14 * height / 480)))
        self.small_text = _Text(_font(round(11 * height / 480)))

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
        self._box = _StateBox(self.text)

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
    def _overlay(self, image: np.ndarray, s: _Sample) -> None:
        (u, v), = project(self.model, self.data, self.camera, self.size,
                          self.data.geom("load_mass").xpos)
        self.text.stamp(image, u, v, self.load_text, (255, 255, 255), "mm")
        for u, v, label in self.ruler_labels:
            self.small_text.stamp(image, u, v, label, (20, 20, 20), "lm")
        self._box.draw(image, s)

    def frame(self, s: _Sample) -> np.ndarray:
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


class _Text:
    """Text stamped onto RGB frames: Pillow renders each string's coverage mask once.

    A FreeType render costs ~0.1 ms per string; labels repeat every frame, and the
    numbers of the state box come from a small set of strings per run segment.
    """

    def __init__(self, font) -> None:
        self.font = font
        self._masks: dict[tuple[str, str], tuple[np.ndarray, int, int]] = {}

    def _mask(self, text: str, anchor: str) -> tuple[np.ndarray, int, int]:
        key = (text, anchor)
        if key not in self._masks:
            if len(self._masks) > 4096:
                self._masks.clear()
            left, top, right, bottom = self.font.getbbox(text, anchor=anchor)
            img = Image.new("L", (max(right - left, 1), max(bottom - top, 1)), 0)
            ImageDraw.Draw(img).text((-left, -top), text, fill=255, font=self.font,
                                     anchor=anchor)
            self._masks[key] = (np.asarray(img, np.float32)[..., None] / 255.0, left, top)
        return self._masks[key]

    def stamp(self, image: np.ndarray, u: float, v: float, text: str,
              rgb: tuple[int, int, int], anchor: str = "la") -> None:
        """Draw `text` in colour `rgb` at pixel (u, v) with a Pillow `anchor`, in place."""
        alpha, left, top = self._mask(text, anchor)
        x0, y0 = round(float(u)) + left, round(float(v)) + top
        h, w = alpha.shape[:2]
        cx0, cy0 = max(x0, 0), max(y0, 0)
        cx1, cy1 = min(x0 + w, image.shape[1]), min(y0 + h, image.shape[0])
        if cx0 >= cx1 or cy0 >= cy1:
            return
        a = alpha[cy0 - y0:cy1 - y0, cx0 - x0:cx1 - x0]
        region = image[cy0:cy1, cx0:cx1]
        region[:] = region + a * (np.asarray(rgb, np.float32) - region) + 0.5


class _StateBox:
    """Top-left text box: t [s], x and target [mm], Pi and Po [MPa] with colour swatches."""

    NAMES = ("t", "x", "target", "Pi", "Po")
    BACKGROUND = (248, 248, 248)
    OUTLINE = (90, 90, 90)

    def __init__(self, text: _Text) -> None:
        font = text.font
        self.text = text
        self.line_h = font.getbbox("Ag")[3] + 3
        self.pad = max(4, self.line_h // 3)
        self.col = int(font.getlength("target ")) + self.pad
        self.width = self.col + int(font.getlength("-00.000 MPa")) + self.line_h + 3 * self.pad
        self.height = len(self.NAMES) * self.line_h + 2 * self.pad
        base = Image.new("RGB", (self.width, self.height), self.BACKGROUND)
        draw = ImageDraw.Draw(base)
        draw.rectangle((0, 0, self.width - 1, self.height - 1), outline=self.OUTLINE)
        for i, name in enumerate(self.NAMES):
            draw.text((self.pad, self.pad + i * self.line_h), name, fill=(0, 0, 0), font=font)
        self.base = np.asarray(base)

    def draw(self, image: np.ndarray, s: _Sample) -> None:
        h = min(self.height, image.shape[0] - self.pad)
        w = min(self.width, image.shape[1] - self.pad)
        if h <= 0 or w <= 0:
            return
        x0 = y0 = self.pad  # box corner in the frame
        image[y0:y0 + h, x0:x0 + w] = self.base[:h, :w]
        target = f"{fmt(s.x_ref / MM, '6.2f')} mm" if math.isfinite(s.x_ref) else "    --"
        values = (f"{fmt(s.t, '6.2f')} s", f"{fmt(s.x / MM, '6.2f')} mm", target,
                  f"{fmt(s.pi / MPA, '6.3f')} MPa", f"{fmt(s.po / MPA, '6.3f')} MPa")
        for i, value in enumerate(values):
            self.text.stamp(image, x0 + self.pad + self.col, y0 + self.pad + i * self.line_h,
                            value, (0, 0, 0))
        for i, rgba in ((3, pressure_colour(s.pi, PI_COLOUR_RANGE, _SLEEVE_LOW, _SLEEVE_HIGH)),
                        (4, pressure_colour(s.po, PO_COLOUR_RANGE, _BAG_LOW, _BAG_HIGH))):
            # the colour as seen over the light box (translucent bag tint)
            rgb = [int(255 * (rgba[3] * c + (1 - rgba[3]) * 0.97)) for c in rgba[:3]]
            top = y0 + self.pad + i * self.line_h + 2
            right = x0 + self.width - self.pad
            left, bottom = right - self.line_h + 4, top + self.line_h - 4
            if bottom < image.shape[0] and right < image.shape[1]:
                image[top:bottom + 1, left:right + 1] = self.OUTLINE
                image[top + 1:bottom, left + 1:right] = rgb


def _font(size: int) -> ImageFont.ImageFont | ImageFont.FreeTypeFont:
    """Pillow's bundled font at `size` px (no system font needed)."""
    try:
        return ImageFont.load_default(size=max(8, size))
    except (TypeError, ImportError, OSError):  # Pillow < 10.1 or no FreeType
        return ImageFont.load_default()


def _check_size(size, suffix: str) -> tuple[int, int]:
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


def check_fps(fps: float, suffix: str = ".mp4") -> float:
    """Frames per second for a video ending in `suffix`, within `FPS_RANGE` (the range the
    messages state is the range applied)."""
    return check_range("fps", fps, *FPS_RANGE[suffix], "frames/s")


def _check_suffix(out: str | Path) -> str:
    if not isinstance(out, (str, os.PathLike)) or not str(out):
        raise ParameterError(f"out = {out!r} must be a file name ending in "
                             + " or ".join(FORMATS))
    suffix = Path(out).suffix.lower()
    if suffix not in FORMATS:
        raise ParameterError(f"out = {str(out)!r} has extension {suffix or '(none)'!r}; "
                             f"allowed extensions: {', '.join(FORMATS)}")
    return suffix


@functools.cache
def _scene_cameras() -> tuple[str, ...]:
    model = mujoco.MjModel.from_xml_path(str(SCENE_XML))
    return tuple(model.camera(i).name for i in range(model.ncam))


def _check_camera(camera: str) -> None:
    if not isinstance(camera, str) or camera not in _scene_cameras():
        raise ParameterError(f"camera = {camera!r} is not in the scene; "
                             f"valid cameras: {', '.join(_scene_cameras())}")


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
    size = _check_size(size, "")
    _check_inputs(result, params, shadows)
    _check_camera(camera)
    threads = _check_threads(threads)
    samples = list(_samples(result, frame_times(result.time, fps)))

    def scene() -> _Scene:
        return _Scene(result.load, params, size, camera, shadows, fast=True)

    if threads == 1 or len(samples) == 1:
        return _frames(scene, samples)
    return _threaded_frames(scene, samples, threads)


def _check_threads(threads: int | None) -> int:
    if threads is None:
        return min(2, os.cpu_count() or 1)
    if isinstance(threads, bool) or not isinstance(threads, int) or not 1 <= threads <= 16:
        raise ParameterError(f"threads = {threads!r} must be an integer in [1, 16]")
    return threads


def _frames(new_scene, samples: list[_Sample]) -> Iterator[np.ndarray]:
    scene = new_scene()
    try:
        for s in samples:
            yield scene.frame(s)
    finally:
        scene.close()


def _threaded_frames(new_scene, samples: list[_Sample], threads: int,
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
    suffix = _check_suffix(out)
    fps = check_fps(fps, suffix)
    size = _check_size(size, suffix)
    _check_inputs(result, params, shadows)
    budget.check_video(float(result.time[-1] - result.time[0]), fps, size, suffix)
    comment = None if run_id is None else video_comment(run_id)
    frames = render_frames(result, params, fps=fps, size=size, camera=camera,
                           shadows=shadows, threads=threads)
    try:
        if suffix == ".mp4":
            return write_atomic(out, lambda p: _write_mp4(p, frames, fps, comment))
        return write_atomic(out, lambda p: _write_gif(p, frames, fps, comment))
    finally:
        frames.close()


def _write_mp4(path: Path, frames: Iterator[np.ndarray], fps: float,
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


def _write_gif(path: Path, frames: Iterator[np.ndarray], fps: float,
               comment: str | None) -> None:
    images = [Image.fromarray(f).convert("P", palette=Image.Palette.ADAPTIVE, colors=255)
              for f in frames]
    # GIF delays are in 1/100 s; Pillow merges identical consecutive frames, which the
    # changing time stamp in the overlay prevents.
    images[0].save(path, format="GIF", save_all=True, append_images=images[1:],
                   duration=round(1000.0 / fps), loop=0,
                   **({} if comment is None else {"comment": comment}))


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
    size = _check_size(size, "")
    scene = _Scene(result.load, params, size, camera, shadows, fast=False)
    try:
        image = scene.frame(next(_samples(result, np.array([t]))))
    finally:
        scene.close()
    return write_atomic(out_png, lambda p: Image.fromarray(image).save(p, format="PNG",
                                                                      pnginfo=info))


class StateFrames:
    """Frames of single live states (an environment's), drawn as the video frames are.

    Owns one scene and GL context; `close` frees them.
    """

    def __init__(self, params: Params, load: float, *, size: tuple[int, int] = (640, 480),
                 camera: str = "front") -> None:
        self._scene = _Scene(load, params, _check_size(size, ""), camera, shadows=False,
                             fast=True)

    def set_load(self, load: float) -> None:
        """Label the hanging mass with `load` [N] (its drawn size does not change)."""
        self._scene.load_text = f"{load:.0f} N"

    def frame(self, t: float, x: float, x_ref: float, pi: float, po: float) -> np.ndarray:
        """RGB image (height, width, 3) uint8 at time t [s], contraction x and target
        x_ref [m], gauge pressures Pi and Po [Pa]."""
        return self._scene.frame(_Sample(t, x, x_ref, pi, po))

    def close(self) -> None:
        self._scene.close()
