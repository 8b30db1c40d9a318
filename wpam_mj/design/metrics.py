"""One run of a study, reduced to its experiment's metrics (display units)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

from wpam_mj.experiments.analysis import frequency_response, loop_area, steady_state_means
from wpam_mj.experiments.drives import SineSpec, check_po, sine_plan, step_plan
from wpam_mj.experiments.feasibility import MOVE_MIN_MM, check_liftable, load_moved
from wpam_mj.experiments.responses import LOOP_METHOD
from wpam_mj.experiments.paper_studies import PLATEAU_SETTLE_S, StaticTask, plateau_segments
from wpam_mj.experiments.protocol import SHIPPED, table2_batch
from wpam_mj.paper import STEP_HOLD_S, STEP_LEVELS_MM
from wpam_mj.physics.params import Params
from wpam_mj.errors import ParameterError
from wpam_mj.units import MM, MPA
from wpam_mj.simulation.execution import SimulationTask
from wpam_mj.simulation.results import SimResult
from wpam_mj.simulation.simulate import Run


def params_for(base: Params, inputs: Mapping[str, Any]) -> Params:
    """`base` with the inputs that name a parameter ("section.field") applied."""
    return base.with_values({n: v for n, v in inputs.items() if "." in n})


def _step_metrics(result, hold: float) -> dict[str, float]:
    """Plateau means (last half of each plateau, as `paper_studies.step_study`) and their area."""
    seg = plateau_segments(STEP_LEVELS_MM, hold)
    settle = hold * PLATEAU_SETTLE_S / STEP_HOLD_S
    x = steady_state_means(result.time, result.x, seg, settle)
    pi = steady_state_means(result.time, result.pi, seg, settle)
    err = x - np.asarray(STEP_LEVELS_MM, dtype=float) * MM
    try:
        area = loop_area(pi, x, method=LOOP_METHOD)
    except ParameterError:  # Pi's plateau means only rise (or only fall): no loop
        raise ParameterError(
            f"Pi's plateau means never turn back (x missed its targets by up to "
            f"{np.max(np.abs(err)) / MM:.3g} mm): the muscle did not follow the staircase "
            f"of {hold:g} s plateaus, so it has no loop area") from None
    return {"loop_area_mpa_mm": area / (MPA * MM),
            "plateau_error_max_mm": float(np.max(np.abs(err))) / MM,
            "plateau_error_rms_mm": float(np.sqrt(np.mean(err ** 2))) / MM,
            "po_max_mpa": float(result.po_reg.max()) / MPA}


def _sine_metrics(result, spec: SineSpec) -> dict[str, float]:
    """Gain and lag of the analysed cycles (`analysis.frequency_response`) and the highest
    regulator-gauge Po over them (as `responses.SweepPoint.po_max`)."""
    fr = frequency_response(result.time, result.x_ref, result.x, spec.freq,
                            settle_cycles=spec.settle_cycles, n_cycles=spec.cycles)
    window = spec.analysed(result.time)
    return {"gain": fr.gain, "phase_lag_deg": fr.phase_lag_deg,
            "po_max_mpa": float(result.po_reg[window].max()) / MPA}


def _moved(*results):
    """The results, or ParameterError when the load never moved in one of them (its
    metrics would mean nothing: a gain of 0, a loop of no area)."""
    for result in results:
        if not load_moved(result):
            raise ParameterError(f"the load never moved (x spanned < {MOVE_MIN_MM:g} mm); "
                                 "this run's metrics mean nothing")
    return results[0]


@dataclass(frozen=True)
class MetricsTask(SimulationTask):
    """One run of a study (for table2: its seven runs) reduced to the experiment's
    metrics (display units): `base` with the `varied` inputs that name a parameter
    applied. ParameterError for inputs these parameters refuse, a load they cannot lift
    or one that never moved."""

    experiment: str
    base: Params
    inputs: Mapping[str, Any]
    dt: float
    varied: tuple[str, ...] = ()

    def _params(self) -> Params:
        return params_for(self.base, {k: self.inputs[k] for k in self.varied})

    def _table2(self, params: Params):
        return table2_batch(params, SHIPPED, loads=(self.inputs["load"],),
                            po_down=self.inputs["po_down"], dt=self.dt)

    def _static(self, params: Params) -> StaticTask:
        return StaticTask(params, self.inputs["load"],
                          check_po("po_down", self.inputs["po_down"], params), self.dt)

    def _hold(self) -> float:
        return self.inputs["duration"] / len(STEP_LEVELS_MM)

    def _sine(self) -> SineSpec:
        return SineSpec(self.inputs["frequency"], amplitude=self.inputs["amplitude"])

    def runs(self) -> list[Run]:
        params, inputs, load = self._params(), self.inputs, self.inputs["load"]
        check_liftable(params, (load,), "load")
        if self.experiment == "static":
            return self._static(params).runs()
        if self.experiment == "step":
            return [step_plan(params, load, inputs["controller"], hold=self._hold(),
                              dt=self.dt)]
        if self.experiment == "sine":
            return [sine_plan(params, load, inputs["controller"], self._sine(), dt=self.dt)]
        return [run for task in self._table2(params).tasks for run in task.runs()]

    def reduce(self, results: list[SimResult]) -> dict[str, float]:
        if self.experiment == "static":
            loop = self._static(self._params()).reduce(results)
            return {"loop_area_mpa_mm": loop.area_mpa_mm,
                    "po_max_mpa": float(_moved(loop.result).po_reg.max()) / MPA}
        if self.experiment == "step":
            return _step_metrics(_moved(*results), self._hold())
        if self.experiment == "sine":
            return _sine_metrics(_moved(*results), self._sine())
        batch = self._table2(self._params())  # each of its tasks is one run
        t2 = batch.assemble([task.reduce([r]) for task, r in zip(batch.tasks, results)])
        _moved(t2.feedback_runs[0].result, *(lp.result for lp in (*t2.open_loops, *t2.po_loops)))
        load = self.inputs["load"]
        return {"open_po": t2.open_po[load], "feedback": t2.feedback[load],
                **_step_metrics(t2.feedback_runs[0].result, STEP_HOLD_S)}
