"""The controller's equilibrium model as the paper's experimenter has it: fitted to the
plant's own open-loop loops.

The feedforward reads Pi off the mechanical equilibrium model (eqs. 5-6, §3: "the target
contraction amount x_r is set based on the internal pressure Pi and contraction force F
using the mechanical equilibrium model"). Its values are not known a priori on a rig:
they are what the experimenter fits to the muscle's measured static characteristics,
Fig. 8 (Po = 0) and Fig. 9 (Po = 0.04 MPa on the way down), which §2 measures before any
feedback is run. `fit_feedforward` does that on a plant's simulated ramps, read as the rig
reads them: x from the linear encoder, Pi and Po from the ITV2031's own gauge (§2: "Each
pressure is measured by a pressure gauge in the electro-pneumatic regulators"), at its
sensitivity, logged every RECORD_EVERY_S. The model is the quasi-static play operator of
the equilibrium branches (`wpam_mj.physics.quasistatic`), fitted by bounded least squares
on x (mm). The plant's dynamics on a 60 s ramp (line lag, the slide where friction lets
go) are not in that model, so the fitted values are not the plant's; what the
feedforward needs, the contracting branch at the loads measured, they reproduce.
Units: SI.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from wpam_mj.experiments.paper_studies import check_ramp_time
from wpam_mj.experiments.protocol import Protocol, open_loop_tasks
from wpam_mj.errors import ParameterError
from wpam_mj.experiments.responses import StaticLoop
from wpam_mj.physics.muscle import MuscleModel
from wpam_mj.physics.params import Params
from wpam_mj.physics.quasistatic import ramp_contraction
from wpam_mj.simulation.execution import Failed, execute
from wpam_mj.units import MM

# The values the feedforward's equilibrium model reads (`controllers.pi_feedforward`):
# eqs. 5-6's Kf, mu and friction constant, the axial area Po presses on, and the braid
# angle that shapes S(x) = dV/dx.
FEEDFORWARD_MODEL = ("braid.braid_angle", "muscle.output_coeff", "muscle.friction_coeff",
                     "muscle.friction_const", "muscle.axial_area")
# What the controller's equilibrium model is: fitted to the plant's own open-loop loops
# (`calibrate`; the shipped reading: §4.1's Pi "is the result of model calculations" of a
# model the experimenter fits to the muscle's measured characteristics), or the nominal
# values themselves (a controller that knows the nominal plant exactly)
FEEDFORWARD_MODELS = ("calibrated", "nominal")
GAUGE_RESOLUTION = 1e3  # Pa: the ITV2031's sensitivity, 0.2 % of its 0.5 MPa span (SMC)
RECORD_EVERY_S = 0.1  # s: the log's sample interval (ours; 600 samples per 60 s ramp)
# A muscle friction holds: slower than this (m/s). Stiction holds it still (the no-slip
# solver): on the shipped ramps at most 1 % of the samples move at 1e-6 to 1e-4 m/s, so
# the split hardly depends on where in that gap it is drawn.
HELD_SPEED = 1e-5
FIT_SPAN = 0.3  # each fitted value within +-30 % of its start: far wider than the plant's
# uncertainty, so the bound never decides the fit


def check_feedforward_model(name: str) -> str:
    if name not in FEEDFORWARD_MODELS:
        raise ParameterError(f"feedforward model {name!r}; valid: "
                             + ", ".join(FEEDFORWARD_MODELS))
    return name


@dataclass(frozen=True)
class MeasuredLoop:
    """One open-loop ramp as logged: `load` [N]; gauge Pi, Po [Pa] and encoder x [m]."""

    load: float
    pi: np.ndarray
    po: np.ndarray
    x: np.ndarray


def measured_loop(loop: StaticLoop) -> MeasuredLoop:
    """`loop`'s run logged every RECORD_EVERY_S, the gauges rounded to their resolution."""
    r = loop.result
    every = max(1, int(round(RECORD_EVERY_S / float(np.median(np.diff(r.time))))))

    def gauge(p: np.ndarray) -> np.ndarray:
        return np.round(p[::every] / GAUGE_RESOLUTION) * GAUGE_RESOLUTION

    return MeasuredLoop(r.context.load, gauge(r.pi_reg), gauge(r.po_reg), r.x[::every])


def model_contraction(params: Params, loops: Sequence[MeasuredLoop]) -> np.ndarray:
    """x [m] the equilibrium model of `params` gives along every logged ramp, joined."""
    model = MuscleModel.from_params(params)
    return np.concatenate([ramp_contraction(model, lp.pi, lp.po, lp.load, x0=float(lp.x[0]))
                           for lp in loops])


@dataclass(frozen=True)
class FeedforwardFit:
    """The fitted equilibrium model: `values` {name: value} of FEEDFORWARD_MODEL and the
    rms of x's residual [m] over the logged ramps."""

    values: dict[str, float]
    rms: float

    def controller_of(self, plant: Params) -> Params:
        """The parameters whose nominal values (what the controller reads) are `plant`'s
        own with this fit's model, and whose `plant_deviation` gives back `plant.plant`:
        the plant stays the plant, the feedforward becomes the experimenter's."""
        truth = plant.plant
        model = dataclasses.replace(plant, plant_deviation=()).with_values(self.values)
        names = dict.fromkeys([*(n for n, _ in plant.plant_deviation), *self.values])
        return dataclasses.replace(model, plant_deviation=tuple(
            (n, float(truth.value(n) / model.value(n) - 1.0)) for n in names))


def fit_feedforward(start: Params, loops: Sequence[MeasuredLoop],
                    slower_than: float = math.inf) -> FeedforwardFit:
    """FEEDFORWARD_MODEL fitted to `loops` from `start`'s nominal values: bounded least
    squares of the model's x against the logged x [mm], each value within +-FIT_SPAN,
    over the samples where the encoder's x moves slower than `slower_than` [m/s] (its
    log differenced; default: every sample, the shipped reading)."""
    from scipy.optimize import least_squares  # noqa: PLC0415 (scipy: slow import)

    x_logged = np.concatenate([lp.x for lp in loops])
    speed = np.concatenate([np.abs(np.gradient(lp.x, RECORD_EVERY_S)) for lp in loops])
    keep = speed < slower_than
    if not keep.any():
        raise ParameterError(f"fit_feedforward: slower_than {slower_than:g} m/s keeps no "
                             f"logged sample; it must exceed the slowest, {speed.min():g} m/s")
    first = {n: float(start.value(n)) for n in FEEDFORWARD_MODEL}

    def at(z: np.ndarray) -> Params:
        return start.with_values({n: v * (1.0 + float(d)) for (n, v), d in zip(first.items(),
                                                                                  z)})

    def residual(z: np.ndarray) -> np.ndarray:
        return ((model_contraction(at(z), loops) - x_logged) / MM)[keep]

    best = least_squares(residual, np.zeros(len(first)), bounds=(-FIT_SPAN, FIT_SPAN),
                         diff_step=1e-3)
    fitted = at(best.x)
    return FeedforwardFit({n: float(fitted.value(n)) for n in first},
                          float(np.sqrt(np.mean(best.fun ** 2))) * MM)


def fitted_to(plant: Params, loops: Sequence[StaticLoop]) -> tuple[Params, float]:
    """`plant` with its controller's model fitted to its open-loop `loops` as the rig
    logs them (`measured_loop`, `FeedforwardFit.controller_of`), and the fit's rms x
    residual [m]."""
    fit = fit_feedforward(plant, [measured_loop(lp) for lp in loops])
    return fit.controller_of(plant), fit.rms


@dataclass(frozen=True)
class GaugeLag:
    """Why a model fitted through the gauges is not the plant, on one simulated ramp: how
    far the chamber's Pi [Pa] runs behind the gauge's (median |difference|) where
    friction holds the muscle (slower than HELD_SPEED) and where it slides, and
    the rms [m] over the sliding samples of x less the plant's own equilibrium model
    read on the chamber's Pi and on the gauge's."""

    lag_held: float
    lag_sliding: float
    x_error_chamber: float
    x_error_gauge: float


def gauge_lag(loop: StaticLoop, plant: Params) -> GaugeLag:
    """`GaugeLag` of `loop`, a ramp of `plant` (its own values: `Params.plant`), read at
    every recorded sample, unrounded (the gauge's resolution plays no part)."""
    r = loop.result
    model = MuscleModel.from_params(plant)

    def on(pi: np.ndarray, po: np.ndarray) -> np.ndarray:
        return ramp_contraction(model, pi, po, r.load, x0=float(r.x[0])) - r.x

    sliding = np.abs(r.velocity) >= HELD_SPEED
    if sliding.all() or not sliding.any():
        raise ParameterError("gauge_lag: the ramp needs samples both held and sliding")
    lag = np.abs(r.pi - r.pi_reg)

    def rms(e: np.ndarray) -> float:
        return float(np.sqrt(np.mean(e[sliding] ** 2)))

    return GaugeLag(float(np.median(lag[~sliding])), float(np.median(lag[sliding])),
                    rms(on(r.pi, r.po)), rms(on(r.pi_reg, r.po_reg)))


@dataclass(frozen=True)
class Calibration:
    """A plant with its controller's model fitted to its own loops: `params` (the plant
    kept as `plant_deviation`), the fit's rms x residual [m], and the `loops` it was
    fitted to (Table 2's open-loop ramps, `protocol.open_loop_tasks`' order)."""

    params: Params
    rms: float
    loops: tuple[StaticLoop, ...]


def calibrate(plants: Sequence[Params], protocol: Protocol, dt: float, workers,
              progress: bool = False,
              ramp_time: float | None = None) -> list[Calibration | Failed]:
    """Each plant's `Calibration`, or the `Failed` of a plant whose ramps failed. The
    loops: Fig. 8 (Po = 0) and Fig. 9 (Po = 0.04 MPa on the way down) at the paper's loads,
    under `protocol`, run where `workers` says (`execute`). ramp_time: each calibration
    ramp's duration [s] (default: the protocol's); ramps other than the protocol's are not
    Table 2's, so a `Calibration` keeps no loops then."""
    ramps = protocol if ramp_time is None else dataclasses.replace(
        protocol, ramp_time=check_ramp_time(ramp_time))
    tasks = [open_loop_tasks(p, ramps, dt=dt) for p in plants]
    loops = iter(execute([t for ts in tasks for t in ts], workers, failed=Failed,
                         progress=progress, desc="open-loop loops"))
    out: list[Calibration | Failed] = []
    for plant, ts in zip(plants, tasks):
        mine = tuple(next(loops) for _ in ts)
        failed = next((r for r in mine if isinstance(r, Failed)), None)
        if failed is not None:
            out.append(failed)
            continue
        out.append(Calibration(*fitted_to(plant, mine), mine if ramps == protocol else ()))
    return out


def calibrate_one(plant: Params, protocol: Protocol, dt: float, workers,
                  progress: bool = False, ramp_time: float | None = None) -> Calibration:
    """`calibrate` of one plant; a failed ramp raises its error."""
    (fit,) = calibrate([plant], protocol, dt, workers, progress, ramp_time)
    if isinstance(fit, Failed):
        raise fit.error
    return fit


def model_error(params: Params) -> tuple[tuple[str, float], ...]:
    """(name, model / plant - 1) for each value the controller's model reads."""
    plant = params.plant
    return tuple((n, float(params.value(n) / plant.value(n) - 1.0))
                 for n in FEEDFORWARD_MODEL)


def model_markdown(params: Params, rms: float) -> str:
    """The controller's equilibrium model beside the plant: each value it reads, and how
    well the model's play operator follows the loops it was fitted to (`rms` [m])."""
    plant = params.plant
    lines = [f"The controller's equilibrium model, fitted to the plant's own open-loop loops "
             f"(Figs. 8-9, the gauges at {GAUGE_RESOLUTION / 1e3:g} kPa, logged every "
             f"{RECORD_EVERY_S:g} s; x residual {rms / MM:.2f} mm rms):", "",
             "| value | plant | controller's model | model / plant - 1 |", "|---|---|---|---|"]
    for name, error in model_error(params):
        lines.append(f"| `{name}` | {plant.value(name):.6g} | {params.value(name):.6g} | "
                     f"{error:+.1%} |")
    return "\n".join(lines)
