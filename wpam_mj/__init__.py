"""wpam-mj: MuJoCo simulator of the double-air-chamber pneumatic artificial muscle (W-PAM)."""

import importlib.util as _importlib_util

# No GL backend is chosen here (loading EGL breaks PyTorch): wpam_mj.visualisation.gl, where
# rendering starts.
from wpam_mj.simulation import engine as _engine
from wpam_mj.simulation import plugin as _plugin
from wpam_mj.physics.params import Params, ParameterError, preset
from wpam_mj.simulation.results import SimResult
from wpam_mj.simulation.loop_contract import SimulationDiverged
from wpam_mj.simulation.simulate import Drive

# `wpam_mj.simulation.simulate` is the module; run a simulation with
# `wpam_mj.simulation.simulate.simulate`.
__all__ = ["Drive", "Params", "ParameterError", "SimResult", "SimulationDiverged", "preset"]
__version__ = "0.1.0"

# Register the `wpam_mj.muscle` actuator plugin (built at first use; docs/plugin.md), or,
# where it cannot be built, a stand-in that lets MJCF naming it parse for the Python engine.
if _plugin.load() is None:
    _engine.register_stand_in()

if _importlib_util.find_spec("gymnasium") is not None:  # the optional `rl` extra
    from wpam_mj.environments.registry import register_all as _register_all

    _register_all()
