"""An antagonistic pair of W-PAMs turning a hinge: a model that only reuses the plugin.

`models/arm/arm.xml`: a flexor and an extensor on fixed tendons around one pulley of
radius r (their coefficients), each mounted pre-contracted at x0 (its ``contraction0``),
each running the paper's controller inside the plugin (Pi from eq. 5 at the co-contraction
load, Po from PI on its own contraction error). A target angle theta_r [rad] is the pair of
targets x_flexor = x0 + r theta_r, x_extensor = x0 - r theta_r: both controllers push the
same way, and the feedback on Po of both muscles holds the angle. `step_response` and
`sine_response` run the paper's two protocols on the joint through `mujoco.batch`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np
from mujoco import batch as mjbatch

from wpam_mj.simulation import plugin
from wpam_mj.experiments.analysis import FrequencyPoint, frequency_response
from wpam_mj.errors import ParameterError, check_range
from wpam_mj.paths import MODELS_DIR

ARM_XML = MODELS_DIR / "arm" / "arm.xml"
MUSCLES = ("flexor", "extensor")
STEP_LEVELS_DEG = (0, 5, 10, 5, 0, -5, -10, -5, 0)  # inside the +-14 deg stroke
SETTLED_S = 3.0  # the end of each plateau that counts as settled [s]


@dataclass(frozen=True)
class Pair:
    """The arm model and what maps an angle to the muscles' targets."""

    model: mujoco.MjModel
    radius: float  # pulley radius r [m]
    contraction0: float  # x0 of both muscles [m]

    @classmethod
    def load(cls, xml: str | Path = ARM_XML) -> "Pair":
        spec = mujoco.MjSpec.from_file(str(xml))
        model = spec.compile()
        coefs = {name: float(model.wrap_prm[model.tendon_adr[model.tendon(name).id]])
                 for name in MUSCLES}
        if coefs["flexor"] != -coefs["extensor"] or coefs["flexor"] >= 0.0:
            raise ParameterError(f"{xml}: the flexor's and extensor's tendon coefficients "
                                 f"must be -r and +r, got {coefs}")
        x0 = {p.name: float(p.config.get("contraction0", 0.0)) for p in spec.plugins}
        if x0["flexor"] != x0["extensor"]:
            raise ParameterError(f"{xml}: both muscles must share contraction0, got {x0}")
        return cls(model, -coefs["flexor"], x0["flexor"])

    def targets(self, theta_ref: np.ndarray) -> np.ndarray:
        """(n, 2) ctrl rows: the muscles' target contractions [m] for angles [rad]."""
        theta_ref = np.asarray(theta_ref, dtype=float)
        return np.column_stack([self.contraction0 + self.radius * theta_ref,
                                self.contraction0 - self.radius * theta_ref])


@dataclass(frozen=True)
class ArmRun:
    """A recorded run of the pair: time [s], angle and target [rad], each muscle's chamber
    gauge pressures [Pa], shape (n,) each (pressures (n, 2), flexor first)."""

    time: np.ndarray
    theta: np.ndarray
    theta_ref: np.ndarray
    pi: np.ndarray
    po: np.ndarray

    def csv_text(self) -> str:
        header = ("time_s,theta_deg,theta_ref_deg,flexor_pi_mpa,flexor_po_mpa,"
                  "extensor_pi_mpa,extensor_po_mpa")
        rows = np.column_stack([self.time, np.degrees(self.theta), np.degrees(self.theta_ref),
                                self.pi[:, 0] / 1e6, self.po[:, 0] / 1e6,
                                self.pi[:, 1] / 1e6, self.po[:, 1] / 1e6])
        return header + "\n" + "\n".join(",".join(f"{v:.6g}" for v in r) for r in rows) + "\n"


def run(pair: Pair, theta_ref: np.ndarray, *, record_every: int = 10) -> ArmRun:
    """Step the pair through the targets theta_ref [rad], one per physics step."""
    model = pair.model
    sim = mjbatch.Batch(model, 1, nthread=1)
    sim.reset()
    out = sim.rollout(len(theta_ref), control=pair.targets(theta_ref)[None],
                      record=("qpos", "plugin_state"))
    field = plugin.FIELD
    state = out["plugin_state"][0, ::record_every]
    adr = [plugin.state_address(model, m) for m in MUSCLES]
    if np.any(state[:, [a + field["status"] for a in adr]]):
        raise RuntimeError("the arm's pneumatics diverged; reduce the timestep")
    n = len(state)
    # the state after step k holds the pressures its force used (the start of step k)
    return ArmRun(time=np.arange(n) * record_every * model.opt.timestep,
                  theta=out["qpos"][0, ::record_every, 0], theta_ref=theta_ref[::record_every],
                  pi=state[:, [a + field["pi"] for a in adr]],
                  po=state[:, [a + field["po"] for a in adr]])


@dataclass(frozen=True)
class Plateau:
    """One held target: its angle [deg], the settled mean error and peak-to-peak [deg]."""

    target_deg: float
    error_deg: float
    peak_to_peak_deg: float


def step_response(pair: Pair, *, levels_deg=STEP_LEVELS_DEG,
                  hold: float = 15.0) -> tuple[ArmRun, list[Plateau]]:
    """Angle steps (the paper's staircase on the joint), each held `hold` [s]; the last
    `SETTLED_S` seconds of each plateau give its settled error and peak-to-peak."""
    check_range("hold", hold, SETTLED_S, 600.0, "s")
    per = round(hold / pair.model.opt.timestep)
    theta_ref = np.repeat(np.radians(np.asarray(levels_deg, dtype=float)), per)
    result = run(pair, theta_ref)
    plateaus = []
    for i, level in enumerate(levels_deg):
        window = (result.time >= i * hold + hold - SETTLED_S) & (result.time < (i + 1) * hold)
        theta = np.degrees(result.theta[window])
        plateaus.append(Plateau(float(level), float(theta.mean() - level), float(np.ptp(theta))))
    return result, plateaus


def sine_response(pair: Pair, *, amplitude_deg: float = 10.0, freq: float = 0.1,
                  settle_cycles: int = 1, cycles: int = 2) -> tuple[ArmRun, FrequencyPoint]:
    """theta_r = amplitude sin(2 pi f t), started at rest at 0: gain and lag of the joint."""
    check_range("freq", freq, 0.0, 5.0, "Hz", lo_open=True)
    check_range("amplitude", amplitude_deg, 0.0, 15.0, "deg", lo_open=True)
    dt = pair.model.opt.timestep
    t = np.arange(round((settle_cycles + cycles) / freq / dt)) * dt
    theta_ref = np.radians(amplitude_deg) * np.sin(2.0 * math.pi * freq * t)
    result = run(pair, theta_ref)
    point = frequency_response(result.time, result.theta_ref, result.theta, freq,
                               settle_cycles=settle_cycles, n_cycles=cycles)
    return result, point
