"""The linear models (`wpam_mj.design.linear`) beside the simulated frequency response.

For one load and operating contraction, `compare` builds the §3 and extended models for PI
and PID and runs the simulated sweep (`paper_studies.sweep_batch`) at several target amplitudes
(the paper's 25 mm and smaller ones), all in one `execute`. A `LinearComparison` holds
both; `agreement` is the yardstick: at 0.1-0.25 Hz, does the simulated gain lie
within 1 dB and the lag within 10 deg of the model's? Everything is recomputed from the
current parameters, so the numbers follow any change of the physics.

SI inside (m, N, Hz as in `SineSpec`); mm, dB and deg only in `rows`, JSON and text.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Iterable, Mapping, Sequence

import numpy as np

from wpam_mj import paper
from wpam_mj.design import linear
from wpam_mj.infra import files
from wpam_mj.experiments import paper_studies
from wpam_mj.experiments.drives import SINE_AMPLITUDE_MM, SINE_MEAN_MM
from wpam_mj.experiments.feasibility import MOVE_MIN_MM
from wpam_mj.physics.params import Params
from wpam_mj.errors import ParameterError
from wpam_mj.units import MM
from wpam_mj.experiments.responses import SweepResult
from wpam_mj.simulation.execution import execute

SMALL_AMPLITUDE_MM = 5.0  # about the friction band's reach in error at 150 N (docs/linear_model.md)
AMPLITUDES_MM = (SINE_AMPLITUDE_MM, SMALL_AMPLITUDE_MM)  # the paper's, and a small one
AGREEMENT_FREQS_HZ = (0.1, 0.2, 0.25)  # compared with the simulation (docs/linear_model.md)
GAIN_TOL_DB = 1.0
LAG_TOL_DEG = 10.0


def gain_db(gain: float) -> float:
    """20 log10(gain) [dB]; -inf for a zero gain."""
    return 20.0 * math.log10(gain) if gain > 0.0 else -math.inf


@dataclass(frozen=True)
class LinearComparison:
    """Linear models and simulated sweeps at one load [N] about one contraction [m].

    loops: a `linear.LinearLoop` per (model, controller); sweeps: amplitude [m] ->
    `SweepResult` at this load (targets about `SineSpec`'s 25 mm mean).
    """

    load: float
    contraction: float
    loops: tuple[linear.LinearLoop, ...]
    sweeps: Mapping[float, SweepResult]

    @property
    def controllers(self) -> list[str]:
        return list(dict.fromkeys(lp.control for lp in self.loops))

    def loop(self, model: str, control: str) -> linear.LinearLoop:
        for lp in self.loops:
            if lp.model == model and lp.control == control:
                return lp
        raise ParameterError(f"no {model} model for controller {control!r}")

    def rows(self) -> list[dict]:
        """One dict per (amplitude, controller, frequency): the simulated gain [1] and
        lag [deg] beside each model's, and the differences sim - model [dB, deg];
        load_moved: False where the load never moved (the simulated numbers mean nothing)."""
        out = []
        for amp, sw in self.sweeps.items():
            for ctrl in sw.controllers:
                pts = sw.curve(self.load, ctrl)
                freqs = [p.freq for p in pts]
                row0 = [{"load_n": self.load, "amplitude_mm": amp / MM, "controller": ctrl,
                         "freq_hz": p.freq, "load_moved": p.load_moved, "sim_gain": p.gain,
                         "sim_lag_deg": p.phase_lag_deg} for p in pts]
                for model in linear.MODELS:
                    gains, lags = self.loop(model, ctrl).frequency_response(freqs)
                    for r, g, lag in zip(row0, gains, lags):
                        r[f"{model}_gain"] = float(g)
                        r[f"{model}_lag_deg"] = float(lag)
                        r[f"{model}_diff_db"] = gain_db(r["sim_gain"]) - gain_db(float(g))
                        r[f"{model}_diff_deg"] = r["sim_lag_deg"] - float(lag)
                out += row0
        return out

    def agreement(self, amplitude: float, *, model: str = "paper",
                  freqs: Iterable[float] = AGREEMENT_FREQS_HZ) -> dict:
        """Worst |gain difference| [dB] and |lag difference| [deg] between the simulation
        at `amplitude` [m] and `model` over `freqs` [Hz] and every controller, and whether
        both are within GAIN_TOL_DB and LAG_TOL_DEG (an unstable model's G_yr(jw) is still
        compared, but no steady sinusoid follows it: see `model_stable`). Points whose load
        never moved are left out (counted in `still_points`); with none left the worst
        figures are NaN and nothing agrees."""
        freqs = set(freqs)
        rows = [r for r in self.rows() if math.isclose(r["amplitude_mm"], amplitude / MM)
                and r["freq_hz"] in freqs]
        if not rows:
            raise ParameterError(f"no simulated points at {amplitude / MM:g} mm and "
                                 f"{sorted(freqs)} Hz")
        moved = [r for r in rows if r["load_moved"]]
        db = max((abs(r[f"{model}_diff_db"]) for r in moved), default=math.nan)
        deg = max((abs(r[f"{model}_diff_deg"]) for r in moved), default=math.nan)
        return {"amplitude_mm": amplitude / MM, "model": model,
                "model_stable": all(lp.stable for lp in self.loops if lp.model == model),
                "worst_gain_db": db, "worst_lag_deg": deg,
                "still_points": len(rows) - len(moved),
                "agrees": bool(moved) and db <= GAIN_TOL_DB and deg <= LAG_TOL_DEG}

    def as_json(self) -> dict:
        """Plain JSON types (non-finite numbers become None)."""
        return _finite({"load_n": self.load, "contraction_mm": self.contraction / MM,
                        "operating_point": self.loops[0].op.as_json(),
                        "models": [lp.as_json() for lp in self.loops],
                        "comparison": self.rows(),
                        "agreement": [self.agreement(a, model=m) for a in self.sweeps
                                      for m in linear.MODELS],
                        "tolerance": {"gain_db": GAIN_TOL_DB, "lag_deg": LAG_TOL_DEG,
                                      "freqs_hz": list(AGREEMENT_FREQS_HZ)}})

    def csv_text(self) -> str:
        """`rows` as CSV, one header line."""
        return files.csv_text(self.rows())

    def text(self) -> str:
        """Operating point, poles, margins, DC gains, and the comparison table."""
        op = self.loops[0].op
        lines = [f"operating point: {self.load:g} N at x = {self.contraction / MM:g} mm: "
                 f"Pi = {op.pi / 1e6:.4f} MPa, Po = {op.po / 1e6:.4f} MPa, m = {op.mass:.3f} kg,"
                 f" c = {op.damping:.4g} N s/m, A_o = {op.po_area:.4g} m^2, "
                 f"k = {op.stiffness:.4g} N/m"]
        for lp in self.loops:
            mg = lp.margins()
            g_yr0, g_yd0 = lp.dc_gains()
            poles = ", ".join(_complex(p) for p in lp.poles())
            lines += [f"{lp.model} model, {lp.control.upper()}: "
                      f"{'stable' if lp.stable else 'UNSTABLE'}; G_yr(0) = {g_yr0:.6g}, "
                      f"G_yd(0) = {g_yd0:.3g} m/N; gain margin "
                      f"{_margin(mg['gain_margin'], '', mg['phase_crossover_hz'])}, "
                      f"phase margin "
                      f"{_margin(mg['phase_margin_deg'], ' deg', mg['gain_crossover_hz'])}",
                      f"  poles [rad/s]: {poles}"]
        lines.append(f"{'amp [mm]':>9}{'ctrl':>5}{'f [Hz]':>7}{'sim gain':>9}{'lag':>7}"
                     f"{'§3 gain':>9}{'lag':>7}{'ext gain':>9}{'lag':>7}{'dB':>7}{'deg':>7}")
        for r in self.rows():
            head = f"{r['amplitude_mm']:>9g}{r['controller']:>5}{r['freq_hz']:>7g}"
            models = (f"{r['paper_gain']:>9.3f}{r['paper_lag_deg']:>7.1f}"
                      f"{r['extended_gain']:>9.3f}{r['extended_lag_deg']:>7.1f}")
            if r["load_moved"]:
                lines.append(f"{head}{r['sim_gain']:>9.3f}{r['sim_lag_deg']:>7.1f}{models}"
                             f"{r['paper_diff_db']:>7.2f}{r['paper_diff_deg']:>7.1f}")
            else:
                lines.append(f"{head}{'still':>9}{'-':>7}{models}{'-':>7}{'-':>7}")
        lines.append("dB, deg: simulation minus the §3 model; still: the load never moved "
                     f"(x spanned < {MOVE_MIN_MM:g} mm over the analysed cycles)")
        freqs = ", ".join(f"{f:g}" for f in AGREEMENT_FREQS_HZ)
        for a in self.sweeps:
            ag = self.agreement(a)
            still = f"; {ag['still_points']} still point(s) left out" \
                if ag["still_points"] else ""
            if math.isnan(ag["worst_gain_db"]):
                lines.append(f"at {a / MM:g} mm, {freqs} Hz: the load never moved: nothing "
                             "to compare with the §3 model")
                continue
            lines.append(f"at {a / MM:g} mm, {freqs} Hz: worst {ag['worst_gain_db']:.2f} dB, "
                         f"{ag['worst_lag_deg']:.1f} deg from the §3 model: "
                         f"{'agree' if ag['agrees'] else 'differ'} "
                         f"(within {GAIN_TOL_DB:g} dB and {LAG_TOL_DEG:g} deg){still}")
        return "\n".join(lines)

    def still_points(self) -> list[str]:
        """The simulated points whose load never moved, one entry per amplitude and
        controller, as "150 N 0.5 mm pi at 0.1, 0.2 Hz"."""
        still: dict[tuple[float, str], list[float]] = {}
        for r in self.rows():
            if not r["load_moved"]:
                still.setdefault((r["amplitude_mm"], r["controller"]), []).append(r["freq_hz"])
        return [f"{self.load:g} N {amp:g} mm {ctrl} at {', '.join(f'{f:g}' for f in freqs)} Hz"
                for (amp, ctrl), freqs in still.items()]

    def plot(self):
        """Bode plot of G_yr (`control.bode_plot`) with the simulated points."""
        from wpam_mj.design.linear_figures import comparison_figure  # noqa: PLC0415 (matplotlib)
        return comparison_figure(self)


def _finite(obj):
    """`obj` with numpy scalars as Python numbers and inf/NaN as None, recursively."""
    if isinstance(obj, dict):
        return {k: _finite(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_finite(v) for v in obj]
    if isinstance(obj, (float, np.floating)):
        return float(obj) if math.isfinite(obj) else None
    if isinstance(obj, np.bool_):
        return bool(obj)
    return obj


def _margin(value: float, unit: str, freq_hz: float) -> str:
    if not math.isfinite(value):
        return "inf (no crossover)"
    return f"{value:.3g}{unit} at {freq_hz:.3g} Hz"


def _complex(p: complex) -> str:
    return f"{p.real:.4g}" if p.imag == 0.0 else f"{p.real:.4g}{p.imag:+.4g}j"


def compare(params: Params, loads: Sequence[float], *, contraction: float = SINE_MEAN_MM * MM,
            amplitudes: Sequence[float] = tuple(a * MM for a in AMPLITUDES_MM),
            freqs: Sequence[float] = paper.SWEEP_FREQS_HZ,
            controllers: Sequence[str] = linear.CONTROLLERS, dt: float = 1e-3, jobs: int = 1,
            progress: bool = False) -> list[LinearComparison]:
    """A `LinearComparison` per load [N]: models at `contraction` [m], sweeps at each
    amplitude [m] (every run in one `execute`)."""
    controllers = tuple(linear.check_linear_control(c) for c in controllers)
    if not amplitudes:
        raise ParameterError("no amplitudes given")
    loops = {load: tuple(linear.linear_loop(params, load, contraction, c, m)
                         for m in linear.MODELS for c in controllers) for load in loads}
    keys = [(load, a) for load in loads for a in amplitudes]
    batches = [paper_studies.sweep_batch(params, (load,), freqs, controllers, keep=(), dt=dt,
                                   amplitude=a) for load, a in keys]
    results = dict(zip(keys, execute(batches, jobs, progress=progress, desc="linear vs sim")))
    return [LinearComparison(load, contraction, loops[load],
                             {a: results[(load, a)] for a in amplitudes}) for load in loads]


def amplitude_scan(comparisons: Sequence[LinearComparison]) -> list[dict]:
    """`agreement` with the §3 model for every load and amplitude (docs table)."""
    return [{"load_n": c.load, **c.agreement(a)} for c in comparisons for a in c.sweeps]
