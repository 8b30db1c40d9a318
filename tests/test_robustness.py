"""Robustness over the plant's uncertainty: the Latin-hypercube sample, the nominal model
the controller keeps while the plant deviates, the summary of held findings, and the
limit-velocity experiment."""

import json
import math
import subprocess
import sys

import numpy as np
import pytest

from wpam_mj.experiments.drives import step_plan
from wpam_mj.experiments.limit_velocity import limit_velocity, sine_at_the_limit, variant
from wpam_mj.physics import kernel
from wpam_mj.physics.params import preset
from wpam_mj.errors import ParameterError
from wpam_mj.reproduction import feedforward_fit, findings, robustness
from wpam_mj.reproduction.margins import Check, Margin


def test_the_sample_is_a_seeded_latin_hypercube_within_its_box():
    dev = robustness.sample_deviations(16, seed=3, rel=0.05)
    assert dev.shape == (16, len(robustness.UNMEASURED))
    assert np.all(np.abs(dev) <= 0.05)
    strata = np.floor((dev / 0.05 + 1.0) / 2.0 * 16).astype(int)  # each stratum once
    assert all(sorted(col) == list(range(16)) for col in strata.T)
    assert np.array_equal(dev, robustness.sample_deviations(16, seed=3, rel=0.05))
    assert not np.array_equal(dev, robustness.sample_deviations(16, seed=4, rel=0.05))


def test_a_measured_value_narrows_its_own_range_and_keeps_every_other_draw():
    """Known to +-1 %, the braid angle's deviations are the +-5 % draw scaled by 0.2; known
    exactly, they are 0; every other parameter's column is the same draw."""
    braid = robustness.UNMEASURED.index("braid.braid_angle")
    wide = robustness.sample_deviations(16, seed=3, rel=0.05)
    narrow = robustness.sample_deviations(16, seed=3, rel=0.05,
                                          measured={"braid.braid_angle": 0.01})
    exact = robustness.sample_deviations(16, seed=3, rel=0.05,
                                         measured={"braid.braid_angle": 0.0})
    assert narrow[:, braid] == pytest.approx(0.2 * wide[:, braid], abs=1e-15)
    assert np.all(exact[:, braid] == 0.0)
    others = np.arange(wide.shape[1]) != braid
    assert np.array_equal(narrow[:, others], wide[:, others])
    assert np.array_equal(exact[:, others], wide[:, others])


@pytest.mark.parametrize("measured, what", [({"braid.foo": 0.01}, "not an unmeasured"),
                                            ({"braid.braid_angle": -0.01}, "allowed range"),
                                            ({"braid.braid_angle": 0.6}, "allowed range")])
def test_a_bad_measured_value_is_refused_in_one_line(measured, what):
    with pytest.raises(ParameterError, match=what) as err:
        robustness.sample_deviations(4, seed=0, measured=measured)
    assert "\n" not in str(err.value)


@pytest.mark.parametrize("n, rel, what", [(0, 0.05, "samples"), (4, 0.0, "rel"),
                                          (4, 0.9, "rel")])
def test_a_bad_sample_is_refused_in_one_line(n, rel, what):
    with pytest.raises(ParameterError, match=what) as err:
        robustness.sample_deviations(n, seed=0, rel=rel)
    assert "\n" not in str(err.value)


def test_the_plant_deviates_while_the_feedforward_keeps_the_nominal_model():
    nominal = preset("wpam")
    (plant,) = robustness.sampled_plants(
        nominal, np.array([[0.05 if n == "muscle.friction_coeff" else 0.0
                            for n in robustness.UNMEASURED]]))
    assert plant.plant.muscle.friction_coeff == pytest.approx(
        1.05 * nominal.muscle.friction_coeff)
    assert plant.plant.plant_deviation == ()
    nominal_run = step_plan(nominal, 100.0, "pi")
    deviated_run = step_plan(plant, 100.0, "pi")
    # the feedforward's Pi commands are the nominal model's, bit for bit ...
    assert np.array_equal(nominal_run.inputs, deviated_run.inputs)
    # ... while the rig simulates the deviated plant
    assert nominal_run.spec.to_xml() != deviated_run.spec.to_xml()


def test_a_sample_that_physics_does_not_admit_is_pulled_toward_the_nominal():
    """A braid angle 2 % below its locking angle cannot deviate +5 %: the sampled plant is
    the deviation halved until the bag still fills before the threads lock; an admissible
    deviation is kept as drawn."""
    base = preset("wpam")
    locking = kernel.locking_angle(base.braid.natural_diameter, base.braid.max_diameter)
    near = base.with_values({"braid.braid_angle": 0.98 * locking})
    names = ("braid.braid_angle", "muscle.friction_coeff")
    plants = robustness.sampled_plants(near, np.array([[0.05, 0.05], [0.01, -0.05]]), names)
    (name, bent), (_, mu) = plants[0].plant_deviation
    assert name == "braid.braid_angle" and 0.0 < bent < 0.02 / 0.98 and mu == bent
    assert plants[0].plant.value("braid.braid_angle") < locking
    assert plants[1].plant_deviation == (("braid.braid_angle", 0.01),
                                         ("muscle.friction_coeff", -0.05))


@pytest.mark.parametrize("name", ["controller.kp", "muscle.no_such"])
def test_a_deviation_of_anything_but_a_plant_parameter_is_refused(name):
    nominal = preset("wpam")
    with pytest.raises(ParameterError, match="plant_deviation") as err:
        type(nominal)(plant_deviation=((name, 0.01),))
    assert "\n" not in str(err.value)


def _outcome(passed: dict, error: str = ""):
    checks = tuple(Check(n, n, passed.get(n), "") for n in findings.FINDINGS)
    cells = {cell: 0.1 for cell in robustness.CELLS}
    return robustness.PlantOutcome((), () if error else checks, {} if error else cells,
                                   error)


def test_the_summary_counts_plants_and_a_failed_plant_holds_nothing():
    name = "po_reaches_cap"
    result = robustness.Robustness((_outcome({name: True}), _outcome({name: True}),
                                    _outcome({name: False}), _outcome({}, "diverged")),
                                   0.05, 0)
    assert result.held_fraction()[name] == pytest.approx(0.5)
    assert result.held_fraction()["gain_spread"] == 0.0  # the failed plant holds none
    md = result.markdown()
    assert "50% (2 of 4)" in md and "**fragile**" in md and "could not be run" in md


def test_the_held_fraction_comes_with_its_wilson_interval_which_narrows_with_the_sample():
    """The interval is Wilson's closed form (z = 1.96), holds the sample's fraction, and
    a four times larger sample with the same fraction halves its width, about."""
    name = "po_reaches_cap"

    def interval(k: int, n: int) -> tuple[float, float]:
        result = robustness.Robustness(tuple(_outcome({name: i < k}) for i in range(n)),
                                       0.05, 0)
        return result.held_interval()[name]

    z, k, n = 1.959964, 23, 32
    p = k / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z / (1 + z * z / n) * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n))
    lo, hi = interval(k, n)
    assert (lo, hi) == pytest.approx((centre - half, centre + half), abs=1e-6)
    assert lo < p < hi and hi < robustness.HOLD_TARGET + 0.1
    lo4, hi4 = interval(4 * k, 4 * n)
    assert lo < lo4 < p < hi4 < hi and (hi4 - lo4) / (hi - lo) == pytest.approx(0.5, abs=0.05)
    assert interval(n, n)[1] == pytest.approx(1.0) and interval(n, n)[0] > 0.85
    md = robustness.Robustness((_outcome({name: True}), _outcome({name: False})), 0.05,
                               0).markdown()
    assert "95 % interval" in md and "| 50% (1 of 2) | 9%-91% |" in md


def test_the_summary_splits_the_plants_by_the_feedforwards_authority():
    """Over-contracted plants (share >= 1) and the others are counted apart, and the φ
    that would over-contract a fraction of them is that quantile of their needed shares."""
    import dataclasses  # noqa: PLC0415

    name = "table2_shape"
    plants = [dataclasses.replace(_outcome({name: held}), feedforward_share=share,
                                  needed_share=need)
              for held, share, need in ((True, 1.05, 0.98), (True, 1.0, 1.02),
                                        (False, 0.9, 1.2), (True, 0.95, 1.1))]
    result = robustness.Robustness(tuple(plants), 0.05, 0)
    over, short = result.over_contracted()
    assert len(over) == 2 and len(short) == 2
    md = result.markdown()
    row = next(line for line in md.splitlines()
               if line.startswith(f"| {findings.FINDINGS[name].short} |"))
    assert row.endswith("| 2 of 2 | 1 of 2 |")
    assert "over-contracts 2 of 4 plants" in md
    assert "100% of them is 1.20" in md


def test_the_sensitivity_recovers_which_deviation_decides_a_finding():
    """A margin that is a known plane in the deviations (2 per +rel of the first, -0.5 per
    +rel of the third, none of the second) comes back as its slopes, largest first, with
    R² 1; a margin that never varies is left out."""
    rel, name, flat = 0.05, "po_reaches_cap", "open_loop_hardly_extends"
    names = ("muscle.friction_coeff", "muscle.axial_area", "braid.braid_angle")
    dev = robustness.sample_deviations(12, seed=1, rel=rel, names=names)
    outcomes = []
    for row in dev:
        margin = 0.3 + 2.0 * row[0] / rel - 0.5 * row[2] / rel
        checks = (Check(name, name, margin >= 0, "", (Margin(margin, 0.0, 1, 1.0),)),
                  Check(flat, flat, True, "", (Margin(2.0, 0.0, 1, 1.0),)))
        outcomes.append(robustness.PlantOutcome(tuple(zip(names, row)), checks, {}))
    sens = robustness.Robustness(tuple(outcomes), rel, 1).sensitivity()
    assert set(sens) == {name}
    assert [n for n, _ in sens[name].slopes] == [names[0], names[2], names[1]]
    assert [s for _, s in sens[name].slopes] == pytest.approx([2.0, -0.5, 0.0], abs=1e-9)
    assert sens[name].r2 == pytest.approx(1.0)
    assert sens[name].describe() == "friction_coeff +2.00, braid_angle -0.50 (R² 1.00)"


def test_the_steps_decided_at_landing_are_counted_among_the_plants_that_miss_them():
    def plant(holds: bool, landed: bool | None, error: str = ""):
        check = Check("steps_settle", "steps", holds, "", (Margin(1.0 if holds else -1.0, 0.0,
                                                                  1, 1.0),))
        return robustness.PlantOutcome((), (check,), {}, error,
                                       steps_decided_at_landing=landed)

    result = robustness.Robustness((plant(True, False), plant(False, True), plant(False, True),
                                    plant(False, False), plant(False, None, "diverged")),
                                   0.05, 0)
    assert result.decided_at_landing() == (2, 3)
    assert "PI steps: in 2 of the 3 plants that miss them" in result.markdown()


def test_the_sensitivity_reads_a_measured_value_at_its_own_range():
    """With the braid angle measured to +-1 %, its slope is the margin's change at +1 %;
    known exactly, it is left out of the plane."""
    rel, name = 0.05, "po_reaches_cap"
    names = ("muscle.friction_coeff", "muscle.axial_area", "braid.braid_angle")
    for width, expected in ((0.01, [2.0, -0.5, 0.0]), (0.0, [2.0, 0.0])):
        measured = {"braid.braid_angle": width}
        dev = robustness.sample_deviations(12, seed=1, rel=rel, names=names,
                                           measured=measured)
        outcomes = []
        for row in dev:
            margin = 0.3 + 2.0 * row[0] / rel - 0.5 * (row[2] / width if width else 0.0)
            checks = (Check(name, name, margin >= 0, "", (Margin(margin, 0.0, 1, 1.0),)),)
            outcomes.append(robustness.PlantOutcome(tuple(zip(names, row)), checks, {}))
        result = robustness.Robustness(tuple(outcomes), rel, 1,
                                       robustness.check_measured(measured, names))
        sens = result.sensitivity()[name]
        assert [s for _, s in sens.slopes] == pytest.approx(expected, abs=1e-9)
        assert ("braid.braid_angle" in dict(sens.slopes)) == (width > 0.0)
        assert result.box() == f"+-5%, braid_angle +-{width:.0%}"


def test_the_limit_velocity_grows_with_the_lines_that_set_it():
    """The fastest contraction and extension under a saturated Po command; wider lines move
    the air the motion needs faster (docs/physics.md, "What sets the limit velocity")."""
    params = preset("wpam")
    base = limit_velocity(params, 100.0, hold=1.5)
    wide = limit_velocity(variant(params, {"pneumatics.inner_conductance": 3.0,
                                           "pneumatics.outer_conductance": 3.0}), 100.0,
                          hold=1.5)
    assert base.contraction > 0.0 and base.extension > 0.0
    assert wide.contraction > 1.5 * base.contraction
    assert wide.extension > 1.5 * base.extension


def test_robustness_command_refuses_a_bad_sample_in_one_line(tmp_path):
    proc = subprocess.run([sys.executable, "-m", "wpam_mj", "robustness", "--samples", "0",
                           "--out", str(tmp_path / "r")], capture_output=True, text=True)
    assert proc.returncode != 0
    assert proc.stderr.strip().count("\n") == 0 and "samples" in proc.stderr


def test_one_sampled_plant_runs_every_study_and_writes_its_files(tmp_path):
    """End to end on one plant: every finding of `wpam reproduce` is checked on it, and
    the CSV, JSON, Markdown and figure are written whole."""
    result = robustness.robustness(preset("wpam"), 1, seed=2, jobs=2)
    (outcome,) = result.outcomes
    assert outcome.error == "" and {c.name for c in outcome.checks} == set(findings.FINDINGS)
    assert set(outcome.cells) == set(robustness.CELLS)
    assert isinstance(outcome.steps_decided_at_landing, bool)
    # the controller's model was fitted to this plant's own loops (the default)
    assert result.feedforward == "calibrated" and 0.0 < outcome.fit_rms < 2e-3
    assert [n for n, _ in outcome.model_error] == list(feedforward_fit.FEEDFORWARD_MODEL)
    assert outcome.feedforward_share >= 1.0  # it puts the plant past its own branch
    written = robustness.write_robustness(tmp_path, result)
    assert sorted(p.name for p in written) == ["robustness.csv", "robustness.json",
                                               "robustness.md", "robustness.png"]
    summary = json.loads((tmp_path / "robustness.json").read_text())
    assert summary["feedforward"] == "calibrated" and summary["calibration_ramp_time_s"] is None
    assert set(summary["model_error_median"]) == set(feedforward_fit.FEEDFORWARD_MODEL)
    assert not list(tmp_path.glob(".*"))


@pytest.mark.parametrize("load", [50.0, 150.0])
def test_from_half_a_hertz_the_pi_loop_works_at_its_limits(load):
    """§4.2: above about 0.5 Hz "the system ... operates at almost the limit velocity": the
    Po command sits at its cap or floor most of each cycle (bang-bang), unlike at 0.1 Hz,
    and the fastest speeds reached are the limit's order, not the target's 78.5 mm/s
    (2 pi 0.5 Hz x 25 mm) both ways."""
    params = preset("wpam")
    slow, fast = (sine_at_the_limit(params, load, f) for f in (0.1, 0.5))
    assert slow.at_floor + slow.at_cap < 0.6
    assert fast.at_floor + fast.at_cap > 0.8
    assert fast.gain < 0.8 * slow.gain and fast.lag_deg > 5.0 * slow.lag_deg
    assert min(fast.contraction, fast.extension) < 2 * math.pi * 0.5 * 0.025


def test_the_structure_sample_fills_its_box_one_stratum_a_value():
    """`structure_sample`: every element within its range, each of its n strata used
    once (log strata for the conductances), the same seed the same plants, the rest of the
    plant untouched."""
    from wpam_mj.experiments.limit_velocity import STRUCTURE_BOX, structure_sample  # noqa: PLC0415

    params, n = preset("wpam"), 16
    plants = structure_sample(params, n, seed=3)
    for name, (lo, hi, log) in STRUCTURE_BOX.items():
        v = np.array([p.value(name) for p in plants])
        assert np.all((v >= lo) & (v <= hi)), name
        q = np.log(v / lo) / np.log(hi / lo) if log else (v - lo) / (hi - lo)
        assert sorted(np.floor(q * n).astype(int)) == list(range(n)), name
    again = structure_sample(params, n, seed=3)
    assert [p.pneumatics for p in plants] == [p.pneumatics for p in again]
    assert all(p.muscle == params.muscle and p.controller == params.controller
               for p in plants)


def test_structure_sweep_script_writes_its_fractions_from_its_rows(tmp_path):
    """scripts/structure_sweep.py on two plants at 1 Hz: the JSON's fractions are the CSV's
    verdicts counted over the plants that move, and checks that need another frequency
    are left out."""
    import csv  # noqa: PLC0415
    from pathlib import Path  # noqa: PLC0415

    script = Path(__file__).resolve().parents[1] / "scripts" / "structure_sweep.py"
    proc = subprocess.run([sys.executable, str(script), "--samples", "2", "--freqs", "1",
                           "--jobs", "2", "--out", str(tmp_path)],
                          capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    rows = list(csv.DictReader((tmp_path / "structure_sweep.csv").open()))
    summary = json.loads((tmp_path / "structure_sweep.json").read_text())
    moving = [r for r in rows if r["moved"] == "true"]
    assert len(rows) == 2 == summary["ran"] and summary["freqs_hz"] == [1.0]
    assert summary["moving"] == len(moving) > 0
    for name, frac in summary["held_fraction"].items():
        assert frac == sum(r[f"{name}_holds"] == "true" for r in moving) / len(moving), name
    assert "lag_order_low_freq" not in summary["held_fraction"]  # needs < 0.5 Hz
    assert (tmp_path / "structure_sweep.png").stat().st_size > 0
