"""How the muscle is drawn, in any MuJoCo scene: the braided sleeve (diameter D(x), its
threads, coloured by Pi) and, on a muscle type that has one, the translucent outer bag
(coloured by Po). The video frames and the live viewer draw the same muscle."""

from __future__ import annotations

import math

import mujoco
import numpy as np

from wpam_mj import paper
from wpam_mj.physics.geometry import BraidGeometry
from wpam_mj.physics.params import Params
from wpam_mj.units import MPA

PI_COLOUR_RANGE = (0.0, 0.5 * MPA)  # Pa: ITV2031 range (paper §2.3)
PO_COLOUR_RANGE = (0.0, paper.PO_CAP_MPA * MPA)  # Pa: Po cap (paper §4.2)

# colours, RGBA in 0..1
SLEEVE_LOW = np.array([0.88, 0.82, 0.62, 1.0], np.float32)  # Pi = 0
SLEEVE_HIGH = np.array([0.80, 0.12, 0.10, 1.0], np.float32)  # Pi = 0.5 MPa
BAG_LOW = np.array([0.80, 0.88, 0.95, 0.15], np.float32)  # Po = 0
BAG_HIGH = np.array([0.15, 0.45, 0.95, 0.35], np.float32)  # Po at the cap
_THREAD = np.array([0.22, 0.18, 0.14, 1.0], np.float32)

_THREADS_PER_HAND = 3  # helices drawn in each winding direction
_SEGMENTS_PER_TURN = 10
_EYE = np.eye(3).ravel()
_ZERO3 = np.zeros(3)


def pressure_colour(p: float, lo_hi: tuple[float, float], low: np.ndarray,
                    high: np.ndarray) -> np.ndarray:
    """Linear colour map: RGBA (4,) float32 for pressure `p` [Pa] in `lo_hi` [Pa]."""
    lo, hi = lo_hi
    s = min(max((p - lo) / (hi - lo), 0.0), 1.0)
    return (low + s * (high - low)).astype(np.float32)


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
    """The braided sleeve (diameter D(x), threads, coloured by Pi) and, if the muscle type
    has one, the translucent outer bag (coloured by Po), appended as decor geoms to any
    `mujoco.MjvScene`: the video frames and the live viewer (`wpam_mj.visualisation.viewer`)
    draw the same muscle. Needs the scene model's sites muscle_top/muscle_bottom and geoms
    top_fitting/bottom_fitting, after mj_forward.
    """

    def __init__(self, params: Params, line_px: float = 1.5) -> None:
        self.geometry = BraidGeometry.from_params(params.braid)
        self.bag_radius = 0.5 * params.braid.outer_bag_diameter
        self.x_max = self.geometry.max_contraction
        self.line_px = line_px
        self.outer_bag = params.outer_chamber  # an RLAM has none to draw

    def draw(self, scene: mujoco.MjvScene, model: mujoco.MjModel, data: mujoco.MjData,
             x: float, pi: float, po: float, eye: np.ndarray | None = None) -> None:
        """Bag, sleeve and threads at contraction x [m] and gauge pressures Pi, Po [Pa];
        with the camera position `eye` [m], only the threads facing it."""
        if self.outer_bag:
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
                 pressure_colour(pi, PI_COLOUR_RANGE, SLEEVE_LOW, SLEEVE_HIGH))
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
                 pressure_colour(po, PO_COLOUR_RANGE, BAG_LOW, BAG_HIGH))
