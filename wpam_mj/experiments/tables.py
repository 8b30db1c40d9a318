"""Plain-text and Markdown tables of study results, for the terminal and the report."""

from __future__ import annotations

import math

from wpam_mj.display import fmt
from wpam_mj.physics.params import Params, describe
from wpam_mj.units import MM, MPA
from wpam_mj.experiments.responses import StepRun, SweepResult, Table2Result


def mpa_label(po: float) -> str:
    """A pressure [Pa] as its number of MPa, e.g. "0.04" (file names, labels)."""
    return f"{po / MPA:g}"


def fmt_value(v: float | None, spec: str = ".4f") -> str:
    """A table cell; "-" where the value is missing (None or NaN)."""
    return "-" if v is None or (isinstance(v, float) and math.isnan(v)) else fmt(v, spec)


def table2_text(t2: Table2Result) -> str:
    """Our Table 2 beside the paper's, as plain text."""
    ref = t2.paper()
    head = f"{'condition':<34}" + "".join(f"{f'{v:g} N':>20}" for v in t2.loads)
    sub = f"{'':<34}" + "".join(f"{'ours':>10}{'paper':>10}" for _ in t2.loads)
    lines = ["Table 2: hysteresis-loop area / open-loop (Po = 0) area", head, sub]

    def row(name: str, ours: dict, key: str) -> str:
        cells = "".join(f"{ours[v]:>10.4f}{fmt_value(ref[key].get(v)):>10}" for v in t2.loads)
        return f"{name:<34}{cells}"

    lines.append(row("open loop, no Po", {v: 1.0 for v in t2.loads}, "open"))
    lines.append(row(f"open loop, Po = {mpa_label(t2.po_down)} MPa", t2.open_po, "open_po"))
    lines.append(row("feedback control (PI)", t2.feedback, "feedback"))
    lines.append("open-loop (Po = 0) areas [MPa mm]: " + ", ".join(
        f"{o.load:g} N: {o.area_mpa_mm:.4g}" for o in t2.open_loops))
    return "\n".join(lines)


def sweep_text(sw: SweepResult) -> str:
    lines = [f"{'load [N]':>9}{'freq [Hz]':>10}{'ctrl':>6}{'gain':>8}{'lag [deg]':>11}"
             f"{'Po max [MPa]':>14}   (Po: regulator gauge)"]
    for p in sw.points:
        lines.append(f"{p.load:>9g}{p.freq:>10g}{p.controller:>6}{fmt(p.gain, '>8.3f')}"
                     f"{fmt(p.phase_lag_deg, '>11.1f')}{fmt(p.po_max / MPA, '>14.4f')}")
    return "\n".join(lines)


def step_text(run: StepRun) -> str:
    """Plateau means of a staircase run; Pi and Po are the chamber pressures."""
    lines = [f"plateau means over the last {run.settle:g} s ({run.load:g} N, {run.control}):",
             f"{'target [mm]':>12}{'x [mm]':>10}{'error [mm]':>12}{'Pi [MPa]':>10}"
             f"{'Po [MPa]':>10}"]
    for tg, x, pi, po in zip(run.target, run.x_mean, run.pi_mean, run.po_mean):
        lines.append(f"{tg / MM:>12g}{fmt(x / MM, '>10.3f')}{fmt((x - tg) / MM, '>12.3f')}"
                     f"{fmt(pi / MPA, '>10.4f')}{fmt(po / MPA, '>10.4f')}")
    return "\n".join(lines)


def params_markdown(params: Params) -> str:
    lines = ["| parameter | value | unit | source |", "|---|---|---|---|"]
    for name, value, unit, source in describe(params):
        lines.append(f"| `{name}` | {value:.6g} | {unit} | {source} |")
    return "\n".join(lines)

