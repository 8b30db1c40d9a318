"""The response objects of the paper's studies (beside `wpam_mj.simulation.results.SimResult`, the
time series of one run): static loops, staircase runs, Table 2 and the frequency sweep.

SI inside (m, Pa, N, s; frequency in Hz); loop areas in Pa m (the normalized Table 2
values are unit-free). No plotting here: the `.plot()` methods call `wpam_mj.experiments.figures`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Mapping

import numpy as np

from wpam_mj.experiments.analysis import loop_area
from wpam_mj.experiments.feasibility import load_moved
from wpam_mj.paper import (PO_DOWN_STATIC_MPA, SINE_AMPLITUDE_MM, STEP_HOLD_S, TABLE2,
                           TABLE2_SOURCE)
from wpam_mj.units import MM, MPA
from wpam_mj.simulation.context import InContext, RunContext, StudyContext
from wpam_mj.simulation.results import SimResult

LOOP_METHOD = "branches"  # one loop-area method for every Table 2 cell
# When a staircase plateau has landed (`StepRun.landings`): from then on the muscle moves
# slower than the crawl the integral drives at errors below 10 mm (Ki/Kp |e| = 0.08 mm/s
# per mm with the paper's gains) and both chambers sit at their commands, to a fifth of
# what an ITV regulator resolves (its sensitivity, 0.2 % of 0.5 MPa = 1 kPa).
LANDED_SPEED = 1e-3  # m/s
LANDED_PRESSURE = 200.0  # Pa


def load_key(load: float) -> str:
    """JSON/CSV key of a load [N]: "50", "100", "112.5"."""
    return f"{load:g}"


@dataclass(frozen=True)
class StaticLoop(InContext):
    """One open-loop Pi ramp up then down (paper Figs. 3, 8, 9).

    po_down: Po while Pi falls [Pa]; area: loop area of the measured (Pi, x) trace
    [Pa m]; result: the run, whose context gives the load [N] and the muscle type.
    """

    po_down: float
    area: float
    result: SimResult

    @property
    def context(self) -> RunContext:
        return self.result.context

    @property
    def area_mpa_mm(self) -> float:
        return self.area / (MPA * MM)

    def plot(self):
        """x against Pi with direction arrows (`wpam_mj.experiments.figures.static_figure`)."""
        from wpam_mj.experiments import figures  # noqa: PLC0415 (matplotlib only when plotting)
        return figures.static_figure([self])


@dataclass(frozen=True)
class StepRun(InContext):
    """A staircase run (paper Figs. 12-15) and its settled plateau means (Fig. 16).

    Plateau arrays have shape (n_plateaus,), averaged over the last `settle` seconds of
    each plateau: target [m], x [m], measured chamber Pi and Po [Pa]; result: the run,
    whose context gives the load [N], the controller and the muscle type.
    """

    settle: float
    target: np.ndarray
    x_mean: np.ndarray
    pi_mean: np.ndarray
    po_mean: np.ndarray
    result: SimResult

    @property
    def context(self) -> RunContext:
        return self.result.context

    @property
    def area(self) -> float:
        """Loop area of the plateau means (Pi, x), up branch then down branch [Pa m]."""
        return loop_area(self.pi_mean, self.x_mean, method=LOOP_METHOD)

    @property
    def error(self) -> np.ndarray:
        """Settled error x - target per plateau [m]."""
        return self.x_mean - self.target

    def _settled(self, settle: float) -> np.ndarray:
        r = self.result
        return (r.time % STEP_HOLD_S) >= STEP_HOLD_S - settle

    def _late(self, settle: float) -> list[np.ndarray]:
        """Each plateau's mask of its last `settle` s."""
        r = self.result
        plateau = (r.time // STEP_HOLD_S).astype(int)
        late = self._settled(settle)
        return [late & (plateau == k) for k in np.unique(plateau)]

    def worst_error(self, settle: float = 3.0) -> float:
        """Largest steady-state error of any plateau [m]: |mean of x - x_r| over its last
        `settle` s. Fig. 16 "plots the average of each steady-state response", and Table
        2's feedback cell is the loop of those averages; how still a plateau stays is
        `worst_peak_to_peak`'s."""
        r = self.result
        return max(abs(float(np.mean((r.x - r.x_ref)[m]))) for m in self._late(settle))

    def landings(self, settle: float = 3.0) -> tuple[np.ndarray, np.ndarray]:
        """Per plateau, the time into it [s] from which the muscle has landed before the
        last `settle` s begin (slower than `LANDED_SPEED`, both chambers within
        `LANDED_PRESSURE` of their commands, until then) and its error x - x_r at that time
        [m]; nan for a plateau not landed by then."""
        r = self.result
        phase = r.time % STEP_HOLD_S
        plateau = (r.time // STEP_HOLD_S).astype(int)
        moving = ((np.abs(r.velocity) >= LANDED_SPEED)
                  | (np.abs(r.pi - r.pi_cmd) >= LANDED_PRESSURE)
                  | (np.abs(r.po - r.po_cmd) >= LANDED_PRESSURE))
        ks = np.unique(plateau)
        time, error = np.full(len(ks), math.nan), np.full(len(ks), math.nan)
        for j, k in enumerate(ks):
            idx = np.nonzero((plateau == k) & (phase < STEP_HOLD_S - settle))[0]
            still = idx[np.cumsum(moving[idx][::-1])[::-1] == 0]  # no motion from here on
            if len(still):
                time[j], error[j] = phase[still[0]], r.x[still[0]] - r.x_ref[still[0]]
        return time, error

    def landing_floor(self, settle: float = 3.0) -> np.ndarray:
        """Per plateau, the least steady-state error (`worst_error`'s, the mean |x - x_r|
        over the last `settle` s) [m] any quasi-static plant can have, from where it
        landed (`landings`), under the PI.

        Landed, x follows Po's history with g = -dx/dPo >= 0 (Po only extends); any friction
        law, stiction, pre-sliding or creep, only sets g. With Po = Kp e + Ki int(e) dt on the
        plateau, de/dt = -g (Kp de/dt + Ki e), so de/dt = -e g Ki / (1 + g Kp): the error
        keeps its sign and falls no faster than exp(-t Ki/Kp), Kp/Ki = 12.5 s with the
        paper's gains in any unit reading; its mean over the last `settle` s is then at
        least its value when they begin times (1 - exp(-r settle)) / (r settle), r = Ki/Kp.
        nan for a plateau not landed, for other controllers and for Kp = 0 (a pure integral
        has no such bound).
        """
        c = self.context
        if c.control != "pi" or c.params.controller.kp <= 0.0:
            return np.full(len(self.target), math.nan)
        time, error = self.landings(settle)
        rate = c.params.controller.ki / c.params.controller.kp
        spread = settle * rate
        mean_share = -math.expm1(-spread) / spread if spread > 0.0 else 1.0
        return np.abs(error) * np.exp(-(STEP_HOLD_S - settle - time) * rate) * mean_share

    def worst_peak_to_peak(self, settle: float = 3.0) -> float:
        """Largest x peak-to-peak over the last `settle` s of any plateau [m]."""
        return max(float(np.ptp(self.result.x[m])) for m in self._late(settle))

    def plot(self):
        """Figure of x, target, Pi and Po against time
        (`wpam_mj.experiments.figures.step_figure`)."""
        from wpam_mj.experiments import figures  # noqa: PLC0415 (matplotlib only when plotting)
        return figures.step_figure([self.result])


@dataclass(frozen=True)
class Table2Result:
    """Hysteresis-loop areas behind the paper's Table 2, per load.

    open_loops: open loop, Po = 0 (Fig. 8); po_loops: open loop, Po = `po_down` while Pi
    falls (Fig. 9); feedback_runs: PI staircase runs (Figs. 14-16); context: the
    parameters and dt of every run. Normalized values divide each area by the open-loop,
    Po = 0 area of the same load.
    """

    loads: tuple[float, ...]
    po_down: float
    open_loops: tuple[StaticLoop, ...]
    po_loops: tuple[StaticLoop, ...]
    feedback_runs: tuple[StepRun, ...]
    context: StudyContext

    @property
    def open_po(self) -> dict[float, float]:
        return {o.load: p.area / o.area for o, p in zip(self.open_loops, self.po_loops)}

    @property
    def feedback(self) -> dict[float, float]:
        return {o.load: f.area / o.area for o, f in zip(self.open_loops, self.feedback_runs)}

    @property
    def load_moved(self) -> dict[float, bool]:
        """Per load: whether the load moved in all three runs (else its ratios mean
        nothing; `feasibility.load_moved`)."""
        return {o.load: all(load_moved(r.result) for r in (o, p, f))
                for o, p, f in zip(self.open_loops, self.po_loops, self.feedback_runs)}

    def paper(self) -> dict[str, dict[float, float]]:
        """The paper's rows for the loads of this study that the paper has."""
        return {row: {load: v[load] for load in self.loads if load in v}
                for row, v in TABLE2.items()}

    def as_json(self) -> dict:
        """{"open_po": {"50": a, ...}, "feedback": {...}, "load_moved": {"50": true, ...},
        "paper": {...}}."""
        paper: dict = {row: {load_key(k): v for k, v in vals.items()}
                       for row, vals in self.paper().items()}
        paper["po_down_mpa"] = PO_DOWN_STATIC_MPA
        paper["source"] = TABLE2_SOURCE
        return {"open_po": {load_key(k): v for k, v in self.open_po.items()},
                "feedback": {load_key(k): v for k, v in self.feedback.items()},
                "load_moved": {load_key(k): v for k, v in self.load_moved.items()},
                "paper": paper}

    def plot(self):
        """Bar chart of the normalized areas beside the paper's (`figures.table2_figure`)."""
        from wpam_mj.experiments import figures  # noqa: PLC0415 (matplotlib only when plotting)
        return figures.table2_figure(self)

    def rows(self) -> list[dict]:
        """One dict per load: raw areas [MPa mm] and normalized values, ours and paper's."""
        paper = self.paper()
        out = []
        for o, p, f in zip(self.open_loops, self.po_loops, self.feedback_runs):
            out.append({
                "load_n": o.load,
                "open_area_mpa_mm": o.area_mpa_mm,
                "open_po_area_mpa_mm": p.area_mpa_mm,
                "feedback_area_mpa_mm": f.area / (MPA * MM),
                "open_po": p.area / o.area,
                "feedback": f.area / o.area,
                "paper_open_po": paper["open_po"].get(o.load, math.nan),
                "paper_feedback": paper["feedback"].get(o.load, math.nan),
                "load_moved": self.load_moved[o.load],
            })
        return out


@dataclass(frozen=True)
class SweepPoint:
    """Response to a sinusoidal target at one (load, frequency, controller).

    load [N]; freq [Hz]; gain [1]; phase_lag_deg [deg], positive = lag; po_max: highest
    Po read by the regulator's own gauge over the analysed cycles [Pa] (what the paper
    plots, §2.3); po_chamber_max: highest Po inside the outer chamber, behind the line
    restriction [Pa]; po_cmd_max: highest Po command (capped at po_cap) [Pa]; load_moved:
    whether x spanned `feasibility.MOVE_MIN_MM` over the analysed cycles (else the gain
    and lag mean nothing).
    """

    load: float
    freq: float
    controller: str
    gain: float
    phase_lag_deg: float
    po_max: float
    po_chamber_max: float = float("nan")
    po_cmd_max: float = float("nan")
    load_moved: bool = True

    def as_json(self) -> dict:
        return {"load_n": self.load, "freq_hz": self.freq, "controller": self.controller,
                "gain": self.gain, "phase_lag_deg": self.phase_lag_deg,
                "po_max_mpa": self.po_max / MPA, "load_moved": self.load_moved}


SweepKey = tuple[float, float, str]  # (load [N], freq [Hz], controller)


@dataclass(frozen=True)
class SweepResult:
    """Points in (load, freq, controller) loop order; context: the parameters (the Po
    cap the findings and figures read among them) and dt of every run; `series` holds the
    kept runs; amplitude: of the sinusoidal target [m]."""

    points: tuple[SweepPoint, ...]
    context: StudyContext
    series: Mapping[SweepKey, SimResult] = field(default_factory=dict)
    amplitude: float = SINE_AMPLITUDE_MM * MM

    def as_json(self) -> list[dict]:
        return [p.as_json() for p in self.points]

    def point(self, load: float, freq: float, controller: str) -> SweepPoint | None:
        for p in self.points:
            if p.load == load and p.freq == freq and p.controller == controller:
                return p
        return None

    def curve(self, load: float, controller: str) -> list[SweepPoint]:
        """The points of one (load, controller), by increasing frequency."""
        return sorted((p for p in self.points if p.load == load and
                       p.controller == controller), key=lambda p: p.freq)

    def plot(self):
        """Gain and phase lag against frequency (`wpam_mj.experiments.figures.sweep_figure`)."""
        from wpam_mj.experiments import figures  # noqa: PLC0415 (matplotlib only when plotting)
        return figures.sweep_figure(self)

    @property
    def loads(self) -> list[float]:
        return sorted({p.load for p in self.points})

    @property
    def freqs(self) -> list[float]:
        return sorted({p.freq for p in self.points})

    @property
    def controllers(self) -> list[str]:
        return list(dict.fromkeys(p.controller for p in self.points))
