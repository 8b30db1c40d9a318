"""A step study's duration: too short a staircase is refused when the file is read, naming
the shortest one the protocol holds at, and a row whose muscle does not follow its
staircase says so in user terms."""

from __future__ import annotations

import numpy as np
import pytest

from wpam_mj.cli import main
from wpam_mj.cli.runs import UNSETTLED_PP_MM
from wpam_mj.design import metrics, study_spec
from wpam_mj.experiments.drives import step_run
from wpam_mj.paper import STEP_LEVELS_MM
from wpam_mj.physics.params import preset
from wpam_mj.errors import ParameterError
from wpam_mj.units import MM


def _worst_late_swing(hold: float) -> float:
    """Largest x peak-to-peak [mm] over the averaged last half of any plateau of the
    shipped plant's PI staircase at 100 N with plateaus of `hold` s."""
    r = step_run(preset("wpam"), 100.0, "pi", hold=hold)
    plateau = (r.time // hold).astype(int)
    late = r.time % hold >= hold / 2
    return max(float(np.ptp(r.x[late & (plateau == k)]))
               for k in range(len(STEP_LEVELS_MM))) / MM


def test_the_shortest_step_duration_is_where_the_plateaus_settle():
    hold = study_spec.MIN_STEP_HOLD_S
    assert study_spec.MIN_STEP_DURATION_S == pytest.approx(hold * len(STEP_LEVELS_MM))
    assert _worst_late_swing(hold) < 0.2 * UNSETTLED_PP_MM
    assert _worst_late_swing(hold - 0.5) > UNSETTLED_PP_MM


def test_a_step_study_too_short_to_settle_is_refused_in_one_line(tmp_path, capsys):
    spec = tmp_path / "short.toml"
    spec.write_text('experiment = "step"\n[fixed]\nduration = 2.0\n'
                    '[vary]\nvalues = {load = [60, 120]}\n')
    assert main(["study", str(spec), "--out", str(tmp_path / "o"), "--jobs", "1"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "Traceback" not in err, err
    assert "duration = 2 s" in err and f"holds from {study_spec.MIN_STEP_DURATION_S:g} s" in err
    assert not (tmp_path / "o").exists()
    parsed = study_spec.parse_spec({"experiment": "step", "vary": {"values": {
        "duration": [study_spec.MIN_STEP_DURATION_S]}}})
    assert parsed.values["duration"] == (study_spec.MIN_STEP_DURATION_S,)


def test_a_row_whose_muscle_does_not_follow_the_staircase_says_so():
    """A line a hundred times as restrictive: Pi's plateau means rise to the end, so
    there is no loop; the row's reason is the muscle's, not the loop analysis's."""
    params = preset("wpam")
    slow = params.replace(pneumatics={
        "inner_conductance": params.pneumatics.inner_conductance / 100})
    inputs = {"load": 100.0, "controller": "pi", "duration": study_spec.MIN_STEP_DURATION_S}
    with pytest.raises(ParameterError, match="did not follow the staircase of 3 s plateaus"):
        metrics.MetricsTask("step", slow, inputs, 1e-3).run()
