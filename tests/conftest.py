"""Shared test setup.

Import wpam_mj before any test module imports mujoco: its __init__ chooses the headless
EGL backend (MUJOCO_GL=egl when there is no display), which mujoco reads once at import.
"""

import wpam_mj  # noqa: F401
