"""The regulators as devices (kernel.regulator_flow): a valve holds the regulator's outlet at
its set point while it can, valve and line in series from the supply (or to the exhaust)
once it cannot. Closed forms: the choked fill's time, the series law, the ideal source as
the limit of a large valve, a sealed chamber's pV; and the shipped rig's lines, not its
regulator, set the flow."""

from __future__ import annotations

import math

import pytest

from wpam_mj import paper
from wpam_mj.experiments.limit_velocity import VARIANTS, limit_velocity, variant
from wpam_mj.physics import kernel
from wpam_mj.physics.params import ParameterError, Pneumatics, preset
from wpam_mj.units import MPA

ATM = 101325.0
B = 0.5
LINE = 2.6e-9  # m^3/(s Pa), the order of the shipped lines


def test_series_conductance_is_isos_law():
    """1/C^2 = 1/C1^2 + 1/C2^2: symmetric, below either, sqrt(2)/2 of two equal ones."""
    assert kernel.series_conductance(3e-9, 4e-9) == pytest.approx(2.4e-9, rel=1e-12)
    assert kernel.series_conductance(4e-9, 3e-9) == kernel.series_conductance(3e-9, 4e-9)
    assert kernel.series_conductance(LINE, LINE) == pytest.approx(LINE / math.sqrt(2.0))


@pytest.mark.parametrize("chamber", [0.3 * ATM + ATM, 0.9 * ATM + ATM, 1.7 * ATM + ATM])
def test_a_large_valve_is_an_ideal_source_behind_the_line(chamber):
    """With valves far larger than the line the device's flow is the line's from the set
    point, filling and venting (to within the series' (C_line / C_valve)^2 / 2)."""
    for set_abs in (ATM + 5e3, ATM + 0.08 * MPA, ATM + 0.5 * MPA):
        ideal = kernel.mass_flow(set_abs, chamber, LINE, B)
        device = kernel.regulator_flow(set_abs, chamber, ATM + 0.6 * MPA, ATM, LINE,
                                       1e-6, 1e-6, B)
        assert device == pytest.approx(ideal, rel=1e-5)


def test_a_small_valve_fills_from_the_supply_through_the_series():
    """Valve-limited: the flow is valve and line in series from the supply, which is less
    than the line alone would pass from the set point; venting likewise to the exhaust."""
    supply, valve = ATM + 0.6 * MPA, 1e-9
    series = kernel.series_conductance(valve, LINE)
    fill = kernel.regulator_flow(ATM + 0.5 * MPA, ATM, supply, ATM, LINE, valve, valve, B)
    assert fill == kernel.mass_flow(supply, ATM, series, B)
    assert fill < kernel.mass_flow(ATM + 0.5 * MPA, ATM, LINE, B)
    vent = kernel.regulator_flow(ATM + 5e3, ATM + 0.4 * MPA, supply, ATM, LINE, valve, valve, B)
    assert vent == kernel.mass_flow(ATM, ATM + 0.4 * MPA, series, B) < 0.0
    assert vent > kernel.mass_flow(ATM + 5e3, ATM + 0.4 * MPA, LINE, B)


def test_the_flow_never_exceeds_either_limit_and_keeps_its_sign():
    """Filling below the set point, venting above it, never more than the line passes from
    the set point nor than the series passes from the supply or to the exhaust."""
    supply, valve = ATM + 0.6 * MPA, 5e-9
    series = kernel.series_conductance(valve, LINE)
    for set_gauge in (5e3, 4e4, 8e4, 3e5):
        for chamber_gauge in (0.0, 2e4, 6e4, 1e5, 4e5):
            s, c = ATM + set_gauge, ATM + chamber_gauge
            m = kernel.regulator_flow(s, c, supply, ATM, LINE, valve, valve, B)
            line = kernel.mass_flow(s, c, LINE, B)
            if s >= c:
                assert 0.0 <= m <= line and m <= kernel.mass_flow(supply, c, series, B)
            else:
                assert line <= m < 0.0 and m >= kernel.mass_flow(ATM, c, series, B)


@pytest.mark.parametrize("n", [1.0, 1.4])
def test_a_choked_fill_from_the_supply_takes_the_analytic_time(n):
    """A fixed volume filled with the valve wide open, choked throughout (chamber below
    b p_supply): dp/dt = n R T0 C_s rho_0 p_supply / V, a constant, so the rise from the
    atmosphere to 0.2 MPa gauge takes V dp / (n R T0 C_s rho_0 p_supply): an adiabatic
    chamber (n 1.4) fills 1.4 times faster than an isothermal one."""
    volume, dt, supply, valve = 1e-4, 1e-5, ATM + 0.6 * MPA, 1e-9
    target = ATM + 0.2 * MPA
    assert target <= B * supply
    series = kernel.series_conductance(valve, LINE)
    analytic = volume * (target - ATM) / (n * kernel.RT0 * series * kernel.RHO_0 * supply)
    p, t = ATM, 0.0
    while p < target:
        m = kernel.regulator_flow(ATM + 0.5 * MPA, p, supply, ATM, LINE, valve, valve, B)
        p = kernel.chamber_step(p, m, volume, 0.0, 0.0, n, dt)
        t += dt
    assert t == pytest.approx(analytic, abs=2 * dt)


@pytest.mark.parametrize("n", [1.0, 1.2, 1.4])
def test_a_sealed_chamber_keeps_p_v_to_the_n(n):
    """No flow, a moving wall: p V^n stays what it was (isothermal p V, adiabatic p V^1.4;
    explicit Euler, first order in dt: within 1e-4 over a 20 % compression at 1e-5 s)."""
    v0, dvdx, speed, dt = 1e-4, -2e-3, 0.1, 1e-5  # V = v0 + dvdx x, x = speed t
    p, x = 2e5, 0.0
    for _ in range(10000):
        p = kernel.chamber_step(p, 0.0, v0 + dvdx * x, dvdx, speed, n, dt)
        x += speed * dt
    assert p * (v0 + dvdx * x) ** n == pytest.approx(2e5 * v0 ** n, rel=1e-4)
    assert p > 2e5 * (v0 / (v0 + dvdx * x)) ** (n - 0.1), "compressed harder than n - 0.1"


def test_on_the_shipped_rig_the_lines_set_the_flow():
    """The ITV2031's valve (1500 L/min, C 3.6e-8) passes several times what either line
    does, so the regulator holds its outlet at the set point almost always: from the
    atmosphere to the 0.08 MPa cap the flow is the line's from the set point."""
    pn = preset("wpam").pneumatics
    supply = pn.supply_pressure + pn.atmosphere
    for line in (pn.inner_conductance, pn.outer_conductance):
        assert pn.supply_valve_conductance > 5 * line
        for chamber_gauge in (0.0, 2e4, 4e4, 7e4):
            set_abs, c = pn.atmosphere + 0.08 * MPA, pn.atmosphere + chamber_gauge
            m = kernel.regulator_flow(set_abs, c, supply, pn.atmosphere, line,
                                      pn.supply_valve_conductance,
                                      pn.exhaust_valve_conductance, pn.critical_ratio)
            assert m == kernel.mass_flow(set_abs, c, line, pn.critical_ratio)


def test_a_supply_below_the_regulators_range_is_refused_in_one_line():
    with pytest.raises(ParameterError, match=r"pneumatics.supply_pressure.*p_max"):
        Pneumatics(supply_pressure=0.4 * MPA)


def test_only_a_valve_limited_regulator_makes_the_contraction_limit_load_independent():
    """The limit velocity (§4.2): behind the lines, the speed follows the load (the line's
    flow is driven by p_set - p); with a tenth of the ITV2031's valve the choked fill from
    the supply sets it, the same at every load."""
    plant = preset("wpam")
    small = variant(plant, VARIANTS["regulator valves /10 (ITV1000 class)"])
    lines = [limit_velocity(plant, load).contraction for load in paper.LOADS_N]
    valve = [limit_velocity(small, load).contraction for load in paper.LOADS_N]
    assert lines == sorted(lines) and max(lines) / min(lines) > 1.1
    assert max(valve) / min(valve) < 1.05 and max(valve) < min(lines)
