"""`wpam view`: MuJoCo's interactive viewer on the hung W-PAM, stepped live by our loop.

MuJoCo's passive viewer (`mujoco.viewer.launch_passive`) draws the model in its own
thread, with the sleeve, its braid and the outer bag as `wpam render` draws them
(`wpam_mj.visualisation.decor.MuscleDecor`); this module's loop owns the physics. It
steps the rig's muscle plugin as every other path does (`wpam_mj.simulation.live.LiveRig`:
regulators, chambers, muscle force and friction inside `mj_step`), with Pi from the
equilibrium feedforward for the target and Po from PI/PID feedback
(`wpam_mj.control.controllers.PoFeedback`) or 0 in open loop, as in the paper's experiments
(`wpam_mj.experiments.drives.drive_for_targets`). Simulated time follows the wall clock.

Keys (MuJoCo's viewer uses every letter and the digits 0-5 itself):
    Up / Down   target +-5 mm (switches to a fixed target)
    Home        next target: step (the paper's 0-50-0 mm staircase), sine (25 mm about
                25 mm at 0.2 Hz), fixed
    End         next controller: pi, pid, open (switching is bumpless: the new PI/PID
                starts from the current Po command; `VIEW_CONTROLS`)
Mouse: double-click the load to select it, then Ctrl + right drag pulls it (MuJoCo's
perturbation). The viewer writes that force into `data.xfrc_applied` of the load body at
each sync; MuJoCo maps it onto the slide joint through the body's Jacobian, so it acts on
the contraction x like any other load and the Po feedback rejects it (a pull must exceed
the muscle's dry friction, ~50 N at 100 N, to move it at all). Scripts can add a force of
their own (`perturb`).

The viewer needs a display and GLFW; without them `view` raises `ViewerUnavailable` (one
line) before any window is attempted, since MuJoCo's viewer thread would otherwise exit
the process or wait forever.
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import os
import queue
import sys
import threading
import time
import warnings
from collections.abc import Callable, Iterator

import mujoco
import numpy as np

from wpam_mj.control.controllers import (CONTROLLERS, LIVE_CONTROLS, check_control, check_live,
                                         pi_feedforward)
from wpam_mj.experiments.drives import STEP_LEVELS_MM, SineSpec
from wpam_mj.physics.geometry import BraidGeometry
from wpam_mj.simulation.live import LiveRig as _Stepper
from wpam_mj.simulation.context import RunContext
from wpam_mj.physics.muscle import MuscleModel
from wpam_mj.physics.params import Params
from wpam_mj.errors import ParameterError, check_range
from wpam_mj.units import MM, MPA
from wpam_mj.paths import SCENE_XML

TARGET_MODES = ("step", "sine", "fixed")
STEP_HOLD_S = 4.0  # s per staircase level: livelier than the paper's 10 s (settles in ~2 s)
SINE_FREQ_HZ = 0.2  # Hz: within the paper's 0.1-1 Hz sweep, slow enough to watch
TARGET_INCREMENT = 5 * MM  # m per Up/Down key press
FPS = 60.0  # frames handed to the viewer per second of simulated time
MAX_LAG_S = 0.25  # s: when drawing falls behind, the simulation slows rather than jumps
TEXT_PERIOD_S = 0.1  # s (wall clock) between overlay updates: `set_texts` waits for the
#                      viewer to draw a frame, and faster-changing numbers are unreadable

# GLFW key codes (glfw3.h)
KEY_UP, KEY_DOWN, KEY_HOME, KEY_END = 265, 264, 268, 269

# The controllers the live rig can run: keys pressed live give no target ahead of time.
VIEW_CONTROLS = LIVE_CONTROLS


class ViewerUnavailable(RuntimeError):
    """The interactive viewer cannot open here (no display, no GLFW, macOS without
    mjpython)."""


@dataclasses.dataclass(frozen=True)
class ViewTrace:
    """The state at each frame (SI): time [s], x and target [m], Pi and Po (gauge) [Pa],
    external force on the load along +z (mouse and script) [N]."""

    time: np.ndarray
    x: np.ndarray
    x_ref: np.ndarray
    pi: np.ndarray
    po: np.ndarray
    force: np.ndarray


class LiveRig:
    """The hung muscle stepped live: model, plant, controller and target, no drawing.

    Args:
      params: muscle parameters.
      load: hanging load [N].
      control: one of `VIEW_CONTROLS` ("open", "pi", "pid").
      target: "step", "sine" or a fixed contraction [m].
      dt: physics step [s].
    """

    def __init__(self, params: Params, load: float, control: str, target: str | float,
                 dt: float = 1e-3) -> None:
        context = RunContext(params, dt, load)  # load and dt checked here, once
        self.params, self.load, self.dt = params, context.load, context.dt
        self.stepper = _Stepper.build(context, xml=SCENE_XML)
        self.model = self.stepper.model
        self.data = mujoco.MjData(self.model)
        self.x_max = BraidGeometry.from_params(params.braid).max_contraction
        self.load_body = self.model.body("load").id
        self._muscle = MuscleModel.from_params(params)
        self.po_cmd = 0.0
        self.pi_cmd = 0.0
        self.push = 0.0  # N along +z: the mouse's force on the load, read at each sync
        self._pi_key: tuple[float, float] | None = None
        self._t0 = 0.0  # s: start of the current step/sine pattern
        self._sine = SineSpec(SINE_FREQ_HZ)
        if isinstance(target, str):
            if target not in TARGET_MODES[:2]:
                raise ParameterError(f"target = {target!r}; valid: step, sine or a "
                                     "contraction in mm")
            self.mode, self.fixed = target, 0.0
        else:
            self.mode = "fixed"
            self.fixed = check_range("target", target / MM, 0.0, self.x_max / MM, "mm") * MM
        self.control = ""
        self.set_control(check_control(control), bumpless=False)
        mujoco.mj_forward(self.model, self.data)

    @property
    def time(self) -> float:
        return float(self.data.time)

    @property
    def x(self) -> float:
        """Contraction [m]."""
        return self.stepper.contraction(self.data)

    def pressures(self) -> tuple[float, float]:
        """Chamber gauge pressures (Pi, Po) [Pa]."""
        return self.stepper.pressures(self.data)

    def target(self, t: float) -> float:
        """Target contraction x_r [m] at time t [s]."""
        if self.mode == "step":  # the paper's staircase, repeated
            levels = STEP_LEVELS_MM
            k = int((t - self._t0) // STEP_HOLD_S) % len(levels)
            return levels[k] * MM
        if self.mode == "sine":
            return float(self._sine.target(t - self._t0))
        return self.fixed

    def set_control(self, control: str, *, bumpless: bool = True) -> None:
        """Switch controller; PI/PID start from the current Po command (bumpless) or, at
        the start, from the Po the feedforward assumes (the loop at rest)."""
        self.control = check_live(control)
        if not CONTROLLERS[control].feedback:
            self._feedback = None
            return
        start = self.po_cmd if bumpless else self.params.controller.po_feedforward
        self._feedback = CONTROLLERS[control](self.params, self.dt, initial_output=start)

    def press(self, key: int) -> None:
        """Apply a key (GLFW code); unknown keys are ignored."""
        if key in (KEY_UP, KEY_DOWN):
            sign = 1.0 if key == KEY_UP else -1.0
            current = self.target(self.time)
            self.mode = "fixed"
            self.fixed = min(max(current + sign * TARGET_INCREMENT, 0.0), self.x_max)
        elif key == KEY_HOME:
            self.fixed = self.target(self.time)  # "fixed" holds where the pattern was
            self.mode = TARGET_MODES[(TARGET_MODES.index(self.mode) + 1) % len(TARGET_MODES)]
            self._t0 = self.time
        elif key == KEY_END:
            self.set_control(VIEW_CONTROLS[(VIEW_CONTROLS.index(self.control) + 1)
                                           % len(VIEW_CONTROLS)])

    def _pi_command(self, x_ref: float) -> float:
        """Pi feedforward for x_ref at the Po the controller assumes (0 in open loop)."""
        po_ff = 0.0 if self._feedback is None else self.params.controller.po_feedforward
        if self._pi_key != (x_ref, po_ff):
            self.pi_cmd = float(pi_feedforward(self._muscle, self.params, [x_ref], self.load,
                                               po_ff)[0])
            self._pi_key = (x_ref, po_ff)
        return self.pi_cmd

    def advance(self, until: float, perturb: Callable[[float], float] | None = None) -> float:
        """Step to simulated time `until` [s]; returns the external force along +z [N]
        at the last step. `perturb(t)` [N] is added to `push`, the viewer's (mouse) force."""
        d, stepper = self.data, self.stepper
        force = self.push
        while d.time < until - 0.5 * self.dt:
            t = float(d.time)
            if perturb is not None:
                force = self.push + float(perturb(t))
                d.xfrc_applied[self.load_body, 2] = force
            x = stepper.contraction(d)
            x_ref = self.target(t)
            pi = self._pi_command(x_ref)
            self.po_cmd = 0.0 if self._feedback is None else self._feedback.update(x, x_ref)
            stepper.set_commands(d, pi, self.po_cmd)
            stepper.step(d, 1)
        return force

    def texts(self) -> list[tuple]:
        """Overlay text for `mujoco.viewer.Handle.set_texts`: state (top left), keys
        (bottom left)."""
        pi, po = self.pressures()
        x_ref = self.target(self.time)
        push = float(self.data.xfrc_applied[self.load_body, 2])  # mouse and script
        state = ("t\nx\ntarget\nerror\nPi\nPo\ncontrol\nload\npush",
                 f"{self.time:.1f} s\n{self.x / MM:.2f} mm\n{x_ref / MM:.2f} mm ({self.mode})\n"
                 f"{(self.x - x_ref) / MM:+.2f} mm\n{pi / MPA:.3f} MPa\n{po / MPA:.3f} MPa\n"
                 f"{self.control}\n{self.load:.0f} N\n{push:+.1f} N")
        keys = ("Up / Down\nHome\nEnd\ndouble-click, Ctrl + right drag",
                "target +-5 mm\ntarget: step, sine, fixed\ncontrol: pi, pid, open\n"
                "select and pull the load")
        font = mujoco.mjtFontScale.mjFONTSCALE_150
        return [(font, mujoco.mjtGridPos.mjGRID_TOPLEFT, *state),
                (font, mujoco.mjtGridPos.mjGRID_BOTTOMLEFT, *keys)]


def check_display(who: str = "wpam view") -> None:
    """Raise ViewerUnavailable (one line, naming `who` needs the window) unless a GLFW
    window can be opened."""
    if sys.platform.startswith("linux") and not (os.environ.get("DISPLAY")
                                                 or os.environ.get("WAYLAND_DISPLAY")):
        raise ViewerUnavailable(f"{who} needs a display: DISPLAY is not set (run it on a "
                                "desktop, over ssh -X, or under Xvfb; `wpam render` makes "
                                "videos headless)")
    import glfw  # noqa: PLC0415 (mujoco's own dependency; only the viewer needs it)

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        ok = glfw.init()
    if not ok:
        why = "; ".join(str(w.message) for w in caught) or "glfw.init() failed"
        raise ViewerUnavailable(f"{who} cannot open a window on display "
                                f"{os.environ.get('DISPLAY', '')!r}: {why}")


@contextlib.contextmanager
def console_log_only() -> Iterator[None]:
    """MuJoCo's log to the console alone while inside: its default handler also writes
    MUJOCO_LOG.TXT into the working folder, which a viewer that fails to open (a fatal
    error in its window thread) would leave behind in the user's folder."""
    config = mujoco.MjLogConfig.get()
    to_file = config.logto_file
    config.logto_file = False
    mujoco.MjLogConfig.set(config)
    try:
        yield
    finally:
        config.logto_file = to_file
        mujoco.MjLogConfig.set(config)


def view(params: Params, *, load: float = 100.0, control: str = "pi",
         target: str | float = "step", dt: float = 1e-3, duration: float | None = None,
         realtime: bool = True, perturb: Callable[[float], float] | None = None,
         on_frame: Callable[[float, mujoco.viewer.Handle], None] | None = None) -> ViewTrace:
    """Open the viewer and run the rig until the window closes or `duration` [s] of
    simulated time have passed.

    Args:
      params, load, control, target, dt: as `LiveRig` (target: "step", "sine" or [m]).
      duration: stop after this much simulated time [s] (None: until the window closes).
      realtime: pace the simulation by the wall clock; False runs it as fast as it goes
        (scripts and tests).
      perturb: external force on the load along +z [N] as a function of time [s], added
        to the mouse's (scripted perturbations).
      on_frame: called with the simulated time [s] and the viewer's handle after each
        frame is handed to the viewer (scripts: screenshots, or a drag through
        `handle.perturb`, the struct the mouse fills in).
    Returns the state at each frame. Raises ViewerUnavailable without a display.
    """
    if duration is not None:
        duration = check_range("duration", duration, 0.0, 1e6, "s", lo_open=True)
    rig = LiveRig(params, load, control, target, dt)
    check_display()
    import mujoco.viewer  # noqa: PLC0415 (GLFW; only with a display)

    from wpam_mj.visualisation.decor import MuscleDecor  # noqa: PLC0415 (drawing code; only here)

    decor = MuscleDecor(params)

    keys: queue.SimpleQueue[int] = queue.SimpleQueue()  # filled by the viewer's thread
    rows = []
    frame = 1.0 / FPS
    texts_at = -math.inf
    running = set(threading.enumerate())
    with console_log_only():  # for as long as the window thread lives
        try:
            handle = mujoco.viewer.launch_passive(rig.model, rig.data, key_callback=keys.put,
                                                  show_left_ui=False, show_right_ui=False)
        except RuntimeError as err:  # e.g. macOS outside mjpython
            raise ViewerUnavailable(f"wpam view cannot open MuJoCo's viewer: {err}") from None
        # the viewer's window thread: joined after closing, since the process's exit would
        # otherwise terminate GLFW under its clean-up (a segfault at exit)
        window_threads = set(threading.enumerate()) - running
        try:
            _frame_the_rig(handle.cam)
            handle.opt.flags[mujoco.mjtVisFlag.mjVIS_TENDON] = False  # the sleeve replaces it
            with handle.lock():  # so that the first frame the window shows has the sleeve too
                _draw_muscle(handle.user_scn, decor, rig)
            start = time.perf_counter()
            while handle.is_running() and (duration is None or rig.time < duration - 0.5 * dt):
                handle.sync()  # draws this state; clears xfrc_applied, then adds the mouse's
                rig.push = float(rig.data.xfrc_applied[rig.load_body, 2])
                while not keys.empty():
                    rig.press(keys.get())
                until = rig.time + frame
                if realtime:  # follow the wall clock, at most MAX_LAG_S behind
                    until = max(until, min(time.perf_counter() - start, rig.time + MAX_LAG_S))
                if duration is not None:
                    until = min(until, duration)
                with handle.lock():
                    force = rig.advance(until, perturb)
                    _draw_muscle(handle.user_scn, decor, rig)
                if time.perf_counter() - texts_at >= TEXT_PERIOD_S:
                    handle.set_texts(rig.texts())
                    texts_at = time.perf_counter()
                pi, po = rig.pressures()
                rows.append((rig.time, rig.x, rig.target(rig.time), pi, po, force))
                if on_frame is not None:
                    on_frame(rig.time, handle)
                if realtime:
                    time.sleep(max(0.0, rig.time - (time.perf_counter() - start)))
        finally:
            handle.close()
            for thread in window_threads:
                thread.join(timeout=10.0)
    return ViewTrace(*np.array(rows, dtype=float).reshape(-1, 6).T)


def _draw_muscle(scene: mujoco.MjvScene, decor, rig: LiveRig) -> None:
    """The outer bag, sleeve and braid threads of `wpam render` at the rig's state (the
    viewer adds these decor geoms to its scene every frame)."""
    scene.ngeom = 0
    pi, po = rig.pressures()
    decor.draw(scene, rig.model, rig.data, rig.x, pi, po)


def _frame_the_rig(cam: mujoco.MjvCamera) -> None:
    """Free camera on the rig from the front (as the scene's "front" camera), movable."""
    cam.type = mujoco.mjtCamera.mjCAMERA_FREE
    cam.lookat[:] = (0.0, 0.0, 0.74)  # m: between the frame beam and the load
    cam.distance = 1.0  # m
    cam.azimuth = 90.0  # deg: looking along +y, x to the right
    cam.elevation = -8.0  # deg
