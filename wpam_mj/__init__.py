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
starts. A MuJoCo outside the version range this package pins is refused in one line, and
a signal during the import (the plugin's build included) ends it cleanly
(`wpam_mj.infra.termination.importing`).
"""

from wpam_mj.infra import termination as _termination  # first, and light: signals


def _check_mujoco() -> None:
    """Refuse a MuJoCo outside the range pinned in the package's requirements."""
    import importlib.metadata as metadata  # noqa: PLC0415 (under the import's guard)
    import re  # noqa: PLC0415

    try:
        wanted = next(r for r in metadata.requires("wpam-mj") or () if re.match(r"mujoco\b", r))
    except (metadata.PackageNotFoundError, StopIteration):  # run from a source tree
        return
    try:
        found = metadata.version("mujoco")
    except metadata.PackageNotFoundError:
        raise _termination.RequirementError(f"wpam_mj needs {wanted}, which is not installed: "
                                            f"pip install '{wanted}'") from None

    def number(version: str) -> tuple[int, ...]:
        return tuple(int(part) for part in re.findall(r"\d+", version)[:3])

    for op, bound in re.findall(r"(>=|<)\s*([\d.]+)", wanted):
        if (number(found) >= number(bound)) != (op == ">="):
            raise _termination.RequirementError(f"wpam_mj needs {wanted}, found mujoco {found}: "
                                                f"pip install '{wanted}'")


with _termination.importing("wpam_mj"):
    _check_mujoco()
    # MuJoCo's pybind11 modules swallow, or print, an exception raised inside their
    # initialisation: a signal during their import is acted on once it is done
    with _termination.deferred():
        import mujoco  # noqa: F401

    import importlib.util as _importlib_util

    from wpam_mj.control.controllers import CONTROLS
    from wpam_mj.physics.muscle_types import MUSCLE_TYPES
    from wpam_mj.physics.params import Params, preset
    from wpam_mj.errors import ParameterError
    from wpam_mj.simulation import stand_in as _stand_in
    from wpam_mj.simulation import plugin as _plugin
    from wpam_mj.simulation.loop_contract import SimulationDiverged
    from wpam_mj.simulation.context import RunContext
    from wpam_mj.simulation.results import SimResult
    from wpam_mj.simulation.execution import execute
    from wpam_mj.simulation.simulate import Drive, Run, simulate
    from wpam_mj.version import __version__

    # Where the plugin cannot be built, a stand-in lets MJCF naming it parse for the Python
    # engine.
    if _plugin.load() is None:
        _stand_in.register_stand_in()

    if _importlib_util.find_spec("gymnasium") is not None:  # the optional `rl` extra
        from wpam_mj.environments.registry import register_all as _register_all

        _register_all()

__all__ = ["CONTROLS", "Drive", "MUSCLE_TYPES", "Params", "ParameterError", "Run", "RunContext",
           "SimResult", "SimulationDiverged", "__version__", "execute", "preset", "simulate"]
