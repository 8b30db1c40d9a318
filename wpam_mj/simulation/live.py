"""The rig stepped live, command by command (environments, the viewer, the linear study).

`LiveRig` holds the hung-muscle model compiled for open-loop commands (channels Pi, Po)
on the plugin, or on the Python engine where the plugin is unavailable, and steps any
MjData of it: `set_commands`, then `step(data, n)`, which runs the same physics step as
`wpam_mj.simulation.simulate.simulate` (an episode driven by the same commands is the same run, bit
for bit). The readings are taken as the muscle will see them at the next step: the
contraction and velocity from the tendon, the chamber pressures from the muscle's state.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import mujoco

from wpam_mj.simulation import engine
from wpam_mj.simulation import plugin
from wpam_mj.simulation.loop_contract import SimulationDiverged, state_failure
from wpam_mj.simulation.context import RunContext
from wpam_mj.simulation.model import INSTANCE, check_chamber_step, rig_spec
from wpam_mj.errors import ParameterError
from wpam_mj.paths import MODEL_XML


@dataclass
class LiveRig:
    """The rig's model and what steps it (see the module docstring)."""

    model: mujoco.MjModel
    muscles: list[engine.PythonMuscle] | None  # the Python engine's; None on the plugin
    channels: tuple[int, int]  # actuators whose ctrl are the Pi and Po commands
    tendon: int
    length0: float  # tendon length at x = 0 [m]
    state: int  # the plugin instance's state address (plugin only)
    atmosphere: float  # [Pa]

    @classmethod
    def build(cls, context: RunContext, *, xml: str | Path = MODEL_XML) -> "LiveRig":
        """The rig for a live run's `context` (its parameters, load and dt, checked where
        it was made), driven open loop."""
        params = context.params
        check_chamber_step(params, context.dt)
        if not params.outer_chamber:  # every live driver commands Po (simulate refuses it too)
            raise ParameterError(f"the {params.preset} preset has no outer chamber for the "
                                 "Po command a live rig takes; use a preset with one (wpam)")
        spec = rig_spec(context, xml=xml)
        names = [f"{INSTANCE}_{c}" for c in plugin.CONTROL_BY_NAME["open"].channels]
        if plugin.available():
            model, muscles = spec.compile(), None
            state = plugin.state_address(model, INSTANCE)
        else:
            model, muscles = engine.python_model(spec)
            state = -1
        tendon = model.tendon("muscle").id
        return cls(model, muscles, tuple(model.actuator(n).id for n in names), tendon,
                   float(model.tendon_length0[tendon]), state, params.pneumatics.atmosphere)

    def set_commands(self, data: mujoco.MjData, pi_cmd: float, po_cmd: float) -> None:
        """Regulator commands [Pa gauge] from the next physics step on."""
        data.ctrl[self.channels[0]] = pi_cmd
        data.ctrl[self.channels[1]] = po_cmd

    def step(self, data: mujoco.MjData, nstep: int = 1) -> None:
        """`nstep` physics steps, then `mj_step1` (positions, velocities and sensors of the
        new state, as dm_control's own step). Raises SimulationDiverged."""
        if self.muscles is None:
            mujoco.mj_step(self.model, data, nstep=nstep)
            if data.plugin_state[self.state + plugin.FIELD["status"]]:
                raise SimulationDiverged(state_failure(data.plugin_state[self.state:]))
        else:
            (muscle,) = self.muscles
            for _ in range(nstep):
                engine.step(self.model, data, self.muscles)
                if muscle.state(data)[plugin.FIELD["status"]]:
                    raise SimulationDiverged(muscle.status(data))
        mujoco.mj_step1(self.model, data)

    def contraction(self, data: mujoco.MjData) -> float:
        """x [m], as the muscle reads it."""
        return self.length0 - float(data.ten_length[self.tendon])

    def velocity(self, data: mujoco.MjData) -> float:
        """dx/dt [m/s]."""
        return -float(data.ten_velocity[self.tendon])

    def pressures(self, data: mujoco.MjData) -> tuple[float, float]:
        """Chamber gauge pressures (Pi, Po) [Pa] the next step's force uses."""
        s = data.plugin_state[self.state:] if self.muscles is None \
            else self.muscles[0].state(data)
        return (float(s[plugin.FIELD["p_i"]]) - self.atmosphere,
                float(s[plugin.FIELD["p_o"]]) - self.atmosphere)
