"""A muscle type without an outer bag (rlam, mckibben) has no outer chamber: its Po is the
atmosphere (0 gauge) at every step however the inner bag moves, on every engine, and its
tension is the closed form at Po = 0; the W-PAM's outer chamber still breathes with it.
(The Warp backend's case is in tests/test_warp.py.)"""

from __future__ import annotations

import numpy as np
import pytest

from wpam_mj.physics.muscle import MuscleModel
from wpam_mj.physics.params import preset
from wpam_mj.units import MPA
from wpam_mj.simulation import plugin
from wpam_mj.simulation.simulate import Drive, simulate

ENGINES = [pytest.param("plugin", marks=pytest.mark.skipif(
    not plugin.available(), reason="no compiled plugin here")), "python"]


def _up_and_down(name: str, engine: str, seconds: float = 3.0):
    """Pi 0 -> 0.3 MPa -> 0 (a triangle) under 100 N, Po commanded 0: the muscle contracts
    and extends."""
    dt = 1e-3
    t = np.arange(round(seconds / dt)) * dt
    pi = 0.3 * MPA * (1.0 - np.abs(2.0 * t / seconds - 1.0))
    drive = Drive(pi, np.zeros_like(t), np.full(len(t), np.nan))
    return simulate(preset(name), 100.0, drive, dt=dt, record_dt=0.01, engine=engine)


@pytest.mark.parametrize("engine", ENGINES)
@pytest.mark.parametrize("name", ["rlam", "mckibben"])
def test_a_muscle_without_an_outer_bag_keeps_po_at_the_atmosphere(name, engine):
    res = _up_and_down(name, engine)
    assert np.ptp(res.x) > 0.02 and np.max(np.abs(res.velocity)) > 0.01  # it moved
    assert np.all(res.po == 0.0), f"Po reached {np.max(np.abs(res.po)):g} Pa"
    model = MuscleModel.from_params(preset(name))
    closed = [model.tendon_force(x, pi, 0.0) for x, pi in zip(res.x, res.pi)]
    np.testing.assert_allclose(res.tension, closed, rtol=1e-12, atol=1e-9)


@pytest.mark.parametrize("engine", ENGINES)
def test_the_wpams_outer_chamber_is_still_compressed_by_the_inner_bag(engine):
    """The flag is the type's: the W-PAM's closed outer bag, Po vented through its
    restriction, still rises while the inner bag swells into it."""
    res = _up_and_down("wpam", engine)
    assert np.max(res.po) > 100.0  # Pa gauge
