"""wpam-mj: MuJoCo simulator of the double-air-chamber pneumatic artificial muscle (W-PAM)."""

import importlib.util as _importlib_util

# No GL backend is chosen here (loading EGL breaks PyTorch): wpam_mj.gl, where rendering starts.
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
    from wpam_mj.registry import register_all as _register_all

    _register_all()
