"""Model parameters: one frozen, typed, validated object per concern, SI units.

Every field carries its unit, its allowed range and its source in the field metadata;
`validate` checks them all in one place. Users read mm and MPa: conversion happens at
the edges (CLI, plots, CSV headers), never here.

Presets: one per muscle type of `wpam_mj.physics.muscle_types` (wpam, rlam, mckibben),
each the calibrated W-PAM (``models/wpam/calibrated.toml``) with its type's overrides.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping


from wpam_mj import paper
from wpam_mj.physics import rules
from wpam_mj.physics.muscle_types import MUSCLE_TYPES, MuscleType
from wpam_mj.paths import MODELS_DIR
from wpam_mj.errors import ParameterError, check_range, is_number, load_toml
from wpam_mj.units import MPA


def _p(default: float, unit: str, lo: float, hi: float, source: str, *,
       lo_open: bool = False, plausible: tuple[float, float] | None = None,
       measured: bool = False) -> Any:
    """A parameter field: [lo, hi] is what the code accepts (other muscles and rigs);
    `plausible` is the physically credible range for the paper's W-PAM, with its source in
    `source`, and the bounds of `wpam calibrate` (None: not fitted); `measured`: measurable
    on a rig, so a fit leaves it fixed unless freed (`fitted_parameters`)."""
    return field(default=default, metadata=dict(unit=unit, lo=lo, hi=hi, source=source,
                                                lo_open=lo_open, plausible=plausible,
                                                measured=measured))


class _Validated:
    """Mixin: type- and range-check every float field from its metadata after construction,
    then the rules of `wpam_mj.physics.rules` among this section's fields."""

    def __post_init__(self) -> None:
        section = type(self).__name__.lower()
        for f in dataclasses.fields(self):  # type: ignore[arg-type]
            md = f.metadata
            if "lo" in md:
                name, value = f"{section}.{f.name}", getattr(self, f.name)
                if not is_number(value):
                    bracket = "(" if md["lo_open"] else "["
                    raise ParameterError(
                        f"{name} = {value!r} is a {type(value).__name__}; expected a number "
                        f"in {bracket}{md['lo']:g}, {md['hi']:g}] {md['unit']}")
                check_range(name, value, md["lo"], md["hi"], md["unit"], lo_open=md["lo_open"])
                object.__setattr__(self, f.name, float(value))
        names = {f"{section}.{f.name}" for f in dataclasses.fields(self)}  # type: ignore[arg-type]
        rules.check(rules.rules_within(names),
                    lambda name: getattr(self, name.partition(".")[2]))


@dataclass(frozen=True)
class Braid(_Validated):
    """Braided sleeve and bags (pantograph geometry, see `wpam_mj.physics.geometry`)."""

    natural_length: float = _p(0.350, "m", 0.05, 2.0, "paper §2.3 (effective natural length)")
    natural_diameter: float = _p(0.022, "m", 0.003, 0.2, "paper §2.3")
    max_diameter: float = _p(0.042, "m", 0.004, 0.4, "paper §2.3 (bag at maximum inflation)")
    braid_angle: float = _p(0.3477, "rad", math.radians(5), math.radians(50),
                            "calibrated: thread angle to the axis at natural length; the "
                            "50 mm step target must lie inside the stroke (>= 18 deg) and the "
                            "bag must fill before the 54.7 deg locking angle (<= 25.3 deg)",
                            plausible=(math.radians(18.0), math.radians(25.0)))
    outer_bag_length: float = _p(0.420, "m", 0.05, 3.0, "paper §2.3")
    outer_bag_diameter: float = _p(0.060, "m", 0.005, 0.5, "paper §2.3")


@dataclass(frozen=True)
class Muscle(_Validated):
    """Force terms of the tension model (`wpam_mj.physics.muscle`)."""

    output_coeff: float = _p(0.8, "1", 0.0, 1.0,
                             "calibrated: paper Kf (Table 1) as the efficiency of the "
                             "virtual-work force dP dV/dx, constant over the stroke; > 1 "
                             "would create work. Models with an inextensible braid "
                             "overestimate measured force by up to 70 % (Chambers & "
                             "Wereley, Actuators 2022, 11, 219: >= 0.59 of it), and end "
                             "effects at the rigid fittings cut it further as the bag nears "
                             "its full diameter (Tondu, J. Intell. Mater. Syst. Struct. "
                             "2012), which the static ramps reach at 50 N: a constant "
                             "averaged over the stroke lies below 0.59, down to 0.5",
                             lo_open=True, plausible=(0.5, 1.0))
    friction_coeff: float = _p(0.2, "1", 0.0, 1.0,
                               "calibrated: paper mu (eq. 4), friction per unit of the "
                               "pressure force dP S; polymer film on a polyester braid "
                               "(Coulomb coefficients 0.1-0.5)", plausible=(0.0, 0.5))
    friction_const: float = _p(5.0, "N", 0.0, 500.0,
                               "calibrated: pressure-independent friction (sleeve and bag "
                               "folds at rest)", plausible=(0.0, 30.0))
    axial_area: float = _p(5e-4, "m^2", 0.0, 0.05,
                           "calibrated: area on which Po pushes the end fittings apart; at "
                           "most the outer bag's cross-section pi (0.06 m)^2 / 4",
                           plausible=(0.0, 2.8e-3))
    rubber_stiffness: float = _p(0.0, "N/m", 0.0, 1e6,
                                 "paper eq. 7 K_R; 0 for a non-stretchable bag (RLAM)")
    damping: float = _p(20.0, "N s/m", 0.0, 1e5,
                        "estimate: viscous losses of the linear guide and the hanging mass "
                        "(tens of N s/m at most); not fitted", plausible=(0.0, 50.0),
                        measured=True)


@dataclass(frozen=True)
class Pneumatics(_Validated):
    """Two SMC ITV2031-like regulators feeding the chambers (`wpam_mj.physics.pneumatics`)."""

    p_min: float = _p(0.005 * MPA, "Pa", 0.0, 1.0 * MPA, "ITV2031 range, paper §2.3")
    p_max: float = _p(0.5 * MPA, "Pa", 0.0, 1.0 * MPA, "ITV2031 range, paper §2.3")
    time_constant: float = _p(0.083, "s", 0.0, 5.0,
                              "ITV-series first-order lag identified from echo-step data "
                              "(porcaro_2026's regulator models: 83 ms)",
                              plausible=(0.05, 0.1), measured=True)
    dead_time: float = _p(0.02, "s", 0.0, 1.0,
                          "ITV-series dead time identified from echo-step data "
                          "(porcaro_2026: 20-21 ms pilot models, 45 ms rounded)",
                          plausible=(0.02, 0.045), measured=True)
    inner_conductance: float = _p(6e-9, "m^3/(s Pa)", 0.0, 1e-6,
                                  "calibrated: ISO 6358 C of valve + tube + fitting port; at "
                                  "most the ITV2031's 1500 L/min at 0.7 MPa abs (3.6e-8), at "
                                  "least a 1.1 mm orifice (1e-9)", lo_open=True,
                                  plausible=(1e-9, 3.6e-8))
    outer_conductance: float = _p(2e-9, "m^3/(s Pa)", 0.0, 1e-6,
                                  "calibrated: as inner_conductance, for the Po line into the "
                                  "outer bag", lo_open=True, plausible=(1e-9, 3.6e-8))
    supply_pressure: float = _p(0.6 * MPA, "Pa", 0.0, 1.0 * MPA,
                                "not stated in the paper: shop air at the usual 0.6 MPa "
                                "gauge; the ITV2031 takes at most 1.0 MPa and needs the set "
                                "pressure + 0.1 MPa (SMC catalogue)",
                                plausible=(0.5 * MPA, 0.7 * MPA), measured=True)
    supply_valve_conductance: float = _p(3.6e-8, "m^3/(s Pa)", 0.0, 1e-6,
                                         "ITV2031 catalogue: 1500 L/min (ANR), read as choked "
                                         "flow from 0.7 MPa abs (the regulator's valve and "
                                         "ports up to its outlet)", lo_open=True,
                                         measured=True)
    exhaust_valve_conductance: float = _p(3.6e-8, "m^3/(s Pa)", 0.0, 1e-6,
                                          "the catalogue states no relief flow: taken equal "
                                          "to the supply side's (one main valve, a supply "
                                          "and an exhaust seat)", lo_open=True)
    critical_ratio: float = _p(0.5, "1", 0.0, 0.99, "ISO 6358 b, typical valve value")
    tube_volume: float = _p(2.5e-5, "m^3", 0.0, 0.01, "estimate (2 m of 4 mm bore tube)")
    polytropic_index: float = _p(1.0, "1", 1.0, 1.67,
                                 "isothermal air (slow, thin-walled bags); 1.4 for adiabatic "
                                 "chambers, 1.2-1.4 measured on fast cylinders (Richer & "
                                 "Hurmuzlu 2000); docs/physics.md measures what 1.4 changes")
    atmosphere: float = _p(101325.0, "Pa", 5e4, 2e5, "standard atmosphere")


@dataclass(frozen=True)
class Controller(_Validated):
    """PI/PID on Po and the equilibrium-model feedforward on Pi (`wpam_mj.control.controllers`).

    Gains are the paper's §4 numbers: error e = x - x_r in mm, time in s, output
    u = Kp e + Ki int(e) dt + Kd de/dt in a controller unit u that `command_scale` turns
    into the Po command [MPa] (the paper does not state the unit; `wpam_mj.control.controllers`).
    """

    kp: float = _p(paper.KP, "u/mm", 0.0, 1e3, "paper §4.1")
    ki: float = _p(paper.KI, "u/(mm s)", 0.0, 1e3, "paper §4.1")
    kd: float = _p(paper.KD, "u s/mm", 0.0, 1e3, "paper §4.2 (used in PID mode only)")
    command_scale: float = _p(0.1, "MPa/u", 0.0, 10.0,
                              "our reading of the paper's unitless gains: u in volts on the "
                              "ITV2031's 0-5 V input (0.5 MPa / 5 V); docs/physics.md "
                              "compares the readings", lo_open=True)
    derivative_filter: float = _p(0.02, "s", 0.0, 10.0, "our choice (first-order D filter)")
    po_cap: float = _p(paper.PO_CAP_MPA * MPA, "Pa", 0.0, 1.0 * MPA, "paper §4.2 (bag durability)")
    po_feedforward: float = _p(0.04 * MPA, "Pa", 0.0, 1.0 * MPA,
                               "protocol reading (the paper does not state it): the Po the "
                               "Pi feedforward assumes; the W-PAM's is the regulator's "
                               "minimum p_min, the least Po, so that Po only ever holds "
                               "the over-contraction back (docs/physics.md); plausible from "
                               "the regulator minimum to Fig. 9's 0.04 MPa",
                               plausible=(0.005 * MPA, 0.04 * MPA))
    feedforward_friction: float = _p(0.0, "1", 0.0, 1.2,
                                     "calibrated protocol reading of §4.1: the share of the "
                                     "friction band the Pi feedforward adds (0 frictionless, "
                                     "1 the contracting branch of eq. 5; above 1 a little "
                                     "beyond it, the 'excessive contraction state' that Po "
                                     "holds back; at most the few per cent to which the "
                                     "friction is known)", plausible=(0.0, 1.05))


@dataclass(frozen=True)
class Params:
    """Everything that defines one simulated muscle and its drive."""

    braid: Braid = field(default_factory=Braid)
    muscle: Muscle = field(default_factory=Muscle)
    pneumatics: Pneumatics = field(default_factory=Pneumatics)
    controller: Controller = field(default_factory=Controller)
    preset: str = "wpam"
    # The simulated plant's relative deviations from these nominal values, by
    # "section.field" name: ((name, delta), ...), the plant's value being value (1 + delta).
    # The controller's feedforward (the paper's equilibrium model, eqs. 5-6) keeps the
    # nominal values, as an experimenter's model does; `plant` applies them (robustness
    # samples, `wpam_mj.reproduction.robustness`).
    plant_deviation: tuple[tuple[str, float], ...] = ()

    def __post_init__(self) -> None:
        for name, cls in _SECTIONS.items():
            if not isinstance(getattr(self, name), cls):
                raise ParameterError(f"params.{name} = {getattr(self, name)!r} must be a "
                                     f"{cls.__name__}")
        if self.preset not in MUSCLE_TYPES:
            raise ParameterError(f"unknown preset {self.preset!r}; valid presets: "
                                 f"{', '.join(MUSCLE_TYPES)}")
        for name, delta in self.plant_deviation:
            if name not in _PARAMETER_NAMES or name.startswith("controller."):
                raise ParameterError(f"plant_deviation names {name!r}; it takes plant "
                                     "parameters by section.field name (models/README.md)")
            check_range(f"plant_deviation of {name}", delta, -0.5, 0.5)
        # the rules between fields of different sections (each section checks its own)
        rules.check(tuple(r for r in rules.rules_within(_PARAMETER_NAMES)
                          if len({n.partition(".")[0] for n in r.needs}) > 1), self.value)

    @property
    def muscle_type(self) -> MuscleType:
        return MUSCLE_TYPES[self.preset]

    @property
    def outer_chamber(self) -> bool:
        """Whether an outer bag surrounds the inner one for Po to fill (its muscle type)."""
        return self.muscle_type.outer_chamber

    @property
    def plant(self) -> "Params":
        """The simulated plant: these values with `plant_deviation` applied."""
        if not self.plant_deviation:
            return self
        nominal = dataclasses.replace(self, plant_deviation=())
        return nominal.with_values({name: self.value(name) * (1.0 + delta)
                                    for name, delta in self.plant_deviation})

    def replace(self, **sections: Mapping[str, float]) -> "Params":
        """Copy with some fields changed: ``p.replace(muscle={"friction_coeff": 0})``."""
        return apply_overrides(self, sections)

    def value(self, name: str) -> Any:
        """The field named "section.field": ``p.value("muscle.damping")``."""
        section, _, key = name.partition(".")
        return getattr(getattr(self, section), key)

    def with_values(self, values: Mapping[str, Any]) -> "Params":
        """Copy with fields named "section.field" changed: ``{"muscle.damping": 30.0}``."""
        if not values:
            return self
        sections: dict[str, dict[str, Any]] = {}
        for name, value in values.items():
            section, _, key = name.partition(".")
            sections.setdefault(section, {})[key] = value
        return apply_overrides(self, sections)

    def as_dict(self) -> dict[str, dict[str, float]]:
        return {s: dataclasses.asdict(getattr(self, s)) for s in _SECTIONS}


_SECTIONS = {"braid": Braid, "muscle": Muscle, "pneumatics": Pneumatics,
             "controller": Controller}


def parameter_fields() -> list[tuple[str, dataclasses.Field]]:
    """Every parameter as ("section.field", its dataclass field), in `Params` order."""
    return [(f"{section}.{f.name}", f) for section, cls in _SECTIONS.items()
            for f in dataclasses.fields(cls)]


_PARAMETER_NAMES = frozenset(key for key, _ in parameter_fields())


def fitted_parameters() -> tuple[str, ...]:
    """The plant parameters a fit frees by default, in `Params` order: those with a
    plausible range that are not `measured` on a rig, the controller's readings left out
    (a replay drives the muscle with the recorded commands, so it cannot see them)."""
    return tuple(key for key, f in parameter_fields()
                 if f.metadata["plausible"] is not None and not f.metadata["measured"]
                 and not key.startswith("controller."))


def apply_overrides(params: Params, overrides: Mapping[str, Any]) -> Params:
    """Return `params` with ``{section: {field: value}}`` applied; unknown keys raise."""
    new = {}
    for section, values in overrides.items():
        if section not in _SECTIONS:
            raise ParameterError(f"unknown parameter section {section!r}; "
                                 f"valid sections: {', '.join(_SECTIONS)}")
        if not isinstance(values, Mapping):
            raise ParameterError(f"section [{section}] must be a table of values")
        cls = _SECTIONS[section]
        names = {f.name for f in dataclasses.fields(cls)}
        for key in values:
            if key not in names:
                raise ParameterError(f"unknown parameter {section}.{key}; "
                                     f"valid names: {', '.join(sorted(names))}")
        new[section] = dataclasses.replace(getattr(params, section), **values)
    return dataclasses.replace(params, **new)


CALIBRATION_FILE = MODELS_DIR / "wpam" / "calibrated.toml"

PRESETS = tuple(MUSCLE_TYPES)


def preset(name: str = "wpam", *, calibration: str | Path | None = CALIBRATION_FILE) -> Params:
    """Parameters of a named muscle type, with the calibrated values applied.

    The RLAM and McKibben presets share the W-PAM's calibrated braid and regulators.
    `calibration`: the shipped `CALIBRATION_FILE` (used when present: before the first
    `wpam calibrate` the built-in values apply), another TOML file (which must exist),
    or None (the built-in values).
    """
    params = Params(preset=name)  # refuses an unknown name
    if calibration is not None and (Path(calibration) != CALIBRATION_FILE
                                    or CALIBRATION_FILE.exists()):
        params = apply_overrides(params, load_toml(calibration))
    return apply_overrides(params, MUSCLE_TYPES[name].overrides)


def describe(params: Params) -> list[tuple[str, float, str, str]]:
    """Rows (name, value, unit, source) for reports and the README table."""
    return [(name, value, unit, source)
            for name, value, unit, _, source in describe_with_ranges(params)]


def describe_with_ranges(params: Params) -> list[tuple[str, float, str, tuple | None, str]]:
    """Rows (name, value, unit, plausible range or None, source)."""
    rows = []
    for s in _SECTIONS:
        obj = getattr(params, s)
        for f in dataclasses.fields(obj):
            md = f.metadata
            rows.append((f"{s}.{f.name}", getattr(obj, f.name), md["unit"], md["plausible"],
                         md["source"]))
    return rows


def plausible_range(name: str) -> tuple[float, float]:
    """The plausible range of the parameter "section.field" (ParameterError if none)."""
    section, _, key = name.partition(".")
    fields = {f.name: f for f in dataclasses.fields(_SECTIONS.get(section, Params))}
    if key not in fields or fields[key].metadata.get("plausible") is None:
        raise ParameterError(f"{name} has no plausible range (not a fitted parameter)")
    return fields[key].metadata["plausible"]
