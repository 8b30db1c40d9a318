"""Load the shipped rig MJCF and apply a parameter set and run to it by small, named edits.

`rig_spec` is the rig as an MjSpec: its ``wpam_mj.muscle`` instance configured with every
parameter (exactly: floats as their shortest round-trip text), the control mode and its
input channels, the load mass, stroke and slide damping. `build_model` compiles it for the
compiled plugin, or for the Python engine (`wpam_mj.simulation.engine.python_model`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import mujoco

from wpam_mj.simulation import engine, stand_in
from wpam_mj.simulation import plugin
from wpam_mj.physics import pneumatics
from wpam_mj.physics.geometry import BraidGeometry
from wpam_mj.physics.params import Params
from wpam_mj.errors import ParameterError
from wpam_mj.simulation.context import RunContext
from wpam_mj.units import STANDARD_GRAVITY
from wpam_mj.paths import MODEL_XML


@dataclass(frozen=True)
class MuscleIndex:
    """Where the muscle lives in a model made for the Python engine (by name)."""

    qpos: int  # the contraction joint's qpos address
    dof: int  # its dof address (qvel, damping)
    actuator: int  # the force motor carrying -tension
    tendon: int  # the tendon carrying the friction level

    @classmethod
    def of(cls, model: mujoco.MjModel) -> "MuscleIndex":
        joint = model.joint("contraction")
        return cls(int(joint.qposadr[0]), int(joint.dofadr[0]),
                   model.actuator(f"{INSTANCE}_force").id, model.tendon("muscle").id)


INSTANCE = "muscle"  # the rig's plugin instance


def check_chamber_step(params: Params, dt: float) -> None:
    """Refuse a dt [s] at which the explicit chamber update would be unstable
    (`wpam_mj.physics.pneumatics.largest_stable_dt`), naming the conductance and the dt it
    needs; every path that steps the muscle calls it (the plugin refuses the same at
    compile time)."""
    limit, name = pneumatics.largest_stable_dt(params)
    if dt > limit:
        raise ParameterError(f"{name} = {params.value(name):g} m^3/(s Pa) fills its chamber "
                             f"too fast for dt = {dt:g} s (the explicit chamber update "
                             f"would oscillate or diverge); use dt <= {limit:.3g} s")


def rig_spec(context: RunContext, *, start_at_rest: bool = False,
             feedforward_load: float = 0.0, xml: str | Path = MODEL_XML) -> mujoco.MjSpec:
    """The hung-muscle MJCF with a run's context applied (validated where it was made).

    Args:
      context: the run's: its parameter set's plant (SI) written into the instance's
        configuration; its load [N] (the load mass is load / g); its physics time step
        dt [s]; its control, the plugin's control mode: the instance gets every input
        channel of it (`wpam_mj.simulation.plugin.CONTROLS`) that the muscle type takes
        (no Po channel without an outer chamber), one actuator each, named after the
        channel.
      start_at_rest: the regulators and chambers start settled at the first commands.
      feedforward_load: the load [N] the in-plugin Pi feedforward holds (used only when no
        Pi command channel is given; the rig always gives one).
      xml: MJCF file (the scene file for rendering).
    """
    params = context.params.plant  # the simulated plant (`Params.plant_deviation`)
    load, dt, control = context.load, context.dt, context.control
    stand_in.register_stand_in()
    spec = mujoco.MjSpec.from_file(str(xml))
    spec.option.timestep = dt
    spec.option.gravity = (0.0, 0.0, -STANDARD_GRAVITY)
    spec.geom("load_mass").mass = load / STANDARD_GRAVITY
    joint = spec.joint("contraction")
    joint.range = (0.0, BraidGeometry.from_params(params.braid).max_contraction)
    joint.damping[0] = params.muscle.damping
    mode = plugin.control_mode(control)
    instance = next(p for p in spec.plugins if p.name == INSTANCE)
    # the rig's own attributes stay (end_fittings: how its end fittings carry Po's push)
    instance.config = {**{k: v for k, v in dict(instance.config).items()
                          if k in plugin.INSTANCE_WORDS},
                       "preset": params.preset, "control": control,
                       "start": "rest" if start_at_rest else "vented",
                       "feedforward_load": repr(float(feedforward_load)),
                       **{key: repr(float(params.value(key)))
                          for key, _ in plugin.parameter_fields()}}
    shipped = [a for a in spec.actuators if a.plugin.name == INSTANCE]
    for act in shipped:
        act.name = ""  # free the names for the run's channels
    for channel in mode.channels_for(params.outer_chamber):
        act = spec.add_actuator(name=f"{INSTANCE}_{channel}", target="muscle",
                                trntype=mujoco.mjtTrn.mjTRN_TENDON)
        act.plugin = shipped[0].plugin  # the reference to the instance, as parsed
    for act in shipped:
        spec.delete(act)
    return spec


def build_model(params: Params, load: float, dt: float = 1e-3, *,
                xml: str | Path = MODEL_XML) -> mujoco.MjModel:
    """The rig compiled as the Python engine sees it (plain motors; `MuscleIndex` finds
    the muscle): for readers of its mechanics (the linear model, drawing) and the
    bare-step benchmark. Compiled at a step the chambers can take (the rule table refuses
    a longer one), as only its mechanics are read."""
    dt = min(dt, pneumatics.largest_stable_dt(params)[0])
    model, _ = engine.python_model(rig_spec(RunContext(params, dt, load), xml=xml))
    return model
