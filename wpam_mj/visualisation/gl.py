"""Where offscreen rendering gets its OpenGL backend; importing the package chooses none.

mujoco reads MUJOCO_GL once, when it is first imported, and loads that backend's
libraries then. Setting MUJOCO_GL=egl on import (as the package once did) loaded EGL into
every process that imported it, and PyTorch's triton segfaults on import with EGL loaded.
So nothing here runs on import: `offscreen_context_class` is called where offscreen
rendering starts (`wpam_mj.visualisation.render`), and only then, headless on Linux with MUJOCO_GL
unset, does it switch mujoco's offscreen renderer to EGL. An explicit MUJOCO_GL always
wins (`MUJOCO_GL=egl`, `osmesa` or `glfw`, exported before Python starts).
"""

from __future__ import annotations

import contextlib
import os
import sys
import warnings
from collections.abc import Iterator


def headless() -> bool:
    """Linux without an X display: GLFW cannot open a context, EGL can."""
    return sys.platform.startswith("linux") and not os.environ.get("DISPLAY")


def offscreen_context_class() -> type | None:
    """The GL context class `mujoco.Renderer` will use, switched to EGL if headless and
    MUJOCO_GL is unset (mujoco's default then is GLFW, which needs a display)."""
    from mujoco.rendering.classic import gl_context  # noqa: PLC0415 (only when rendering)

    if headless() and not os.environ.get("MUJOCO_GL"):
        from mujoco.egl import GLContext  # noqa: PLC0415 (loads libEGL: only here)

        # mujoco.Renderer looks the class up in this module at construction time
        gl_context.GLContext = GLContext
    return getattr(gl_context, "GLContext", None)


def backend_hint() -> str:
    """One line: which backend offscreen rendering uses and what to set instead."""
    cls = offscreen_context_class()
    chosen = cls.__module__.split(".")[1] if cls is not None else "none"
    wanted = os.environ.get("MUJOCO_GL", "<unset>")
    return (f"MUJOCO_GL={wanted}, offscreen rendering uses mujoco's {chosen!r} backend; "
            "headless, export MUJOCO_GL=egl (or osmesa) before starting Python")


@contextlib.contextmanager
def quiet_display_probe() -> Iterator[None]:
    """dm_control probes GLFW when imported; without a display that probe only warns
    (GLFWError: DISPLAY is missing), which is noise for a process that never renders."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=r".*DISPLAY environment variable")
        yield
