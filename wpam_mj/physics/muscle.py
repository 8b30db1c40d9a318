"""Muscle tension and bag/sleeve friction (paper §2.2, eqs. 1-7, extended by Po).

All pressures are gauge pressures in Pa (the paper's P - Pa), forces in N, x in m,
contraction positive. With the pressure difference across the inner bag dP = Pi - Po:

    T(x)  = Kf (max(dP, 0) S(x) - Fco(x)) - A_ax Po   tension on the load   (eqs. 1-3)
    Ff(x) = mu max(dP, 0) S(x) + F_f0                  dry-friction level    (eq. 4)
    Fco   = pi K_R (D(x) - D0)                         rubber term           (eq. 7)

S = dV/dx is the inner bag's volume change per unit contraction, so dP S is the ideal
(virtual-work) tension of the pressure difference, and Kf in [0.5, 1] is the efficiency
a real braided muscle delivers of it (end effects, sleeve thickness; Chou & Hannaford
1996; Tondu & Lopez 2000): the same S moves the air, so the work the air does and the
work on the load agree up to Kf. Eq. 1 applies Kf to the rubber term as well
(F_out = Kf (F_ex - F_co) - F_f). dP is eq. 3's pressure difference with Pa replaced by
Po (§2.2, last paragraph): a bag squeezed flat (Pi < Po) pulls nothing. A_ax Po is Po
acting on the end fittings inside the outer bag: by virtual work it is the outer
chamber's volume loss per unit contraction beyond S (see `wpam_mj.physics.pneumatics`), at most
the bag's cross-section pi D_bag^2 / 4. F_f0 is a pressure-independent friction floor.
Friction opposes motion (eqs. 1-2); its stiction is enforced by MuJoCo's tendon
frictionloss with the no-slip solver (`wpam_mj.simulation.model`).

A muscle pulls; it cannot push (`tendon_force`). The braid and the bag pull with
Kf (dP S - Fco) where that is positive and go slack where it is not; the outer bag's air
pushes the end fittings apart with A_ax Po. Where the fittings hang on a cable or tendon
(free, MuJoCo's default for the plugin), nothing can carry that push through them: the
force on the tendon is max(T, 0). Where rigid parts hold them on one axis (guided: the
paper's hung rig, the top fitting on the frame under the load cell, the bottom one on the
load's linear guide, `models/wpam/wpam.xml`), the push reaches the load: the force is
max(Kf (dP S - Fco), 0) - A_ax Po, negative where Po outweighs the braid's pull. Both
equal T wherever T > 0, so the static equilibria below hold for either.

The static equilibria follow eqs. 5-6: at rest on the branch of motion direction s
(+1 contracting, -1 extending, 0 frictionless), T - s Ff = F_load, i.e.
    Pi = Po + (F_load + Kf Fco + A_ax Po + s F_f0) / ((Kf - s mu) S).

The equations are `wpam_mj.physics.kernel`'s (every engine runs them); this class binds
them to one parameter set for the analysis code, on floats or, for `equilibrium_pressure`,
arrays.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from wpam_mj.physics import kernel
from wpam_mj.physics.geometry import BraidGeometry
from wpam_mj.physics.kernel_codegen import array_kernel
from wpam_mj.physics.params import Muscle, Params


@dataclass(frozen=True)
class MuscleModel:
    """Tension and friction for one parameter set; float in, float out."""

    geometry: BraidGeometry
    output_coeff: float  # Kf [1]
    friction_coeff: float  # mu [1]
    friction_const: float  # F_f0 [N]
    axial_area: float  # A_ax [m^2]
    rubber_stiffness: float  # K_R [N/m]
    natural_diameter: float  # D0 [m]

    @classmethod
    @functools.lru_cache(maxsize=256)
    def from_params(cls, params: Params) -> "MuscleModel":
        """The model of `params`, built once per parameter set (both are immutable), so
        every user asks for it where it needs it instead of passing one along."""
        m: Muscle = params.muscle
        return cls(BraidGeometry.from_params(params.braid), m.output_coeff, m.friction_coeff,
                   m.friction_const, m.axial_area, m.rubber_stiffness,
                   params.braid.natural_diameter)

    def rubber_force(self, x: float) -> float:
        """Fco(x) = pi K_R (D - D0) [N] (paper eq. 7 with r = D/2)."""
        return kernel.rubber_force(self.geometry.diameter(x), self.rubber_stiffness,
                                   self.natural_diameter)

    def tension(self, x: float, pi: float, po: float) -> float:
        """Frictionless tension on the load [N], contraction positive."""
        return kernel.tension(pi, po, self.geometry.area(x), self.rubber_force(x),
                              self.output_coeff, self.axial_area)

    def tendon_force(self, x: float, pi: float, po: float, guided: bool = False) -> float:
        """The force [N] the muscle pulls its tendon with (the module docstring): max(T, 0)
        on free end fittings; with `guided` ones, the braid's pull less Po's push."""
        return kernel.tendon_force(pi, po, self.geometry.area(x), self.rubber_force(x),
                                   self.output_coeff, self.axial_area, guided)

    def friction(self, x: float, pi: float, po: float) -> float:
        """Dry-friction level Ff >= 0 [N] (paper eq. 4 plus a constant part)."""
        return kernel.friction_level(pi, po, self.geometry.area(x), self.friction_coeff,
                                     self.friction_const)

    def equilibrium_pressure(self, x: float, load: float, po: float,
                             direction: float = 0.0) -> float:
        """Pi [Pa] that holds contraction x under `load` [N] at external pressure `po`.

        direction = +1: on the contracting branch (paper eq. 5, Pi_C); -1: extending
        (eq. 6, Pi_E); 0: frictionless; values between weight the friction band.
        Works elementwise on arrays of x; inf where the braid cannot hold the load.
        """
        args = (float(direction), self.output_coeff, self.friction_coeff,
                self.friction_const, self.axial_area)
        if isinstance(x, np.ndarray) or isinstance(po, np.ndarray) \
                or isinstance(load, np.ndarray):
            x = np.asarray(x, dtype=float)
            pi = array_kernel().equilibrium_pressure(
                po, load, args[0], self.geometry.area(x), self.rubber_force(x), *args[1:])
            return float(pi) if pi.ndim == 0 else pi
        return kernel.equilibrium_pressure(po, load, args[0], self.geometry.area(x),
                                           self.rubber_force(x), *args[1:])

    def friction_share(self, x, load: float, pi, po: float):
        """The branch at which Pi [Pa] holds contraction x [m] under `load` [N] at `po`
        [Pa]: `equilibrium_pressure` solved for its direction s (1 on the contracting
        branch, eq. 5; -1 extending, eq. 6; above 1 beyond the contracting branch, where
        the muscle at rest would contract further). With D = (Pi - Po) S and
        N = F + A_ax Po + Kf Fco, D (Kf - s mu) = N + s F_f0 gives
        s = (Kf D - N) / (F_f0 + mu D). Elementwise on arrays of x or pi."""
        x = np.asarray(x, dtype=float)
        drive = (np.asarray(pi, dtype=float) - po) * self.geometry.area(x)
        rest = load + self.axial_area * po + self.output_coeff * self.rubber_force(x)
        return (self.output_coeff * drive - rest) / (self.friction_const
                                                     + self.friction_coeff * drive)

    def equilibrium_contraction(self, pi: float, po: float, load: float,
                                direction: int = 0) -> float:
        """Contraction x [m] at rest for pressures and load; clipped to the hard stops."""
        from scipy.optimize import brentq  # noqa: PLC0415 (scipy costs 0.7 s to import)

        x_max = self.geometry.max_contraction
        s = float(direction)

        def net(x: float) -> float:
            return self.tension(x, pi, po) - s * self.friction(x, pi, po) - load

        if net(0.0) <= 0.0:
            return 0.0
        if net(x_max) >= 0.0:
            return x_max
        return brentq(net, 0.0, x_max, xtol=1e-12)
