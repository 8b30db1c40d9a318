"""One run of a study, reduced to its experiment's metrics (display units)."""

from __future__ import annotations

from typing import Any, Mapping

import numpy as np

from wpam_mj.experiments.analysis import frequency_response, loop_area, steady_state_means
from wpam_mj.experiments.drives import SineSpec, check_po, sine_run, step_run
from wpam_mj.experiments.feasibility import MOVE_MIN_MM, check_liftable, load_moved
from wpam_mj.experiments.responses import LOOP_METHOD
from wpam_mj.experiments.paper_studies import PLATEAU_SETTLE_S, StaticTask, plateau_segments
from wpam_mj.experiments.protocol import SHIPPED, table2_batch
from wpam_mj.paper import STEP_HOLD_S, STEP_LEVELS_MM
from wpam_mj.physics.params import MM, MPA, ParameterError, Params


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
    return {"loop_area_mpa_mm": loop_area(pi, x, method=LOOP_METHOD) / (MPA * MM),
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


def run_metrics(experiment: str, params: Params, inputs: Mapping[str, Any],
                dt: float) -> dict[str, float]:
    """Simulate one run and reduce it to the experiment's metrics (display units).
    ParameterError for a load this parameter set cannot lift or one that never moved."""
    load = inputs["load"]
    check_liftable(params, (load,), "load")
    if experiment == "static":
        loop = StaticTask(params, load, check_po("po_down", inputs["po_down"], params),
                          dt).run()
        return {"loop_area_mpa_mm": loop.area_mpa_mm,
                "po_max_mpa": float(_moved(loop.result).po_reg.max()) / MPA}
    if experiment == "step":
        hold = inputs["duration"] / len(STEP_LEVELS_MM)
        r = step_run(params, load, inputs["controller"], hold=hold, dt=dt)
        return _step_metrics(_moved(r), hold)
    if experiment == "sine":
        spec = SineSpec(inputs["frequency"], amplitude=inputs["amplitude"])
        r = sine_run(params, load, inputs["controller"], spec, dt=dt)
        return _sine_metrics(_moved(r), spec)
    batch = table2_batch(params, SHIPPED, loads=(load,), po_down=inputs["po_down"], dt=dt)
    t2 = batch.assemble([task.run() for task in batch.tasks])
    _moved(t2.feedback_runs[0].result, *(lp.result for lp in (*t2.open_loops, *t2.po_loops)))
    return {"open_po": t2.open_po[load], "feedback": t2.feedback[load],
            **_step_metrics(t2.feedback_runs[0].result, STEP_HOLD_S)}
