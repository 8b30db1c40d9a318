"""Parameter ranges for domain randomisation of the RL environment.

A ranges file is TOML with the sections of `wpam_mj.physics.params.Params` and, per field, a
pair [low, high] in SI units:

    [muscle]
    friction_coeff = [0.21, 0.25]

`wpam fit --randomize-out FILE` writes one from a fit (each estimate +- k sigma, clipped
to the parameter's plausible range);
`wpam_mj.environments.dm_env_task.make_env(..., randomize=FILE)` draws every listed field
uniformly from its range at each episode's start.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Mapping

import numpy as np

from wpam_mj.physics.params import Params, fitted_parameters, plausible_range
from wpam_mj.errors import ParameterError, load_toml

# The plant parameters a fit frees (field metadata: a plausible range, not measured on a
# rig, not the controller's): what a real muscle is least sure to share with ours.
PLANT_PARAMETERS = fitted_parameters()

if TYPE_CHECKING:  # scipy.optimize, imported by wpam_mj.fitting.estimation, is slow to import
    from wpam_mj.fitting.estimation import Estimate


@dataclass(frozen=True)
class ParameterRanges:
    """{"section.field": (low, high)} [SI] to draw from."""

    ranges: Mapping[str, tuple[float, float]]

    @classmethod
    def load(cls, path: str | Path, base: Params) -> "ParameterRanges":
        """Read a ranges file; checks names and that both ends are valid for `base`."""
        data = load_toml(path)
        ranges = {}
        for section, fields in data.items():
            if not isinstance(fields, Mapping):
                raise ParameterError(f"{path}: [{section}] must be a table of [low, high]")
            for key, pair in fields.items():
                name = f"{section}.{key}"
                try:
                    lo, hi = (float(v) for v in pair)
                except (TypeError, ValueError):
                    raise ParameterError(f"{path}: {name} = {pair!r} must be [low, high]") \
                        from None
                if not lo <= hi:
                    raise ParameterError(f"{path}: {name} = [{lo:g}, {hi:g}] needs low <= high")
                ranges[name] = (lo, hi)
        out = cls(ranges)
        for corner in (0.0, 1.0):  # both ends must make valid parameters
            try:
                base.with_values({n: lo + corner * (hi - lo) for n, (lo, hi) in ranges.items()})
            except ParameterError as err:
                raise ParameterError(f"{path}: {err}") from None
        return out

    @classmethod
    def from_estimates(cls, estimates: tuple["Estimate", ...], k: float) -> "ParameterRanges":
        """Each estimate +- k sigma, clipped to its bounds."""
        return cls({e.name: (float(max(e.lo, e.value - k * e.sigma)),
                             float(min(e.hi, e.value + k * e.sigma))) for e in estimates})

    @classmethod
    def relative(cls, base: Params, spread: float) -> "ParameterRanges":
        """Each of `PLANT_PARAMETERS` within +-spread (a fraction) of its value in `base`,
        clipped to its plausible range."""
        if isinstance(spread, bool) or not isinstance(spread, (int, float)) \
                or not 0.0 < spread < 1.0:
            raise ParameterError(f"randomize = {spread!r}: a relative spread must be a "
                                 "number in (0, 1)")
        ranges = {}
        for name in PLANT_PARAMETERS:
            value = base.value(name)
            lo, hi = plausible_range(name)
            ranges[name] = (min(value, max(lo, value * (1 - spread))),
                            max(value, min(hi, value * (1 + spread))))
        return cls(ranges)

    def sample(self, base: Params, random: np.random.RandomState) -> Params:
        """`base` with every listed field drawn uniformly from its range (sorted name
        order, so a seed gives the same parameters)."""
        return base.with_values({n: random.uniform(*self.ranges[n])
                                 for n in sorted(self.ranges)})

    def toml(self, header: str = "") -> str:
        lines = [f"# {ln}" for ln in header.splitlines()]
        lines += ["# Domain-randomisation ranges [low, high], SI units "
                  "(wpam_mj.fitting.randomize).", ""]
        sections: dict[str, list[str]] = {}
        for name, (lo, hi) in self.ranges.items():
            section, key = name.split(".")
            sections.setdefault(section, []).append(f"{key} = [{lo!r}, {hi!r}]")
        for section, rows in sections.items():
            lines += [f"[{section}]", *rows, ""]
        return "\n".join(lines)


def ranges_of(randomize: "str | Path | float | ParameterRanges | None",
              base: Params) -> "ParameterRanges | None":
    """What an environment's `randomize=` names: None, `ParameterRanges`, a ranges file
    (`wpam fit --randomize-out`), or a relative spread of `PLANT_PARAMETERS` (0.1: +-10 %)."""
    if randomize is None or isinstance(randomize, ParameterRanges):
        return randomize
    if isinstance(randomize, (str, Path)):
        return ParameterRanges.load(randomize, base)
    return ParameterRanges.relative(base, randomize)

