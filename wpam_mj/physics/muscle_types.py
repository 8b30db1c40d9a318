"""The muscle types, each in one place: what it has and how it differs from the W-PAM.

A muscle type is a preset of the parameters (`params.preset(name)` applies its
`overrides` on top of the calibrated W-PAM) plus what the rest of the package needs to
know about it: whether it has an outer chamber for Po to fill (the simulation refuses Po
on a muscle without one, a fit replays it with Po held at 0, the renderer draws no outer
bag), its colour in figures and a few words for the command line's help. The command line
offers every type here (`--preset`), and the plugin's MJCF attribute `preset` takes the
same names. A new muscle type without new physics is one entry of `MUSCLE_TYPES`.

This module imports nothing of wpam_mj: `params` builds on it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Mapping


@dataclass(frozen=True)
class MuscleType:
    """One muscle type (see the module docstring)."""

    name: str  # the preset's name: --preset, the plugin's `preset` attribute, file names
    outer_chamber: bool  # an outer bag around the inner one, for Po to fill
    colour: str  # its line colour where figures compare the types
    brief: str  # what sets it apart, in a few words (the command line's --preset help)
    # the parameter values that differ from the W-PAM's, as {section: {field: value}}
    overrides: Mapping[str, Mapping[str, float]] = field(default_factory=dict)


MUSCLE_TYPES: Mapping[str, MuscleType] = MappingProxyType({t.name: t for t in (
    # The paper's double-air-chamber muscle: an RLAM inside an outer bag; its calibrated
    # values are models/wpam/calibrated.toml.
    MuscleType("wpam", True, "tab:blue", "double chamber"),
    # A bare RLAM has no outer bag: nothing for Po to push on.
    MuscleType("rlam", False, "tab:red", "no outer chamber", {"muscle": {"axial_area": 0.0}}),
    # Rubber McKibben muscle of the same braid: K_R is an estimate for a 1.5 mm latex tube
    # (Chou & Hannaford 1996 report tens of N of elastic loss over the stroke), friction
    # between a rubber tube and a sleeve is much lower than for a loose airbag (paper
    # §2.2). A McKibben muscle is the tube in its sleeve: no outer bag, so no Po.
    MuscleType("mckibben", False, "tab:green", "rubber tube",
               {"muscle": {"rubber_stiffness": 3000.0, "friction_coeff": 0.01,
                           "friction_const": 1.0, "axial_area": 0.0}}),
)})

# Every type, alphabetically: the order in which the Fig. 3 comparison runs, draws and
# lists them.
COMPARED_TYPES = tuple(sorted(MUSCLE_TYPES))
