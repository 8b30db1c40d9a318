"""wpam-mj: MuJoCo simulator of the double-air-chamber pneumatic artificial muscle (W-PAM)."""

from wpam_mj.params import Params, ParameterError, preset
from wpam_mj.results import SimResult
from wpam_mj.simulate import Drive, SimulationDiverged, simulate

__all__ = ["Drive", "Params", "ParameterError", "SimResult", "SimulationDiverged", "preset",
           "simulate"]
__version__ = "0.1.0"
