"""Pantograph geometry of the braided sleeve (McKibben-type muscle).

A thread of fixed length b wound n turns around the sleeve at angle theta to the axis
(Chou & Hannaford, IEEE Trans. Robot. Autom. 12(1), 1996, eqs. 1-5; the paper's ref. [17]):

    L = b cos(theta)                 active length            [m]
    D = b sin(theta) / (n pi)        diameter                 [m]
    V = pi D^2 L / 4 = L (b^2 - L^2) / (4 pi n^2)             [m^3]
    S = dV/dx = (3 L^2 - b^2) / (4 pi n^2)                    [m^2]

with the contraction x = L0 - L (m, positive = shorter). S is the effective area that
turns a pressure difference into axial tension (paper eq. 3). The bag cannot grow past
its maximum diameter, which bounds the contraction at `max_contraction` (a hard stop).

Methods take floats (inside the per-step loop) or numpy arrays (feedforward, plots);
np.sqrt of a float is the correctly rounded IEEE sqrt, like C's (see
`wpam_mj/simulation/muscle_plugin.c`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from wpam_mj.physics.params import Braid


@dataclass(frozen=True)
class BraidGeometry:
    """Derived braid constants for one `Braid` parameter set (SI units)."""

    natural_length: float  # L0 [m]
    thread_length: float  # b [m]
    turns: float  # n [1]
    max_contraction: float  # x at D = D_max [m]

    @classmethod
    def from_params(cls, braid: Braid) -> "BraidGeometry":
        b = braid.natural_length / math.cos(braid.braid_angle)
        n = b * math.sin(braid.braid_angle) / (math.pi * braid.natural_diameter)
        # D = D_max  <=>  b^2 - L^2 = (n pi D_max)^2; `Braid` guarantees the bag fills
        # before the locking angle, so this length is real and S > 0 up to it.
        radial = n * math.pi * braid.max_diameter
        length_at_stop = math.sqrt(b * b - radial * radial)
        return cls(braid.natural_length, b, n, braid.natural_length - length_at_stop)

    def length(self, x: float) -> float:
        """Active length L = L0 - x [m]."""
        return self.natural_length - x

    def diameter(self, x: float) -> float:
        """Sleeve diameter D(x) [m] (Chou & Hannaford eq. 2)."""
        L = self.natural_length - x
        return np.sqrt(self.thread_length ** 2 - L * L) / (self.turns * math.pi)

    def volume(self, x: float) -> float:
        """Inner-bag volume V(x) [m^3]."""
        L = self.natural_length - x
        return L * (self.thread_length ** 2 - L * L) / (4.0 * math.pi * self.turns ** 2)

    def area(self, x: float) -> float:
        """Effective area S(x) = dV/dx [m^2] (Chou & Hannaford eq. 5)."""
        L = self.natural_length - x
        return (3.0 * L * L - self.thread_length ** 2) / (4.0 * math.pi * self.turns ** 2)
