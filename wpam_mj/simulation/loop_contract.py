"""What both engines of the muscle share (the compiled plugin and the Python engine, see
`wpam_mj.simulation.simulate`): what a run records, the per-run constants of the Python pieces, and
how a divergence is reported.
"""

from __future__ import annotations

from dataclasses import dataclass

from wpam_mj.physics import kernel
from wpam_mj.physics.params import Params
from wpam_mj.errors import check_whole_steps
from wpam_mj.simulation.plugin import FIELD, STATE_FIELDS, status_message

# Rows of the recording array, in this order: the time, then the plugin state's recorded
# fields; `SimResult` has a field of each name.
REC_FIELDS = ("time", *STATE_FIELDS[:STATE_FIELDS.index("po_reg") + 1])
REC_ROWS = len(REC_FIELDS)


class SimulationDiverged(RuntimeError):
    """The state left its physical range (`wpam_mj.simulation.plugin.status_message`)."""


def state_failure(state) -> str:
    """Why a plugin instance stopped, from its state (starting at its first field) whose
    "status" is set: one line."""
    return status_message(*(float(state[FIELD[n]]) for n in ("status", "x", "p_i", "p_o")))


@dataclass(frozen=True)
class RunConstants:
    """Per-run constants of the step, of the Python engine's pieces
    (the plugin derives the same values from its attributes)."""

    dt: float
    record_every: int
    lag_alpha: float  # 1 - exp(-dt / tau) of the regulator lag
    delay_steps: int  # regulator dead time in steps
    atmosphere: float
    p_max: float
    conductance_i: float
    conductance_o: float
    critical_ratio: float
    supply_abs: float  # the regulators' supply [Pa abs]
    supply_valve: float  # the regulators' valve conductances [m^3/(s Pa)]
    exhaust_valve: float
    tube_volume: float
    polytropic: float  # the chambers' polytropic index
    bag_volume: float
    start_at_rest: int = 0  # 1: regulators and chambers start settled at the first commands

    @classmethod
    def make(cls, params: Params, dt: float, record_dt: float, *,
             start_at_rest: bool = False) -> "RunConstants":
        record_every = check_whole_steps("record_dt", record_dt, dt)
        p = params.pneumatics
        tau = p.time_constant
        return cls(
            dt=dt, record_every=record_every,
            lag_alpha=kernel.lag_alpha(dt, tau),
            delay_steps=round(p.dead_time / dt), atmosphere=p.atmosphere, p_max=p.p_max,
            conductance_i=p.inner_conductance, conductance_o=p.outer_conductance,
            critical_ratio=p.critical_ratio,
            supply_abs=p.supply_pressure + p.atmosphere,
            supply_valve=p.supply_valve_conductance, exhaust_valve=p.exhaust_valve_conductance,
            tube_volume=p.tube_volume, polytropic=p.polytropic_index,
            bag_volume=kernel.outer_bag_volume(params.braid.outer_bag_length,
                                               params.braid.outer_bag_diameter),
            start_at_rest=int(start_at_rest))
