"""Load the shipped MJCF and apply a parameter set to it by small, named edits."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import mujoco

from wpam_mj.geometry import BraidGeometry
from wpam_mj.params import STANDARD_GRAVITY, ParameterError, Params, check_range
from wpam_mj.paths import MODEL_XML

LOAD_RANGE_N = (1.0, 2000.0)  # N: what a hanging mass on this rig can sensibly be
DT_RANGE_S = (1e-5, 0.005)  # s: the pneumatics need a step well below their time constants


def check_load(load: float) -> float:
    """Validate a hanging load [N]."""
    return check_range("load", load, *LOAD_RANGE_N, "N")


def check_dt(dt: float, *, divides: float | None = None, name: str = "dt") -> float:
    """Validate a physics time step [s]; with `divides` [s] (a recording period) it must
    also be a whole fraction of it, so that the stated range is the range applied."""
    dt = check_range(name, dt, *DT_RANGE_S, "s")
    if divides is not None:
        steps = round(divides / dt)
        if steps < 1 or abs(steps * dt - divides) > 1e-9 * divides:
            lo, hi = DT_RANGE_S
            fits = [divides / k for k in (1, 2, 4, 5, 10, 20) if lo <= divides / k <= hi]
            raise ParameterError(
                f"{name} = {dt:g} s must divide the {divides:g} s recording period into whole "
                f"steps, within [{lo:g}, {hi:g}] s (e.g. {', '.join(f'{f:g}' for f in fits)})")
    return dt


@dataclass(frozen=True)
class MuscleIndex:
    """Where the muscle lives in a compiled model, looked up by name (never raw indices)."""

    qpos: int  # the contraction joint's qpos address
    dof: int  # its dof address (qvel, damping)
    actuator: int  # the tendon motor carrying -tension
    tendon: int  # the tendon carrying the friction level

    @classmethod
    def of(cls, model: mujoco.MjModel) -> "MuscleIndex":
        joint = model.joint("contraction")
        return cls(int(joint.qposadr[0]), int(joint.dofadr[0]), model.actuator("muscle").id,
                   model.tendon("muscle").id)


def build_model(params: Params, load: float, dt: float = 1e-3, *,
                xml: str | Path = MODEL_XML) -> mujoco.MjModel:
    """Compile the hung-muscle MJCF and set load mass, stops, damping and time step.

    Args:
      params: muscle parameters (SI).
      load: hanging load [N]; the load mass is load / g.
      dt: physics time step [s].
      xml: MJCF file (the scene file for rendering).
    """
    load = check_load(load)
    dt = check_dt(dt)
    model = mujoco.MjModel.from_xml_path(str(xml))
    model.opt.timestep = dt
    model.opt.gravity[:] = (0.0, 0.0, -STANDARD_GRAVITY)
    model.body("load").mass[0] = load / STANDARD_GRAVITY
    model.joint("contraction").range[:] = (
        0.0, BraidGeometry.from_params(params.braid).max_contraction)
    model.dof_damping[MuscleIndex.of(model).dof] = params.muscle.damping
    return model
