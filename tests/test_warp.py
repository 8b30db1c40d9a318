"""The MuJoCo Warp backend (the gpu extra): refused in one line without it; with it, on
Warp's CPU device, every preset and control mode follows the compiled plugin within the
float32 tolerance docs/warp.md states, sticking and slipping at the same samples, and the
vector environment follows the default backend.

The parity tests need `warp-lang` and `mujoco-warp` (pip install ".[gpu]") and skip without
them, as in CI; on Warp's CPU device a step of a few worlds takes about 20 ms and the
first run compiles Warp's kernels for about a minute (cached under ~/.cache/warp).
WPAM_WARP_DEVICE=cuda runs them on a GPU instead (default: cpu).
"""

from __future__ import annotations

import dataclasses
import os

import gymnasium
import numpy as np
import pytest

import wpam_mj  # noqa: F401 (registers the ids)
from wpam_mj.experiments.drives import drive_for_targets
from wpam_mj.infra.pool import Workers
from wpam_mj.physics.muscle import MuscleModel
from wpam_mj.physics.params import preset
from wpam_mj.errors import ParameterError
from wpam_mj.units import MM
from wpam_mj.simulation import plugin, warp_muscle
from wpam_mj.simulation.execution import SimulationTask, execute
from wpam_mj.simulation.context import RunContext
from wpam_mj.simulation.simulate import Run, simulate_run
from wpam_mj.experiments.warp_parity import (CASES, STUCK_M_S, TOLERANCE, gaps, parity_runs,
                                            within)

DEVICE = os.environ.get("WPAM_WARP_DEVICE", "cpu")  # where the parity tests run

needs_warp = pytest.mark.skipif(not warp_muscle.warp_available(),
                                reason="needs the gpu extra (warp-lang, mujoco-warp)")


def test_warp_backend_refused_in_one_line_without_the_extra(without_warp):
    with pytest.raises(ParameterError) as err:
        gymnasium.make_vec("wpam_mj/WPAMTrack-v0", num_envs=2, backend="warp")
    assert "\n" not in str(err.value)
    assert "pip install 'wpam-mj[gpu]'" in str(err.value)
    with pytest.raises(ParameterError, match=r"wpam-mj\[gpu\]"):
        from wpam_mj.simulation.warp_backend import run_warp
        run_warp([], device="cpu")


def _short_runs(seconds: float = 0.3) -> list[Run]:
    """Two runs of one length and layout, different plants, loads and control modes."""
    dt = 1e-3
    x_ref = np.full(round(seconds / dt), 15 * MM)
    p = preset("wpam")
    return [Run.make(RunContext(p, dt, load, control),
                     drive_for_targets(p, load, x_ref, control, dt))
            for load, control in ((60.0, "pi"), (140.0, "open"))]


def test_execute_on_warp_refused_in_one_line_without_the_extra(without_warp):
    with pytest.raises(ParameterError) as err:
        execute(_short_runs(), backend="warp", device="cpu")
    assert "\n" not in str(err.value) and "pip install 'wpam-mj[gpu]'" in str(err.value)


@pytest.mark.parametrize("kwargs, message", [
    ({"backend": "jax"}, "backend = 'jax'; valid: mujoco, warp"),
    ({"device": "cuda"}, "device = 'cuda' needs backend='warp'"),
    ({"backend": "warp", "device": "cuda",
      "workers": Workers(None, 2, "Dask at tcp://127.0.0.1:8786", remote=True)},
     "backend = 'warp' simulates on this machine's device, not on Dask at tcp://"),
], ids=["unknown-backend", "device-without-warp", "on-a-cluster"])
def test_execute_refuses_a_backend_it_cannot_use_in_one_line(kwargs, message):
    with pytest.raises(ParameterError) as err:
        execute(_short_runs(), **kwargs)
    assert "\n" not in str(err.value) and message in str(err.value)


def test_run_warp_refuses_a_controller_only_python_defines():
    """The Warp kernels are the plugin's: a run whose controller only the Python engine
    defines would silently run another one."""
    from wpam_mj.simulation.warp_backend import run_warp  # noqa: PLC0415 (imports without Warp)

    run = _short_runs()[0]
    run = dataclasses.replace(run, context=dataclasses.replace(run.context, control="mine"))
    with pytest.raises(ParameterError, match="controller 'mine' runs on the Python engine "
                                             "only; backend = 'warp' runs open, pi"):
        run_warp([run])


FAIL_STEP = 20  # a recorded step of _short_runs (a sample every 10 steps)


class _StubBatch:
    """A WarpBatch whose state is known: world w's recorded fields read 1000 w + step, and
    world 1 sets its status at step FAIL_STEP (runs without the gpu extra)."""

    dt = 1e-3

    def __init__(self, specs, device):
        from wpam_mj.simulation.loop_contract import REC_FIELDS  # noqa: PLC0415

        self.wp = type("wp", (), {"synchronize": staticmethod(lambda: None)})
        self.fields = [plugin.FIELD[name] for name in REC_FIELDS[1:]]
        self.values = np.zeros((len(specs), max(plugin.FIELD.values()) + 1), np.float32)
        self.steps = 0

    def reset(self):
        self.steps = 0

    def set_ctrl(self, u):
        pass

    def step(self, k):
        self.steps += k
        step = self.steps - 1
        self.values[:, self.fields] = (1000 * np.arange(len(self.values)) + step)[:, None]
        if step == FAIL_STEP:
            self.values[1, plugin.FIELD["status"]] = 1

    @property
    def state(self):
        return type("arr", (), {"numpy": lambda _: self.values.copy()})()


def test_each_worlds_record_is_its_own_and_stops_where_it_fails(monkeypatch):
    """warp_backend._run_group records every world's samples in one array: each world's
    record holds its own values at every recorded step, and a world that fails keeps its
    record up to its failing step (recorded too) and zeros after, with the step named."""
    from wpam_mj.simulation import warp_backend  # noqa: PLC0415 (imports without Warp)

    monkeypatch.setattr(warp_backend, "WarpBatch", _StubBatch)
    run = _short_runs(0.045)[0]
    (rec0, fail0), (rec1, fail1), (rec2, fail2) = warp_backend._run_group([run] * 3, "cpu")
    steps = np.arange(0, len(run.inputs), run.record_every)
    assert run.record_every == 10 and FAIL_STEP in steps
    assert fail0 is None and fail2 is None and fail1[0] == FAIL_STEP and fail1[1]
    for w, rec in ((0, rec0), (2, rec2)):
        np.testing.assert_array_equal(rec[0], steps * 1e-3)
        np.testing.assert_array_equal(rec[1:], np.broadcast_to(1000 * w + steps,
                                                                rec[1:].shape))
    kept = steps <= FAIL_STEP
    np.testing.assert_array_equal(rec1[1:, kept], np.broadcast_to(1000 + steps[kept],
                                                                  rec1[1:, kept].shape))
    assert not rec1[:, ~kept].any()


@dataclasses.dataclass(frozen=True)
class _Peaks(SimulationTask):
    """A task of runs and a reduction: each run's largest contraction [m]."""

    runs_: tuple

    def runs(self):
        return list(self.runs_)

    def reduce(self, results):
        return [float(np.max(r.x)) for r in results]


@needs_warp
@pytest.mark.skipif(not plugin.available(), reason="compares with the compiled plugin")
def test_execute_on_warp_follows_the_default_backend():
    """Runs and tasks through `execute(backend="warp")` are run_warp's records, which follow
    the plugin's within the float32 tolerance."""
    from wpam_mj.simulation.warp_backend import run_warp  # noqa: PLC0415 (the extra)

    runs = _short_runs()
    jobs = [runs[0], _Peaks(tuple(runs)), runs[1]]
    warp = execute(jobs, backend="warp", device=DEVICE)
    default = execute(jobs)
    alone = run_warp(runs, device=DEVICE)
    for got, same, reference in ((warp[0], alone[0], default[0]),
                                 (warp[2], alone[1], default[2])):
        assert np.array_equal(got.x, same.x) and np.array_equal(got.po, same.po)
        for field, tolerance in TOLERANCE.items():
            gap = np.max(np.abs(getattr(got, field) - getattr(reference, field)))
            assert gap <= tolerance, f"{field}: {gap:g} > {tolerance:g}"
    assert np.ptp(default[0].x) > 5 * MM  # the runs move
    np.testing.assert_allclose(warp[1], default[1], rtol=0, atol=TOLERANCE["x"])


def test_unknown_backend_refused_in_one_line():
    with pytest.raises(ValueError, match="backend = 'jax'; valid: mujoco, warp"):
        gymnasium.make_vec("wpam_mj/WPAMTrack-v0", num_envs=2, backend="jax")


@pytest.fixture(scope="module")
def parity():
    from wpam_mj.simulation.warp_backend import run_warp  # noqa: PLC0415 (the extra)

    runs = parity_runs()
    return [simulate_run(run, "plugin") for run in runs], run_warp(runs, device=DEVICE)


@needs_warp
@pytest.mark.skipif(not plugin.available(), reason="compares with the compiled plugin")
@pytest.mark.parametrize("case", range(len(CASES)), ids=[f"{p}-{c}" for p, c in CASES])
def test_every_preset_and_control_follows_the_plugin_on_warp(parity, case):
    reference, warp = parity[0][case], parity[1][case]
    assert not isinstance(warp, Exception), warp
    assert not within(gaps(reference, warp)), (CASES[case], within(gaps(reference, warp)))
    # long enough to stick and slip (measured: both stick at every sample alike)
    stuck_ref = np.abs(reference.velocity) < STUCK_M_S
    moved = np.abs(reference.velocity) > 1e-3
    assert stuck_ref[np.argmax(moved):].any() and moved.any()


@needs_warp
@pytest.mark.skipif(not plugin.available(), reason="compares with the compiled plugin")
def test_polytropic_chambers_follow_the_plugin_on_warp(parity):
    """pneumatics.polytropic_index reaches Warp's chambers: adiabatic air (1.4) follows the
    plugin within the parity tolerances, and moves Pi further than they allow from the
    isothermal run."""
    from wpam_mj.simulation.warp_backend import run_warp  # noqa: PLC0415 (the extra)

    run = parity_runs(lambda name: preset(name).with_values(
        {"pneumatics.polytropic_index": 1.4}))[CASES.index(("wpam", "pi"))]
    reference, (warp,) = simulate_run(run, "plugin"), run_warp([run], device=DEVICE)
    assert not isinstance(warp, Exception), warp
    assert not within(gaps(reference, warp)), within(gaps(reference, warp))
    isothermal = parity[0][CASES.index(("wpam", "pi"))]
    assert np.max(np.abs(warp.pi - isothermal.pi)) > 100 * TOLERANCE["pi"]


@needs_warp
@pytest.mark.skipif(not plugin.available(), reason="the parity runs include the plugin's")
@pytest.mark.parametrize("name", ["rlam", "mckibben"])
def test_a_muscle_without_an_outer_bag_keeps_po_at_the_atmosphere_on_warp(parity, name):
    """No outer bag, no outer chamber: Po is 0 gauge exactly while the muscle moves, and the
    tension is the closed form at Po = 0 (float32 apart)."""
    run = parity[1][CASES.index((name, "open"))]
    assert np.ptp(run.x) > 5 * MM
    assert np.all(run.po == 0.0), f"Po reached {np.max(np.abs(run.po)):g} Pa"
    model = MuscleModel.from_params(preset(name))
    closed = [model.tendon_force(x, pi, 0.0) for x, pi in zip(run.x, run.pi)]
    np.testing.assert_allclose(run.tension, closed, rtol=0, atol=TOLERANCE["tension"])


@needs_warp
@pytest.mark.skipif(not plugin.available(), reason="compares with the batched plugin")
@pytest.mark.parametrize("env_id", ["wpam_mj/WPAMTrack-v0", "wpam_mj/WPAMTrackResidual-v0",
                                    "wpam_mj/WPAMTrackBoth-v0", "wpam_mj/WPAMTrackSine-v0",
                                    "wpam_mj/WPAMTrackRandomized-v0"])
def test_vector_env_on_warp_follows_the_default_backend(env_id):
    n, steps = 8, 100
    default = gymnasium.make_vec(env_id, num_envs=n)
    warp = gymnasium.make_vec(env_id, num_envs=n, backend="warp", device=DEVICE)
    obs_d, _ = default.reset(seed=3)
    obs_w, _ = warp.reset(seed=3)
    assert np.array_equal(obs_d, obs_w)
    rng = np.random.default_rng(0)
    worst = 0.0
    for _ in range(steps):
        action = rng.uniform(-1, 1, default.action_space.shape).astype(np.float32)
        obs_d, _, term_d, trunc_d, _ = default.step(action)
        obs_w, _, term_w, trunc_w, _ = warp.step(action)
        assert np.array_equal(term_d, term_w) and np.array_equal(trunc_d, trunc_w)
        worst = max(worst, float(np.max(np.abs(obs_d - obs_w))))
    assert worst <= 0.02, f"normalised observations {worst:g} apart"


@needs_warp
def test_every_world_holds_its_own_plant():
    """Worlds of one batch with different loads and parameters each follow their own."""
    from wpam_mj.simulation.warp_backend import run_warp  # noqa: PLC0415 (the extra)

    dt, n = 1e-3, 300
    light, heavy = preset("wpam"), preset("wpam").with_values({"muscle.friction_coeff": 0.05})
    runs = [Run.make(RunContext(p, dt, load, "pi"),
                     drive_for_targets(p, load, np.full(n, 15 * MM), "pi", dt))
            for p, load in ((light, 50.0), (heavy, 150.0))]
    alone = [run_warp([run], device=DEVICE)[0] for run in runs]
    together = run_warp(runs, device=DEVICE)
    for a, b in zip(alone, together):
        assert np.array_equal(a.x, b.x) and np.array_equal(a.po, b.po)
    assert not np.allclose(together[0].x, together[1].x)


def test_many_worlds_need_one_timestep():
    if not warp_muscle.warp_available():
        pytest.skip("needs the gpu extra")
    from wpam_mj.simulation.model import rig_spec  # noqa: PLC0415
    from wpam_mj.simulation.warp_backend import WarpBatch  # noqa: PLC0415

    specs = [rig_spec(RunContext(preset("wpam"), dt, 100.0)) for dt in (1e-3, 5e-4)]
    with pytest.raises(ParameterError, match="one timestep"):
        WarpBatch(specs, "cpu")


@needs_warp
@pytest.mark.skipif(not plugin.available(), reason="compares with the batched plugin")
@pytest.mark.parametrize("host_copies", [False, True], ids=["views", "cuda-path-copies"])
def test_vector_env_on_warp_through_autoresets(monkeypatch, host_copies):
    """Short episodes: autoresets put each world back to its environment's reset state, and
    the host copies a CUDA device needs (forced here on the CPU device) keep the others."""
    from wpam_mj.simulation.warp_backend import WarpBatch  # noqa: PLC0415 (the extra)

    monkeypatch.setattr(WarpBatch, "force_host_copies", host_copies)
    kwargs = {"num_envs": 3, "time_limit": 0.1, "max_episode_steps": 10}
    default = gymnasium.make_vec("wpam_mj/WPAMTrack-v0", **kwargs)
    warp = gymnasium.make_vec("wpam_mj/WPAMTrack-v0", backend="warp", device=DEVICE, **kwargs)
    default.reset(seed=5)
    warp.reset(seed=5)
    action = np.zeros((3, 1), np.float32)
    for k in range(25):
        action[k % 3] = 0.5  # the episodes end together: each world a different action
        obs_d, _, _, trunc_d, _ = default.step(action)
        obs_w, _, _, trunc_w, _ = warp.step(action)
        assert np.array_equal(trunc_d, trunc_w)
        assert np.max(np.abs(obs_d - obs_w)) <= 0.02
