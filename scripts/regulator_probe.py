"""Probe: the regulators as devices instead of ideal pressure sources (issue: what sets the
limit velocity). Not a model of the engines: it swaps the chambers' flow law of the Python
engine for this run only, to measure what the change would do before it is written into
`wpam_mj.physics.kernel` (the one definition) and the plant searched anew.

The shipped regulator is an ideal source at its set point p_set behind the line (ISO 6358
conductance C): the flow is driven by p_set - p. An SMC ITV-class regulator is a device:
its internal loop compares its output pressure with the set point and opens a supply valve
(from the supply, e.g. 0.6 MPa gauge shop air) or an exhaust valve (to atmosphere) in
proportion to the error, fully open beyond `band`. Here the line's C stands for valve and
line in series and the regulator senses the chamber pressure:

    m_dot = min(|p_set - p| / band, 1) C rho_0 p_up psi(p_down / p_up),
    p_up, p_down = (p_supply, p) when p < p_set, else (p, p_atm).

    WPAM_MJ_NO_COMPILE=1 python scripts/regulator_probe.py [--supply MPA] [--band KPA]
        [--line-scale K] [--controllers pi,pid]

prints the fastest contraction/extension per load under Po switched cap <-> floor
(`wpam_mj.experiments.limit_velocity`) and the PI sweep's gains, lags and their spreads
across loads at 0.1/0.25/0.5/1 Hz. `--band 0` runs the shipped regulator (the baseline).
"""

from __future__ import annotations

import argparse
import os

from wpam_mj import paper
from wpam_mj.experiments.limit_velocity import limit_velocity
from wpam_mj.experiments.paper_studies import sweep
from wpam_mj.physics import kernel
from wpam_mj.physics.params import preset
from wpam_mj.units import MM, MPA

ATMOSPHERE = 101325.0  # Pa


def device_chamber_step(supply_abs: float, band: float, line_scale: float):
    """kernel.chamber_step's signature with the device regulator's flow (module doc)."""
    def step(chamber_abs, source_abs, volume, dvdx, v, conductance, critical_ratio, dt):
        error = source_abs - chamber_abs
        opening = min(abs(error) / band, 1.0)
        up = supply_abs if error > 0.0 else ATMOSPHERE
        m = opening * kernel.mass_flow(up, chamber_abs, conductance * line_scale,
                                       critical_ratio)
        return chamber_abs + dt * (kernel.RT0 * m - chamber_abs * dvdx * v) / volume
    return step


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--supply", type=float, default=0.6, help="supply [MPa gauge]")
    ap.add_argument("--band", type=float, default=2.0,
                    help="error at full valve opening [kPa]; 0: the shipped regulator")
    ap.add_argument("--line-scale", type=float, default=1.0,
                    help="factor on both lines' conductances")
    ap.add_argument("--controllers", default="pi", help="comma-separated (default: pi)")
    args = ap.parse_args()
    if os.environ.get("WPAM_MJ_NO_COMPILE") != "1":
        raise SystemExit("run with WPAM_MJ_NO_COMPILE=1: the probe swaps the Python "
                         "engine's flow law; the compiled plugin would not see it")
    if args.band > 0.0:
        kernel.chamber_step = device_chamber_step(args.supply * MPA + ATMOSPHERE,
                                                  args.band * 1e3, args.line_scale)
    params = preset("wpam")
    print("fastest contraction/extension [mm/s] under Po cap <-> floor:")
    for load in paper.LOADS_N:
        lv = limit_velocity(params, load)
        print(f"  {load:g} N: {lv.contraction / MM:.0f} / {lv.extension / MM:.0f}")
    controllers = args.controllers.split(",")
    sw = sweep(params, freqs=(0.1, 0.25, 0.5, 1.0), controllers=controllers)
    for c in controllers:
        for f in sw.freqs:
            pts = [sw.point(load, f, c) for load in sw.loads]
            g = [p.gain for p in pts]
            lag = [p.phase_lag_deg for p in pts]
            print(f"  {c} {f:4.2f} Hz gains " + "/".join(f"{x:.3f}" for x in g)
                  + f" ({max(g) / min(g) - 1:.1%} apart), lags "
                  + "/".join(f"{x:.1f}" for x in lag) + f" ({max(lag) - min(lag):.1f} deg)")


if __name__ == "__main__":
    main()
