"""The plant: regulators, chambers and muscle force, everything but the load's motion.

Per physics step the Python engine (`wpam_mj.simulation.engine`) takes `Plant.forces` at the current
contraction, then `Plant.step` after MuJoCo's step. It composes the pieces of
`wpam_mj.physics.pneumatics` (two `Regulator`s, two `Chamber`s) with
`wpam_mj.physics.muscle.MuscleModel`;
`wpam_mj/simulation/muscle_plugin.c` has the same compute and advance, piece for piece. Pressures:
regulator set points gauge [Pa], chamber pressures absolute [Pa].
"""

from __future__ import annotations

import math

from wpam_mj.simulation.loop_contract import RunConstants, SimulationDiverged
from wpam_mj.physics.muscle import MuscleModel
from wpam_mj.physics.pneumatics import Chamber, Regulator, chamber_volumes


class Plant:
    """Pneumatic state and muscle force of one run (see the module docstring)."""

    def __init__(self, muscle: MuscleModel, k: RunConstants, *, guided: bool = False) -> None:
        self.muscle = muscle
        self.k = k
        self.guided = guided  # end fittings held on one axis (MuscleModel.tendon_force)
        self.regulator_i = Regulator(k.lag_alpha, k.delay_steps, k.p_max)
        self.regulator_o = Regulator(k.lag_alpha, k.delay_steps, k.p_max)
        self.chamber_i = Chamber(k.conductance_i, k.critical_ratio, k.atmosphere)
        self.chamber_o = Chamber(k.conductance_o, k.critical_ratio, k.atmosphere)

    @property
    def pressures(self) -> tuple[float, float]:
        """Chamber gauge pressures (Pi, Po) [Pa]."""
        pa = self.k.atmosphere
        return self.chamber_i.pressure - pa, self.chamber_o.pressure - pa

    @property
    def set_points(self) -> tuple[float, float]:
        """Regulator set pressures (Pi, Po) [Pa gauge]: what the regulators' gauges read."""
        return self.regulator_i.set_point, self.regulator_o.set_point

    def rest(self, pi_cmd: float, po_cmd: float) -> None:
        """Start at rest at the first commands [Pa gauge]: regulators settled on them and
        chambers filled to their set points, as on a rig whose regulators have been holding
        these pressures before the record starts (`wpam_mj.simulation.simulate`)."""
        pa = self.k.atmosphere
        self.regulator_i.rest(pi_cmd)
        self.regulator_o.rest(po_cmd)
        self.chamber_i.pressure = self.regulator_i.set_point + pa
        self.chamber_o.pressure = self.regulator_o.set_point + pa

    def forces(self, x: float) -> tuple[float, float]:
        """(tendon force, friction level) [N] at contraction x [m] from the chamber
        pressures at the start of the step: the force the muscle pulls with, never a push
        on free end fittings (`MuscleModel.tendon_force`)."""
        pi, po = self.pressures
        return (self.muscle.tendon_force(x, pi, po, self.guided),
                self.muscle.friction(x, pi, po))

    def step(self, x: float, v: float, pi_cmd: float, po_cmd: float) -> None:
        """Advance the regulators, then the chambers (volumes and dV/dx at x [m] held to
        the stroke, velocity v [m/s]), by one step. Raises SimulationDiverged."""
        k, muscle, geom = self.k, self.muscle, self.muscle.geometry
        set_i = self.regulator_i.update(pi_cmd)
        set_o = self.regulator_o.update(po_cmd)
        pa = k.atmosphere
        x = geom.in_stroke(x)
        area = geom.area(x)
        vol = geom.volume(x)
        v_i, v_o = chamber_volumes(vol, x, muscle.axial_area, k.bag_volume, k.tube_volume)
        p_i = self.chamber_i.step(set_i + pa, v_i, area, v, k.dt)
        p_o = self.chamber_o.step(set_o + pa, v_o, -(area + muscle.axial_area), v, k.dt)
        if not (p_i > 0.0 and p_o > 0.0 and math.isfinite(p_i) and math.isfinite(p_o)):
            raise SimulationDiverged(f"chamber pressure Pi = {p_i!r} Pa, Po = {p_o!r} Pa "
                                     "(absolute)")
