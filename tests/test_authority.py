"""The feedforward's authority over a plant it does not know exactly (§4.1: Pi puts the
muscle in an excessive contraction state that Po, which can only hold back, brings back):
the inverse of eqs. 5-6, and what it predicts of a simulated staircase."""

import dataclasses

import numpy as np
import pytest

from wpam_mj.experiments.drives import step_run
from wpam_mj.physics.muscle import MuscleModel
from wpam_mj.physics.params import preset
from wpam_mj.reproduction import authority

WEAKER = (("muscle.output_coeff", -0.03), ("braid.braid_angle", 0.02))  # a weaker plant


@pytest.mark.parametrize("share", [-1.0, 0.0, 0.4, 1.0, 1.2])
def test_the_friction_share_inverts_the_equilibrium_model(share):
    muscle = MuscleModel.from_params(preset("wpam"))
    x = np.array([0.005, 0.02, 0.045])
    pi = muscle.equilibrium_pressure(x, 120.0, 7e3, share)
    assert muscle.friction_share(x, 120.0, pi, 7e3) == pytest.approx(share, abs=1e-9)


def test_the_nominal_plant_sits_at_the_feedforwards_own_share():
    params = preset("wpam")  # Po_ff = p_min: the plant's share is φ itself
    assert params.controller.po_feedforward == params.pneumatics.p_min
    assert authority.plant_share(params) == pytest.approx(
        params.controller.feedforward_friction)
    assert authority.needed_share(params) == pytest.approx(1.0)


def test_a_weaker_plant_is_short_of_its_branch_and_asks_a_larger_share():
    params = dataclasses.replace(preset("wpam"), plant_deviation=WEAKER)
    assert authority.plant_share(params) < 1.0 < authority.needed_share(params)
    stronger = dataclasses.replace(params, plant_deviation=tuple(
        (n, -d) for n, d in WEAKER))
    assert authority.plant_share(stronger) > params.controller.feedforward_friction


def test_short_of_its_branch_the_po_loop_stalls_and_over_contracted_it_reaches_the_target():
    """Simulated PI staircase at 150 N: the weaker plant under the shipped φ stops short
    of the contraction targets with Po at the regulator's floor (the loop has nothing
    left); with φ at the plant's needed share it reaches them."""
    params = dataclasses.replace(preset("wpam"), plant_deviation=WEAKER)
    short = step_run(params, 150.0, "pi", levels_mm=(0, 20), hold=8.0)
    end = short.time > 14.0
    assert np.all(short.x_ref[end] - short.x[end] > 2e-3)  # > 2 mm short
    assert np.all(short.po_cmd[end] <= params.pneumatics.p_min * (1 + 1e-9))
    phi = authority.needed_share(params) + 0.02
    reach = step_run(params.with_values({"controller.feedforward_friction": phi}), 150.0,
                     "pi", levels_mm=(0, 20), hold=8.0)
    end = reach.time > 14.0
    assert np.all(np.abs(reach.x_ref[end] - reach.x[end]) < 1e-3)
