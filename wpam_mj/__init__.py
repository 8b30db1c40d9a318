"""wpam-mj: MuJoCo simulator of the double-air-chamber pneumatic artificial muscle (W-PAM)."""

import importlib.util as _importlib_util
import os as _os
import sys as _sys

if _sys.platform.startswith("linux") and not _os.environ.get("DISPLAY"):
    _os.environ.setdefault("MUJOCO_GL", "egl")  # headless EGL; must precede `import mujoco`

from wpam_mj import engine as _engine
from wpam_mj import plugin as _plugin
from wpam_mj.params import Params, ParameterError, preset
from wpam_mj.results import SimResult
from wpam_mj.loop_contract import SimulationDiverged
from wpam_mj.simulate import Drive

# `wpam_mj.simulate` is the module; run a simulation with `wpam_mj.simulate.simulate`.
__all__ = ["Drive", "Params", "ParameterError", "SimResult", "SimulationDiverged", "preset"]
__version__ = "0.1.0"

# Register the `wpam_mj.muscle` actuator plugin (built at first use; docs/plugin.md), or,
# where it cannot be built, a stand-in that lets MJCF naming it parse for the Python engine.
if _plugin.load() is None:
    _engine.register_stand_in()

if _importlib_util.find_spec("gymnasium") is not None:  # the optional `rl` extra
    from gymnasium.envs.registration import register as _register

    _register(id="wpam_mj/WPAM-v0", entry_point="wpam_mj.gym_env:WPAMEnv")
