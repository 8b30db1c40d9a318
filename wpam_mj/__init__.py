"""wpam-mj: MuJoCo simulator of the double-air-chamber pneumatic artificial muscle (W-PAM).

The public face is flat; the code lives in sub-packages by concern (docs/architecture.md):
physics, control, infra, simulation, experiments, design, fitting, reproduction,
environments, visualisation and cli.

    import wpam_mj
    params = wpam_mj.preset("wpam")                        # or "rlam", "mckibben"
    result = wpam_mj.simulate(params, 100.0, drive, control="pi")

Importing the package registers the `wpam_mj.muscle` MuJoCo actuator plugin (built at
first use; docs/plugin.md), so any MJCF that declares it compiles. No GL backend is chosen
here (loading EGL breaks PyTorch): `wpam_mj.visualisation.gl` chooses where rendering
starts.
"""

import importlib.util as _importlib_util

from wpam_mj.control.controllers import CONTROLS
from wpam_mj.physics.muscle_types import MUSCLE_TYPES
from wpam_mj.physics.params import Params, ParameterError, preset
from wpam_mj.simulation import engine as _engine
from wpam_mj.simulation import plugin as _plugin
from wpam_mj.simulation.loop_contract import SimulationDiverged
from wpam_mj.simulation.results import SimResult
from wpam_mj.simulation.simulate import Drive, Run, simulate, simulate_many
from wpam_mj.version import __version__

__all__ = ["CONTROLS", "Drive", "MUSCLE_TYPES", "Params", "ParameterError", "Run", "SimResult",
           "SimulationDiverged", "__version__", "preset", "simulate", "simulate_many"]

# Where the plugin cannot be built, a stand-in lets MJCF naming it parse for the Python
# engine.
if _plugin.load() is None:
    _engine.register_stand_in()

if _importlib_util.find_spec("gymnasium") is not None:  # the optional `rl` extra
    from wpam_mj.environments.registry import register_all as _register_all

    _register_all()
