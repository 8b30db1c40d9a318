"""Pantograph geometry of the braided sleeve (McKibben-type muscle).

A thread of fixed length b wound n turns around the sleeve at angle theta to the axis
(Chou & Hannaford, IEEE Trans. Robot. Autom. 12(1), 1996, eqs. 1-5; the paper's ref. [17]):

    L = b cos(theta)                 active length            [m]
    D = b sin(theta) / (n pi)        diameter                 [m]
    V = pi D^2 L / 4 = L (b^2 - L^2) / (4 pi n^2)             [m^3]
    S = dV/dx = (3 L^2 - b^2) / (4 pi n^2)                    [m^2]

with the contraction x = L0 - L (m, positive = shorter). S is the effective area that
turns a pressure difference into axial tension (paper eq. 3).

The muscle's stroke is 0 <= x <= `max_contraction`, and the geometry is defined at every
length by holding it at the nearest end of the stroke:
  * beyond the full bag (x > max_contraction) the bag is full: it cannot grow past its
    maximum diameter, so D, V and S keep their full-bag values; the muscle is pushed
    shorter than it can pull itself, its sleeve bunching up;
  * past the natural length (x < 0) the braid is taut: its threads are inextensible and
    the bag inside it does not stretch, so D, V and S keep their natural-length values
    (a stretched muscle pulls as at x = 0; its length is held by whatever limits it).
D, V and S are continuous across both ends, so a soft joint or tendon limit at an end
holds the muscle there smoothly (the chambers' air sees the same S there,
`wpam_mj.physics.pneumatics`), and the plugin reports a muscle well outside the stroke
(`wpam_mj.simulation.plugin.STROKE_TOLERANCE`).

The equations are `wpam_mj.physics.kernel`'s, which every engine runs: methods take
floats (the kernel's functions as they are) or numpy arrays (its array form,
`wpam_mj.physics.kernel_codegen.array_kernel`, element for element the same numbers).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from wpam_mj.physics import kernel
from wpam_mj.physics.kernel_codegen import array_kernel
from wpam_mj.physics.params import Braid


@dataclass(frozen=True)
class BraidGeometry:
    """Derived braid constants for one `Braid` parameter set (SI units)."""

    natural_length: float  # L0 [m]
    thread_length: float  # b [m]
    turns: float  # n [1]
    max_contraction: float  # x at D = D_max [m]
    thread_sq: float  # b^2 [m^2]
    volume_denom: float  # 4 pi n^2 [1]
    diameter_denom: float  # n pi [1]

    @classmethod
    def from_params(cls, braid: Braid) -> "BraidGeometry":
        return cls.of(braid.natural_length, braid.braid_angle, braid.natural_diameter,
                      braid.max_diameter)

    @classmethod
    def of(cls, natural_length: float, braid_angle: float, natural_diameter: float,
           max_diameter: float) -> "BraidGeometry":
        """The geometry of L0 [m], theta0 [rad], D0 and D_max [m]."""
        n = kernel.turns(natural_length, braid_angle, natural_diameter)
        return cls(natural_length, kernel.thread_length(natural_length, braid_angle), n,
                   kernel.max_contraction(natural_length, braid_angle, natural_diameter,
                                          max_diameter),
                   kernel.thread_square(natural_length, braid_angle),
                   kernel.volume_denominator(n), kernel.diameter_denominator(n))

    def in_stroke(self, x: float) -> float:
        """x [m] held to the stroke [0, max_contraction] (the module docstring)."""
        if isinstance(x, np.ndarray):
            return array_kernel().in_stroke(x, self.max_contraction)
        return kernel.in_stroke(x, self.max_contraction)

    def length(self, x: float) -> float:
        """Active length L = L0 - x [m]."""
        return self.natural_length - x

    def diameter(self, x: float) -> float:
        """Sleeve diameter D(x) [m] (Chou & Hannaford eq. 2)."""
        f = array_kernel().diameter if isinstance(x, np.ndarray) else kernel.diameter
        return f(x, self.natural_length, self.thread_sq, self.diameter_denom,
                 self.max_contraction)

    def volume(self, x: float) -> float:
        """Inner-bag volume V(x) [m^3]."""
        f = array_kernel().volume if isinstance(x, np.ndarray) else kernel.volume
        return f(x, self.natural_length, self.thread_sq, self.volume_denom,
                 self.max_contraction)

    def area(self, x: float) -> float:
        """Effective area S(x) = dV/dx [m^2] (Chou & Hannaford eq. 5); outside the stroke,
        that of its nearest end (the module docstring)."""
        f = array_kernel().area if isinstance(x, np.ndarray) else kernel.area
        return f(x, self.natural_length, self.thread_sq, self.volume_denom,
                 self.max_contraction)
