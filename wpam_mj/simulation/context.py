"""What a result was made with, validated once where it is made: `StudyContext` (the
parameter set and the physics step every run of a study shares) and `RunContext` (one
run's: that, plus its load, controller and recording period).

A run's context is made where the run is made (`wpam_mj.simulation.simulate.Run.make`,
the drives' plans, `wpam_mj.simulation.live.LiveRig.build`), a study's where the study is
(`wpam_mj.experiments.paper_studies`); the rig, the engines, the findings, figures and
writers take the context with the result and trust it. Public entries that need dt
before any context exists (the command line's --dt, a study file, the environments'
control step) check it themselves with `check_dt`.
"""

from __future__ import annotations

from dataclasses import dataclass

from wpam_mj.errors import ParameterError, check_range, whole_steps
from wpam_mj.physics.params import Params

LOAD_RANGE_N = (1.0, 2000.0)  # N: what a hanging mass on this rig can sensibly be
DT_RANGE_S = (1e-5, 0.005)  # s: the pneumatics need a step well below their time constants


def check_load(load: float) -> float:
    """Validate a hanging load [N]."""
    return check_range("load", load, *LOAD_RANGE_N, "N")


def check_dt(dt: float, *, divides: float | None = None, name: str = "dt") -> float:
    """Validate a physics time step [s]; with `divides` [s] (a recording period) it must
    also be a whole fraction of it, so that the stated range is the range applied."""
    dt = check_range(name, dt, *DT_RANGE_S, "s")
    if divides is not None:
        if not whole_steps(divides, dt):
            lo, hi = DT_RANGE_S
            fits = [divides / k for k in (1, 2, 4, 5, 10, 20) if lo <= divides / k <= hi]
            raise ParameterError(
                f"{name} = {dt:g} s must divide the {divides:g} s recording period into whole "
                f"steps, within [{lo:g}, {hi:g}] s (e.g. {', '.join(f'{f:g}' for f in fits)})")
    return dt


@dataclass(frozen=True)
class StudyContext:
    """What every run of a study shares: `params` as given (the plant that ran is
    `params.plant`; the controller's values, po_cap among them, are never perturbed)
    and the physics step dt [s], checked here."""

    params: Params
    dt: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "dt", check_dt(self.dt))

    @property
    def po_cap(self) -> float:
        """The Po controller's cap [Pa] (the findings' and figures' line)."""
        return self.params.controller.po_cap

    @property
    def preset(self) -> str:
        return self.params.preset


@dataclass(frozen=True)
class RunContext(StudyContext):
    """One run's context: a `StudyContext` with the hanging load [N] (checked here, before
    dt), the controller's name (`wpam_mj.control.controllers.CONTROLLERS`) and the
    recording period record_dt [s]."""

    load: float
    control: str = "open"
    record_dt: float = 0.01

    def __post_init__(self) -> None:
        object.__setattr__(self, "load", check_load(self.load))
        super().__post_init__()


class InContext:
    """What a result reads from the `context` (a `RunContext`) it was made in: its load
    [N], physics step dt [s], controller and muscle type."""

    context: RunContext

    @property
    def load(self) -> float:
        """The hanging load [N]."""
        return self.context.load

    @property
    def dt(self) -> float:
        """The physics step [s]."""
        return self.context.dt

    @property
    def control(self) -> str:
        return self.context.control

    @property
    def preset(self) -> str:
        return self.context.preset
