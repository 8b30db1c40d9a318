"""The declared rule set: every range a muscle's configuration must lie in, once, as data.

A rule says that one quantity, its `subject`, lies between two bounds, each a number or
the name of another quantity. Quantities are

* the parameters, by "section.field" (`wpam_mj.physics.params`); each field's own range
  is its metadata (lo, hi, lo_open), and `field_rules` lists them as rules;
* the numbers a plugin instance is given besides them (`INSTANCE_NUMBERS`);
* "timestep", the model's physics time step [s];
* the derived quantities of `DERIVED`, each computed from the others by the physics
  modules (and by the compiled plugin's mirror of them).

`CROSS_RULES` are the rules between quantities, in the order they are checked: a rule's
derived bounds are only evaluated once the rules before it hold (the full-bag contraction
needs a braid that fills before it locks). `RULES` is the whole table. `Params` checks
the rules among parameters when it is made; both engines of the plugin (the compiled
``wpam_mj.muscle`` and `wpam_mj.simulation.engine`) check them all when a model is made,
with the same line (`message`): `wpam_mj.simulation.plugin.tables_header` writes this table
into the plugin's C tables, so nothing is copied by hand (tests/test_rules.py runs every
rule on both engines).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import Callable

from wpam_mj.physics import kernel

Getter = Callable[[str], float]


@dataclass(frozen=True)
class Number:
    """A number a plugin instance takes besides the parameters: its unit and range."""

    unit: str
    lo: float
    hi: float
    meaning: str


# The instance's numbers (docs/plugin.md), each also an MJCF attribute of the plugin.
INSTANCE_NUMBERS = {
    "feedforward_load": Number("N", 0.0, 1e5, "the load the in-plugin Pi feedforward holds"),
    "contraction0": Number("m", -math.inf, math.inf,
                           "the muscle's contraction in the model's reference pose"),
}
TIMESTEP = "timestep"  # the model's option, [s]
MAX_QUEUE_STEPS = 1e6  # the most steps a regulator's dead-time queue may hold


@dataclass(frozen=True)
class Derived:
    """A quantity computed from others: its unit, what it needs, how it is computed."""

    unit: str
    needs: tuple[str, ...]
    compute: Callable[[Getter], float]


def _locking_angle(get: Getter) -> float:
    """The braid angle [rad] at which the threads lock (54.7 deg) just as the bag fills:
    D = b sin(theta) / (n pi) grows with sin(theta), so the bag reaches max_diameter before
    locking while sin(theta) max_diameter / natural_diameter < sqrt(2/3) (Chou & Hannaford
    1996; `wpam_mj.physics.geometry`)."""
    return kernel.locking_angle(get("braid.natural_diameter"), get("braid.max_diameter"))


def _bag_section(get: Getter) -> float:
    """The outer bag's cross-section pi D_bag^2 / 4 [m^2]: the most area its pressure can
    push the end fittings apart on."""
    return kernel.bag_section(get("braid.outer_bag_diameter"))


def _geometry(get: Getter):
    from wpam_mj.physics.geometry import BraidGeometry  # noqa: PLC0415 (it imports params)

    return BraidGeometry.of(get("braid.natural_length"), get("braid.braid_angle"),
                            get("braid.natural_diameter"), get("braid.max_diameter"))


def _stable_timestep(chamber: int) -> Callable[[Getter], float]:
    def compute(get: Getter) -> float:
        from wpam_mj.physics.pneumatics import stable_timesteps  # noqa: PLC0415

        return stable_timesteps(
            _geometry(get), get("muscle.axial_area"), get("braid.outer_bag_length"),
            get("braid.outer_bag_diameter"), get("pneumatics.tube_volume"),
            get("pneumatics.inner_conductance"), get("pneumatics.outer_conductance"),
            get("pneumatics.critical_ratio"), get("pneumatics.polytropic_index"))[chamber]
    return compute


_BRAID = ("braid.natural_length", "braid.braid_angle", "braid.natural_diameter",
          "braid.max_diameter")
_CHAMBERS = (*_BRAID, "muscle.axial_area", "braid.outer_bag_length",
             "braid.outer_bag_diameter", "pneumatics.tube_volume",
             "pneumatics.inner_conductance", "pneumatics.outer_conductance",
             "pneumatics.critical_ratio", "pneumatics.polytropic_index")
DERIVED = {
    "locking_angle": Derived("rad", ("braid.natural_diameter", "braid.max_diameter"),
                             _locking_angle),
    "bag_section": Derived("m^2", ("braid.outer_bag_diameter",), _bag_section),
    "max_contraction": Derived("m", _BRAID, lambda get: _geometry(get).max_contraction),
    "inner_stable_timestep": Derived("s", _CHAMBERS, _stable_timestep(0)),
    "outer_stable_timestep": Derived("s", _CHAMBERS, _stable_timestep(1)),
    "shortest_timestep": Derived("s", ("pneumatics.dead_time",),
                                 lambda get: get("pneumatics.dead_time") / MAX_QUEUE_STEPS),
}


@dataclass(frozen=True)
class Rule:
    """`subject` lies in [lo, hi] (open at an end where said); a bound is a number or a
    quantity's name. `why` says what the bounds are, in words (empty for a field's own
    range)."""

    subject: str
    lo: float | str = -math.inf
    hi: float | str = math.inf
    lo_open: bool = False
    hi_open: bool = False
    why: str = ""

    @property
    def needs(self) -> frozenset[str]:
        """The quantities the rule reads, derived ones resolved to what they need."""
        names = {self.subject, *(b for b in (self.lo, self.hi) if isinstance(b, str))}
        for name in list(names):
            if name in DERIVED:
                names |= set(DERIVED[name].needs)
        return frozenset(n for n in names if n not in DERIVED)


CROSS_RULES = (
    Rule("braid.max_diameter", lo="braid.natural_diameter", lo_open=True,
         why="the full bag is wider than at rest: above braid.natural_diameter"),
    Rule("braid.outer_bag_diameter", lo="braid.max_diameter", lo_open=True,
         why="the outer bag is wider than the full inner bag: above braid.max_diameter"),
    Rule("braid.outer_bag_length", lo="braid.natural_length",
         why="the outer bag spans the muscle's end fittings: at least braid.natural_length"),
    Rule("braid.braid_angle", lo=0.0, hi="locking_angle", hi_open=True,
         why="the bag must fill to braid.max_diameter before the threads reach the 54.7 deg "
             "locking angle"),
    Rule("muscle.axial_area", lo=0.0, hi="bag_section",
         why="at most the outer bag's cross-section pi braid.outer_bag_diameter^2 / 4"),
    Rule("pneumatics.p_min", lo=0.0, hi="pneumatics.p_max", hi_open=True,
         why="below pneumatics.p_max"),
    Rule("pneumatics.supply_pressure", lo="pneumatics.p_max", lo_open=True,
         why="above the regulator's highest output pneumatics.p_max (SMC: the set "
             "pressure + 0.1 MPa)"),
    Rule("controller.po_cap", lo="pneumatics.p_min", hi="pneumatics.p_max",
         why="within the regulator's range, pneumatics.p_min to pneumatics.p_max"),
    Rule("controller.po_feedforward", lo="pneumatics.p_min", hi="controller.po_cap",
         why="from pneumatics.p_min to controller.po_cap"),
    Rule("contraction0", lo=0.0, hi="max_contraction",
         why="the muscle's stroke, from its natural length to the full bag"),
    Rule(TIMESTEP, lo=0.0, hi="inner_stable_timestep", lo_open=True,
         why="the explicit update of the inner chamber, fed through "
             "pneumatics.inner_conductance, is stable up to here"),
    Rule(TIMESTEP, lo=0.0, hi="outer_stable_timestep", lo_open=True,
         why="the explicit update of the outer chamber, fed through "
             "pneumatics.outer_conductance, is stable up to here"),
    Rule(TIMESTEP, lo="shortest_timestep",
         why="a regulator's dead-time queue holds at most 1e6 steps of pneumatics.dead_time"),
)


def field_rules() -> tuple[Rule, ...]:
    """Each parameter's own range (its field metadata) and each instance number's."""
    from wpam_mj.physics.params import parameter_fields  # noqa: PLC0415 (it imports us)

    return (*(Rule(key, f.metadata["lo"], f.metadata["hi"], f.metadata["lo_open"])
              for key, f in parameter_fields()),
            *(Rule(key, n.lo, n.hi) for key, n in INSTANCE_NUMBERS.items()))


def all_rules() -> tuple[Rule, ...]:
    """The whole table: the fields' own ranges, then the rules between quantities."""
    return (*field_rules(), *CROSS_RULES)


def unit_of(name: str) -> str:
    """The unit of any quantity ("1" for a pure number)."""
    from wpam_mj.physics.params import parameter_fields  # noqa: PLC0415

    if name in INSTANCE_NUMBERS:
        return INSTANCE_NUMBERS[name].unit
    if name == TIMESTEP:
        return "s"
    if name in DERIVED:
        return DERIVED[name].unit
    return dict(parameter_fields())[name].metadata["unit"]


def _with_unit(text: str, unit: str) -> str:
    return text if unit == "1" else f"{text} {unit}"


def shown_range(lo: float, hi: float, lo_open: bool, hi_open: bool, unit: str) -> str:
    """An interval as messages show it: "[0, 1] s", "(0, 1]" for a pure number."""
    left = "(" if lo_open or lo == -math.inf else "["
    right = ")" if hi_open or hi == math.inf else "]"
    return _with_unit(f"{left}{lo:.6g}, {hi:.6g}{right}", unit)


def message(prefix: str, subject: str, value: float, lo: float, hi: float, lo_open: bool,
            hi_open: bool, why: str = "") -> str:
    """The one line of a value outside its range (the compiled plugin prints the same)."""
    unit = unit_of(subject)
    why = f" ({why})" if why else ""
    value = float(value)
    return (f"{prefix}{_with_unit(f'{subject} = {value:.6g}', unit)} is outside the allowed "
            f"range {shown_range(lo, hi, lo_open, hi_open, unit)}{why}")


def not_a_number(prefix: str, subject: str, text: str, rule: Rule) -> str:
    """The one line of a word (or nothing) where a number belongs."""
    return (f"{prefix}{subject} = '{text}' is not a number; allowed: "
            f"{shown_range(rule.lo, rule.hi, rule.lo_open, rule.hi_open, unit_of(subject))}")


_NUMBER = re.compile(r"[ \t\n\v\f\r]*[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)? *", re.ASCII)


def parse_number(text: str) -> float | None:
    """A configuration value as the compiled plugin reads it (C's strtod on a decimal
    number, trailing spaces allowed): the finite number, or None."""
    if not _NUMBER.fullmatch(text):
        return None
    value = float(text)
    return value if math.isfinite(value) else None


def bound(value: float | str, get: Getter) -> float:
    """A bound's value: a number, or the quantity it names."""
    if isinstance(value, str):
        return DERIVED[value].compute(get) if value in DERIVED else get(value)
    return value


def violation(rule: Rule, get: Getter) -> tuple[float, float, float] | None:
    """(value, lo, hi) when `rule` does not hold (NaN never does), else None."""
    lo, hi = bound(rule.lo, get), bound(rule.hi, get)
    v = get(rule.subject)
    above_lo = v > lo if rule.lo_open else v >= lo
    below_hi = v < hi if rule.hi_open else v <= hi
    return None if above_lo and below_hi else (v, lo, hi)


def check(rules: tuple[Rule, ...], get: Getter, prefix: str = "") -> None:
    """Raise ParameterError with the line of the first rule of `rules` that fails."""
    from wpam_mj.errors import ParameterError  # noqa: PLC0415

    for rule in rules:
        bad = violation(rule, get)
        if bad is not None:
            raise ParameterError(message(prefix, rule.subject, *bad, rule.lo_open,
                                         rule.hi_open, rule.why))


def rules_within(names: set[str] | frozenset[str]) -> tuple[Rule, ...]:
    """The cross rules that read only the quantities `names`."""
    return tuple(r for r in CROSS_RULES if r.needs <= names)
