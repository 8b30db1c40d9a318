"""Calibration plumbing: parameter mapping, search, and the TOML it writes.

The full fit runs the simulator for tens of minutes (`wpam calibrate`); here the search is
checked on residuals with a known minimum, which is what a recovery test needs."""

import math

import numpy as np
import pytest

from wpam_mj.calibrate import (DYNAMIC_FIT, STATIC_FIT, CalibrationResult, FitParameter,
                               _search, with_values)
from wpam_mj.params import apply_overrides, load_toml, preset


@pytest.mark.parametrize("p", [*STATIC_FIT, *DYNAMIC_FIT])
def test_unit_mapping_round_trips_inside_the_bounds(p: FitParameter):
    for value in (p.lo, p.hi, math.sqrt(p.lo * p.hi) if p.log else 0.5 * (p.lo + p.hi)):
        assert p.from_unit(p.to_unit(value)) == pytest.approx(value, rel=1e-12)
    assert p.from_unit(-0.5) == pytest.approx(p.lo) and p.from_unit(1.5) == pytest.approx(p.hi)


def test_search_recovers_known_parameters():
    """Residuals that vanish at known values: the search must find them."""
    fit = (FitParameter("muscle", "friction_coeff", 0.002, 0.3),
           FitParameter("muscle", "axial_area", 5e-5, 3e-3))
    truth = {"friction_coeff": 0.021, "axial_area": 7.5e-4}

    def residuals(p):
        return np.array([math.log(p.muscle.friction_coeff / truth["friction_coeff"]),
                         math.log(p.muscle.axial_area / truth["axial_area"])])

    best, res = _search(preset("wpam"), fit, residuals, maxiter=400, progress=False,
                        label="test")
    assert best.muscle.friction_coeff == pytest.approx(truth["friction_coeff"], rel=1e-3)
    assert best.muscle.axial_area == pytest.approx(truth["axial_area"], rel=1e-3)
    assert np.all(np.abs(res) < 1e-3)


def test_written_toml_reproduces_the_fitted_parameters(tmp_path):
    params = with_values(preset("wpam"), STATIC_FIT, [0.35, 0.2, 0.02, 3.0, 1e-3])
    fitted = {f"{p.section}.{p.name}": getattr(getattr(params, p.section), p.name)
              for p in (*STATIC_FIT, *DYNAMIC_FIT)}
    result = CalibrationResult(params, fitted, np.zeros(3), np.zeros(2))
    path = tmp_path / "fit.toml"
    path.write_text(result.toml())
    assert apply_overrides(preset("wpam"), load_toml(path)) == params
