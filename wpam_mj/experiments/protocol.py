"""The static experiments' protocol readings that the paper does not state.

Figs. 8-9 and Table 2 come from "slow" Pi ramps up and back down (§2.3), with Po applied
"only when the internal pressure Pi is decreased" in Fig. 9. The paper does not give:

  * the top of the Pi ramp: per load (ours before: the Pi whose contracting branch,
    paper eq. 5, reaches the step runs' 50 mm top) or one common Pi for every load, as
    one set of axes in Fig. 8 suggests (`ramp_top`, 0 = per load);
  * the ramp rate (`ramp_time`, the duration of each direction);
  * when Po is switched on at the top: at the instant Pi starts to fall, or after Pi has
    been held at its top with Po on for `top_hold` seconds;
  * the loop-area definition when a loop crosses itself, as the paper notes Fig. 9's
    loops do (§2.3): "branches" counts every lobe positive, "shoelace" takes the signed
    polygon area, where the lobes of a figure-eight cancel
    (`wpam_mj.experiments.analysis.loop_area`).

The Po feedforward's nominal Po, its share phi of the friction band and the gain reading
are readings of the controller and live in `wpam_mj.physics.params.Controller`
(`po_feedforward`, `feedforward_friction`, `command_scale`). `SHIPPED` is the reading
`wpam reproduce` ships (docs/physics.md, "The protocol readings").
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Iterable, Sequence

import numpy as np

from wpam_mj.experiments.analysis import loop_area
from wpam_mj.experiments.drives import STATIC_RAMP_S, check_po, static_top_pressure
from wpam_mj.simulation.context import RunContext, StudyContext, check_load
from wpam_mj.paper import LOADS_N, PO_DOWN_STATIC_MPA
from wpam_mj.physics.muscle import MuscleModel
from wpam_mj.physics.params import Params
from wpam_mj.errors import ParameterError, check_range
from wpam_mj.units import MPA
from wpam_mj.physics.quasistatic import ramp_contraction
from wpam_mj.simulation.execution import Batch, SimulationTask
from wpam_mj.simulation.results import SimResult
from wpam_mj.simulation.simulate import Drive, Run
from wpam_mj.experiments.paper_studies import StepTask, check_ramp_time
from wpam_mj.experiments.responses import StaticLoop, Table2Result

LOOP_METHODS = ("branches", "shoelace")
TOP_HOLD_RANGE_S = (0.0, 60.0)
DWELL_S = 1.0  # at p_min before and after the ramps, as `experiments.static_loop`


@dataclass(frozen=True)
class Protocol:
    """The static experiments' readings (module docstring); SI units."""

    ramp_top: float = 0.0  # Pa; 0: per load, the contracting branch's Pi at 50 mm
    ramp_time: float = STATIC_RAMP_S  # s, each direction
    top_hold: float = 0.0  # s at the top with Po on before Pi falls
    loop_method: str = "branches"

    def __post_init__(self) -> None:
        if self.ramp_top != 0.0:
            check_range("ramp_top", self.ramp_top / MPA, 0.0, 1.0, "MPa", lo_open=True)
        check_ramp_time(self.ramp_time)
        check_range("top_hold", self.top_hold, *TOP_HOLD_RANGE_S, "s")
        if self.loop_method not in LOOP_METHODS:
            raise ParameterError(f"loop_method {self.loop_method!r}; valid: "
                                 + ", ".join(LOOP_METHODS))

    def top(self, params: Params, load: float) -> float:
        """The ramp's top Pi [Pa] at `load` [N] (at most the regulator's p_max)."""
        if self.ramp_top == 0.0:
            return static_top_pressure(params, load)
        return min(self.ramp_top, params.pneumatics.p_max)

    def describe(self) -> str:
        top = ("per load (contracting branch at 50 mm)" if self.ramp_top == 0.0
               else f"{self.ramp_top / MPA:g} MPa for every load")
        return (f"ramp top {top}, {self.ramp_time:g} s each way, Po on after "
                f"{self.top_hold:g} s at the top, loop area '{self.loop_method}'")


# What `wpam reproduce`, `wpam table2` and `wpam calibrate` use (docs/physics.md, "The
# protocol readings"):
#   * one Pi ramp for every load, as Fig. 8 draws the three loads on one set of axes; its
#     top is a reading the paper does not state, fitted with the plant by `wpam search`
#     inside `wpam_mj.reproduction.static_fit.RAMP_TOP_RANGE_MPA`;
#   * every lobe of a loop counted ("branches"): the paper defines the absence of
#     hysteresis as x uniquely determined by Pi (§3), so the area measures how far x(Pi)
#     is from one-valued, the integral of |x_down - x_up| dPi; a signed closed-curve
#     integral would call a figure-eight with equal lobes hysteresis-free, while §2.3
#     reports Fig. 9's crossing loops as reduced, not cancelled.
SHIPPED = Protocol(ramp_top=0.19 * MPA, loop_method="branches")


def remeasure(t2: Table2Result, method: str) -> Table2Result:
    """`t2` with its open-loop loops' areas measured by `method` (same runs)."""
    if method not in LOOP_METHODS:
        raise ParameterError(f"loop_method {method!r}; valid: " + ", ".join(LOOP_METHODS))

    def area(loops):
        return tuple(dataclasses.replace(lp, area=loop_area(lp.result.pi, lp.result.x,
                                                            method=method)) for lp in loops)
    return dataclasses.replace(t2, open_loops=area(t2.open_loops), po_loops=area(t2.po_loops))


QUASI_STATIC_SAMPLES = 100  # Pi samples per ramp direction of `quasi_static_po_row`
# (the row moves < 0.3 % from 100 to 800 samples)


def quasi_static_po_row(params: Params, protocol: Protocol, *,
                        loads: Iterable[float] = LOADS_N,
                        po_down: float = PO_DOWN_STATIC_MPA * MPA) -> dict[float, float]:
    """Table 2's "Po = `po_down`" row [1] per load [N] from the equilibrium model alone
    (`wpam_mj.physics.quasistatic`): the same ramps as `static_drive` without the dwell,
    hold or dynamics, measured with the protocol's loop area. Milliseconds per load; on
    slow ramps it agrees with the simulated row within a few per cent (tests/test_search.py),
    so a search can screen parameter sets with it before simulating any."""
    model = MuscleModel.from_params(params)
    n = QUASI_STATIC_SAMPLES
    out = {}
    for load in loads:
        top = protocol.top(params, load)
        pi = np.concatenate([np.linspace(params.pneumatics.p_min, top, n),
                             np.linspace(top, params.pneumatics.p_min, n)[1:]])
        loops = [ramp_contraction(model, pi, np.where(np.arange(pi.size) >= n, po, 0.0),
                                  load) for po in (0.0, po_down)]
        areas = [loop_area(pi, x, method=protocol.loop_method) for x in loops]
        out[load] = areas[1] / areas[0] if areas[0] > 0.0 else math.nan
    return out


def static_drive(params: Params, load: float, po_down: float, protocol: Protocol,
                 dt: float) -> Drive:
    """Pi p_min -> top -> (hold) -> p_min, Po = `po_down` [Pa] from the top on."""
    p_min, top = params.pneumatics.p_min, protocol.top(params, load)
    r, h = protocol.ramp_time, protocol.top_hold
    knots_t = [0.0, DWELL_S, DWELL_S + r]
    knots_p = [p_min, p_min, top]
    if h > 0.0:
        knots_t.append(DWELL_S + r + h)
        knots_p.append(top)
    knots_t += [DWELL_S + 2 * r + h, 2 * DWELL_S + 2 * r + h]
    knots_p += [p_min, p_min]
    n = int(round(knots_t[-1] / dt)) + 1
    t = np.arange(n) * dt
    pi_cmd = np.interp(t, knots_t, knots_p)
    po_cmd = np.where(t > DWELL_S + r, po_down, 0.0)
    return Drive(pi_cmd=pi_cmd, po_cmd=po_cmd, x_ref=np.full(n, np.nan))


@dataclass(frozen=True)
class ProtocolStaticTask(SimulationTask):
    """One open-loop ramp under `protocol` (a task, as `paper_studies.StaticTask`)."""

    params: Params
    load: float
    po_down: float
    dt: float
    protocol: Protocol = SHIPPED

    @property
    def cost(self) -> float:
        return (2.0 * self.protocol.ramp_time + self.protocol.top_hold) / self.dt

    def runs(self):
        context = RunContext(self.params, self.dt, self.load)  # load and dt checked here
        drive = static_drive(self.params, context.load, self.po_down, self.protocol,
                             context.dt)
        return [Run.make(context, drive)]

    def reduce(self, results: list[SimResult]) -> StaticLoop:
        (r,) = results
        return StaticLoop(po_down=self.po_down,
                          area=loop_area(r.pi, r.x, method=self.protocol.loop_method),
                          result=r)


def open_loop_tasks(params: Params, protocol: Protocol = SHIPPED,
                    loads: Iterable[float] = LOADS_N,
                    po_down: float = PO_DOWN_STATIC_MPA * MPA,
                    dt: float = 1e-3) -> list[ProtocolStaticTask]:
    """Table 2's open-loop ramps under `protocol`: Po = 0 at each load [N], then Po =
    `po_down` [Pa] on the way down at each (Figs. 8 and 9)."""
    return [ProtocolStaticTask(params, load, po, dt, protocol) for po in (0.0, po_down)
            for load in loads]


def table2_batch(params: Params, protocol: Protocol = SHIPPED, *,
                 loads: Iterable[float] = LOADS_N,
                 po_down: float = PO_DOWN_STATIC_MPA * MPA, dt: float = 1e-3,
                 open_loops: Sequence[StaticLoop] = ()) -> Batch:
    """`paper_studies.table2_batch` under `protocol`: the open-loop ramps with and without Po
    and the PI staircase at each load [N]. `Protocol()` runs the same ramps as it.
    open_loops: those ramps already run on this plant (`open_loop_tasks`' order); the
    open loop does not use the controller, so only the staircases run then."""
    loads = tuple(check_load(v) for v in loads)
    if not loads:
        raise ParameterError("no loads given")
    context = StudyContext(params, dt)  # dt checked here, once for the study
    dt, po_down = context.dt, check_po("po_down", po_down, params)
    ramps = open_loop_tasks(params, protocol, loads, po_down, dt)
    if open_loops and len(open_loops) != len(ramps):
        raise ParameterError(f"{len(open_loops)} open loops given; Table 2 needs "
                             f"{len(ramps)} (Po = 0, then Po = po_down, at each load)")
    steps = [StepTask(params, load, "pi", dt) for load in loads]
    tasks = steps if open_loops else ramps + steps

    def assemble(res: list) -> Table2Result:
        res = [*open_loops, *res]
        n = len(loads)
        for o in res[:n]:
            if not o.area > 0.0:
                raise ParameterError(f"the open-loop Po = 0 loop at {o.load:g} N has no "
                                     "area; cannot normalize Table 2 (is there friction?)")
        return Table2Result(loads=loads, po_down=po_down, open_loops=tuple(res[:n]),
                            po_loops=tuple(res[n:2 * n]), feedback_runs=tuple(res[2 * n:]),
                            context=context)
    return Batch(tasks, assemble)
