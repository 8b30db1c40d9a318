"""The muscle's limit velocity (§4.2): the fastest contraction and extension under a
saturated Po command, per load, and which element of the plant sets it.

§4.2 explains the high-frequency response by "the system using the PI controller operates
at almost the limit velocity": above about 0.5 Hz the Po command spends most of each cycle
at its cap or its floor (a bang-bang loop), so the speed the load can reach in either
direction is what bounds the gain. This experiment measures those two speeds directly:
Pi held at the feedforward of mid-stroke (25 mm, the sine's centre), Po commanded from
the cap to the regulator's floor (the muscle contracts) and back (it extends), each held
`hold` seconds from rest.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.stats import qmc

from wpam_mj.control.controllers import pi_feedforward
from wpam_mj.experiments.analysis import frequency_response
from wpam_mj.experiments.drives import SINE_MEAN_MM, SineSpec, sine_run
from wpam_mj.physics.muscle import MuscleModel
from wpam_mj.physics.params import Params
from wpam_mj.units import MM
from wpam_mj.simulation.results import SimResult
from wpam_mj.simulation.simulate import Drive, simulate

HOLD_S = 3.0  # each Po level held long enough for the load to stop (our choice)


@dataclass(frozen=True)
class LimitVelocity:
    """Fastest contraction and extension speeds [m/s] at one load [N]; x_span [m]: how
    far the load travelled in each direction (contraction, extension)."""

    load: float
    contraction: float
    extension: float
    x_span: tuple[float, float]
    result: SimResult


def bang_bang_drive(params: Params, load: float, *, dt: float, hold: float = HOLD_S) -> Drive:
    """Pi at the mid-stroke feedforward (Po = po_feedforward assumed, as the PI loop's);
    Po: cap for `hold`, the regulator floor p_min for `hold`, the cap again for `hold`."""
    n_hold = int(round(hold / dt))
    c, pn = params.controller, params.pneumatics
    pi = float(pi_feedforward(MuscleModel.from_params(params), params,
                              np.array([SINE_MEAN_MM * MM]), load, c.po_feedforward)[0])
    po = np.concatenate([np.full(n_hold, c.po_cap), np.full(n_hold, pn.p_min),
                         np.full(n_hold + 1, c.po_cap)])
    return Drive(pi_cmd=np.full(po.size, pi), po_cmd=po, x_ref=np.full(po.size, np.nan),
                 start_at_rest=True)


def limit_velocity(params: Params, load: float, *, dt: float = 1e-3,
                   hold: float = HOLD_S) -> LimitVelocity:
    """Measure the fastest contraction and extension [m/s] under Po switched between
    its cap and its floor (`bang_bang_drive`), recorded every step."""
    r = simulate(params, load, bang_bang_drive(params, load, dt=dt, hold=hold), dt=dt,
                 record_dt=dt)
    down = (r.time >= hold) & (r.time < 2 * hold)  # Po at its floor: contracting
    up = r.time >= 2 * hold  # Po at its cap: extending
    return LimitVelocity(load, float(np.max(r.velocity[down])),
                         float(-np.min(r.velocity[up])),
                         (float(np.ptp(r.x[down])), float(np.ptp(r.x[up]))), r)


# The plant's elements that could set the speed, each removed in turn (`element_study`):
# a variant's name and its parameter overrides relative to the plant.
VARIANTS = {
    "plant": {},
    "regulator instant (no lag, no dead time)": {"pneumatics.time_constant": 0.0,
                                                 "pneumatics.dead_time": 0.0},
    "lines x10": {"pneumatics.inner_conductance": 10.0, "pneumatics.outer_conductance": 10.0},
    "Po line x10": {"pneumatics.outer_conductance": 10.0},
    "Pi line x10": {"pneumatics.inner_conductance": 10.0},
    "no tube volume": {"pneumatics.tube_volume": 0.0},
    "regulator valves x25 (an ideal source)": {"pneumatics.supply_valve_conductance": 25.0,
                                               "pneumatics.exhaust_valve_conductance": 25.0},
    "regulator valves /10 (ITV1000 class)": {"pneumatics.supply_valve_conductance": 0.1,
                                             "pneumatics.exhaust_valve_conductance": 0.1},
    "lines x10, valves x25": {"pneumatics.inner_conductance": 10.0,
                              "pneumatics.outer_conductance": 10.0,
                              "pneumatics.supply_valve_conductance": 25.0,
                              "pneumatics.exhaust_valve_conductance": 25.0},
    "polytropic chambers (n 1.2)": {"pneumatics.polytropic_index": 1.2},
    "adiabatic chambers (n 1.4)": {"pneumatics.polytropic_index": 1.4},
}
_SCALED = ("pneumatics.inner_conductance", "pneumatics.outer_conductance",
           "pneumatics.supply_valve_conductance", "pneumatics.exhaust_valve_conductance")


def variant(params: Params, overrides: dict[str, float]) -> Params:
    """`params` with a VARIANTS entry applied (conductances scaled, the rest set)."""
    values = {name: params.value(name) * v if name in _SCALED else v
              for name, v in overrides.items()}
    return params.with_values(values) if values else params


@dataclass(frozen=True)
class SineAtTheLimit:
    """The PI sine at one load and frequency, seen as a bang-bang loop: gain [1] and lag
    [deg] of x; the share of the analysed cycles with the Po command at the regulator's
    floor (pushing the contraction) and at its cap (pushing the extension); the fastest
    contraction and extension [m/s]; and how far the response's centre sits below the
    target's [m]."""

    load: float
    freq: float
    gain: float
    lag_deg: float
    at_floor: float
    at_cap: float
    contraction: float
    extension: float
    centre_offset: float


def sine_at_the_limit(params: Params, load: float, freq: float, *,
                      dt: float = 1e-3) -> SineAtTheLimit:
    """Run the paper's PI sine (`SineSpec`) and measure where its Po command sits and how
    fast the load moves each way (§4.2: "operates at almost the limit velocity")."""
    spec = SineSpec(freq)
    r = sine_run(params, load, "pi", spec, dt=dt, record_dt=max(dt, 2e-3))
    fr = frequency_response(r.time, r.x_ref, r.x, freq, settle_cycles=spec.settle_cycles,
                            n_cycles=spec.cycles)
    w = spec.analysed(r.time)
    po, c = r.po_cmd[w], params.controller
    return SineAtTheLimit(load, freq, fr.gain, fr.phase_lag_deg,
                          float(np.mean(po <= params.pneumatics.p_min * (1 + 1e-6))),
                          float(np.mean(po >= c.po_cap * (1 - 1e-6))),
                          float(np.max(r.velocity[w])), float(-np.min(r.velocity[w])),
                          float(np.mean(r.x_ref[w]) - np.mean(r.x[w])))


# A grid of the two lines, each scaled by these factors (`line_grid`): the element that
# sets the limit velocity, searched for a plant whose loads lag alike at 0.5-1 Hz.
LINE_FACTORS = (0.5, 1.0, 2.0, 4.0)


def line_grid(factors=LINE_FACTORS) -> dict[str, dict[str, float]]:
    """VARIANTS-style overrides: every pair of Pi-line and Po-line factors but the plant's."""
    return {f"Pi line x{a:g}, Po line x{b:g}": {"pneumatics.inner_conductance": a,
                                                "pneumatics.outer_conductance": b}
            for a in factors for b in factors if (a, b) != (1.0, 1.0)}


# The pneumatic structure between the regulators and the bags, which no paper value pins,
# and the range each element may take on a rig like the paper's (`structure_sample`):
# name -> (low, high, drawn on a log scale).
STRUCTURE_BOX = {
    # a 1.1 mm orifice up to the ITV2031's own valve (each line's plausible range)
    "pneumatics.inner_conductance": (1e-9, 3.6e-8, True),
    "pneumatics.outer_conductance": (1e-9, 3.6e-8, True),
    "pneumatics.tube_volume": (0.0, 1e-4, False),  # no tube up to 8 m of 4 mm bore
    # an ITV1000-class relief (200 L/min) up to the supply side's 1500 L/min
    "pneumatics.exhaust_valve_conductance": (3.6e-9, 3.6e-8, True),
    "pneumatics.critical_ratio": (0.2, 0.7, False),  # ISO 6358 b of fittings and tubes
    "pneumatics.polytropic_index": (1.0, 1.4, False),  # isothermal to adiabatic chambers
    "pneumatics.time_constant": (0.05, 0.1, False),  # the regulators' plausible ranges
    "pneumatics.dead_time": (0.02, 0.045, False),
}


def structure_sample(params: Params, n: int, seed: int = 0) -> list[Params]:
    """`n` plants, each STRUCTURE_BOX element drawn within its range by a seeded Latin
    hypercube (scipy.stats.qmc), the rest of `params` kept."""
    u = qmc.LatinHypercube(d=len(STRUCTURE_BOX), seed=seed).random(n)
    out = []
    for row in u:
        values = {}
        for (name, (lo, hi, log)), q in zip(STRUCTURE_BOX.items(), row):
            values[name] = float(np.exp(np.log(lo) + q * np.log(hi / lo)) if log
                                 else lo + q * (hi - lo))
        out.append(params.with_values(values))
    return out
