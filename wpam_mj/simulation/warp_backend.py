"""Many worlds of a muscle model on MuJoCo Warp (GPU, or Warp's CPU device), and runs on it.

    batch = WarpBatch([spec_1, spec_2, ...], device="cuda")   # one world per MjSpec
    batch.step(10)                                             # 10 physics steps, every world

Each spec is a model that declares `wpam_mj.muscle` actuators (docs/plugin.md), of one
layout (the same bodies, joints, tendons and channels; any parameters, loads and control
modes): it is compiled for the Python engine (`engine.python_model`: the channels become
plain motors, the muscle's force a motor on its tendon) and the muscle runs as the Warp
kernels of `wpam_mj.simulation.warp_muscle`. MuJoCo Warp keeps every model field that
differs between the worlds' compiled models (the load's mass, the stroke's joint range,
the slide's damping, the inverse weights derived from them) per world. On a CUDA device
`step` replays a captured CUDA graph.

`run_warp(runs)` is `simulate_each` on this backend (`simulate_many(..., backend="warp")`):
one batch per model layout and length, the record as the plugin's, in float32.
"""

from __future__ import annotations

import dataclasses

import mujoco
import numpy as np

from wpam_mj.physics.params import ParameterError
from wpam_mj.simulation import engine
from wpam_mj.simulation import plugin
from wpam_mj.simulation import warp_muscle
from wpam_mj.simulation.loop_contract import REC_FIELDS, REC_ROWS, state_failure

DEVICES = ("cpu", "cuda")


def check_device(device: str) -> str:
    """A Warp device name: "cpu", "cuda" or "cuda:N"; refused in one line otherwise or
    when this machine has no such device."""
    wp, _ = warp_muscle.require_warp()
    if not isinstance(device, str) or device.split(":")[0] not in DEVICES:
        raise ParameterError(f"device = {device!r}; valid: cpu, cuda, cuda:N")
    if device.startswith("cuda") and not wp.is_cuda_available():
        raise ParameterError(f"device = {device!r}: Warp finds no CUDA device here; use "
                             "device='cpu'")
    return device


def _batched_fields(mjw) -> list[str]:
    """The MuJoCo Warp Model fields that may hold one value per world."""
    from mujoco_warp._src import warp_util  # noqa: PLC0415 (the optional extra)

    return [f.name for f in dataclasses.fields(mjw.Model) if warp_util.is_array_spec(f.type)
            and getattr(f.type, "shape", ())[:1] == ("*",)]


class WarpBatch:
    """Worlds of one model layout, each its own MjSpec, stepped together on `device`."""

    def __init__(self, specs: list[mujoco.MjSpec], device: str = "cpu") -> None:
        wp, mjw = warp_muscle.require_warp()
        self.wp, self.mjw = wp, mjw
        self.device = check_device(device)
        built = [engine.python_model(spec) for spec in specs]
        self.models = [model for model, _ in built]
        mjm = self.models[0]
        for model, muscles in built:
            if len(muscles) != 1:
                raise ParameterError(f"backend = 'warp' runs one wpam_mj.muscle instance per "
                                     f"model; this one has {len(muscles)}")
            if (model.nq, model.nv, model.nu, model.ntendon, model.nbody) != (
                    mjm.nq, mjm.nv, mjm.nu, mjm.ntendon, mjm.nbody):
                raise ParameterError("backend = 'warp': every world of a batch needs one model "
                                     "layout (bodies, joints, tendons, channels)")
            if model.opt.timestep != mjm.opt.timestep:
                raise ParameterError("backend = 'warp': every world of a batch needs one "
                                     f"timestep; got {model.opt.timestep:g} and "
                                     f"{mjm.opt.timestep:g} s")
        self.muscles = [muscles[0] for _, muscles in built]
        first = self.muscles[0]
        self.nworld = len(specs)
        self.tendon, self.force_actuator = first.tendon, first.force_actuator
        self.channels = first.channels
        limits = [c or (-np.inf, np.inf) for c in first.ctrl_limits]
        lo, hi = [c[0] for c in limits], [c[1] for c in limits]
        dt = float(mjm.opt.timestep)
        self.dt = dt
        values = [warp_muscle.world_values(m.config, m.length0, dt, len(m.channels))
                  for m in self.muscles]
        self.delay = int(max(v["delay_steps"] for v in values))
        self.width = len(plugin.STATE_FIELDS) + 2 * self.delay
        self._initial = self._initial_state(values)
        with wp.ScopedDevice(self.device):
            self.model = self._put_model(mjm)
            self.data = mjw.make_data(mjm, nworld=self.nworld)
            self.world = warp_muscle.world_struct(values, self.device)
            self.state = wp.array(self._initial, dtype=float)
            self._channels = wp.array(np.array(self.channels, dtype=np.int32), dtype=int)
            self._lo = wp.array(np.array(lo, dtype=np.float32), dtype=float)
            self._hi = wp.array(np.array(hi, dtype=np.float32), dtype=float)
        self.kernels = warp_muscle.kernels()
        self.model.callback.control = self._compute
        self._graphs: dict[int, object] = {}

    def _put_model(self, mjm: mujoco.MjModel):
        """`mujoco_warp.put_model`, with every batched field that differs between the worlds'
        models held per world."""
        differing = {}
        for name in _batched_fields(self.mjw):
            if not hasattr(mjm, name) and not hasattr(mjm.opt, name):
                continue
            values = [np.asarray(getattr(m, name) if hasattr(m, name) else getattr(m.opt, name))
                      for m in self.models]
            if any(v.shape != values[0].shape or not np.array_equal(v, values[0])
                   for v in values[1:]):
                differing[name] = np.stack(values)
        model = self.mjw.put_model(mjm, batch_sizes={n: self.nworld for n in differing})
        for name, stacked in differing.items():
            owner = model.opt if hasattr(model.opt, name) else model
            arr = getattr(owner, name)
            if stacked.size != arr.size * max(1, int(np.prod(arr.dtype._shape_))
                                              if hasattr(arr.dtype, "_shape_") else 1):
                raise ParameterError(f"backend = 'warp': model field {name} differs between "
                                     "worlds in a way MuJoCo Warp cannot hold per world")
            setattr(owner, name, self.wp.array(stacked.reshape(arr.shape + tuple(
                getattr(arr.dtype, "_shape_", ()))), dtype=arr.dtype, device=self.device))
        return model

    def _initial_state(self, values: list[dict[str, float]]) -> np.ndarray:
        """The plugin's state_reset for every world: vented chambers, empty regulators,
        the feedback at its bumpless start."""
        F = plugin.FIELD
        s = np.zeros((self.nworld, self.width), dtype=np.float32)
        s[:, F["x_ref"]] = np.nan
        for name in ("p_i", "p_o"):
            s[:, F[name]] = [v["atmosphere"] for v in values]
        s[:, F["integral"]] = [v["integral0"] for v in values]
        s[:, F["rest_pending"]] = [v["start_at_rest"] for v in values]
        return s

    def _compute(self, m, d) -> None:
        """The control callback: the muscle's compute, every world."""
        self.wp.launch(self.kernels.compute, dim=self.nworld, inputs=[
            self.world, self.state, d.ten_length, d.ten_velocity, d.ctrl, d.nefc, d.efc.type,
            d.efc.id, d.efc.frictionloss, self._channels, self._lo, self._hi, self.tendon,
            self.force_actuator])

    def _step_once(self) -> None:
        self.mjw.step(self.model, self.data)
        self.wp.launch(self.kernels.advance, dim=self.nworld, inputs=[self.world, self.state])

    def step(self, nstep: int = 1) -> None:
        """`nstep` physics steps of every world (on CUDA, a captured graph per nstep)."""
        wp = self.wp
        with wp.ScopedDevice(self.device):
            if not self.device.startswith("cuda"):
                for _ in range(nstep):
                    self._step_once()
                return
            graph = self._graphs.get(nstep)
            if graph is None:
                self._step_once()  # compile and load every kernel before capturing
                with wp.ScopedCapture() as capture:
                    for _ in range(nstep):
                        self._step_once()
                graph = self._graphs[nstep] = capture.graph
                # (the warm-up step above is one step more: callers reset after building)
            wp.capture_launch(graph)

    def reset(self) -> None:
        """Every world at its model's initial state and its muscle at the plugin's reset."""
        with self.wp.ScopedDevice(self.device):
            self.mjw.reset_data(self.model, self.data)
            self.state.assign(self._initial)

    def set_ctrl(self, values: np.ndarray) -> None:
        """The input channels of every world, (nworld, channels)."""
        ctrl = self.data.ctrl.numpy()
        ctrl[:, self.channels] = values
        self.data.ctrl.assign(ctrl)


def run_warp(runs: list, *, device: str = "cpu") -> list:
    """Each run's `SimResult` or the SimulationDiverged it raises, as `simulate_each`, on
    MuJoCo Warp: runs of one model layout and length share a batch (any presets, loads and
    control modes). Records as the plugin does, in float32."""
    out: dict[int, object] = {}
    groups: dict[tuple, list[int]] = {}
    for i, run in enumerate(runs):
        groups.setdefault((len(run.inputs), run.record_every, run.inputs.shape[1], run.dt),
                          []).append(i)
    for ids in groups.values():
        for i, (rec, failure) in zip(ids, _run_group([runs[i] for i in ids], device)):
            try:
                out[i] = runs[i].result(rec, failure)
            except Exception as err:  # SimulationDiverged: returned, as simulate_each does
                out[i] = err
    return [out[i] for i in range(len(runs))]


def _run_group(runs: list, device: str) -> list[tuple[np.ndarray, tuple[int, str] | None]]:
    """Runs of one layout and length on one WarpBatch: (record, failure) per run."""
    batch = WarpBatch([run.spec for run in runs], device)
    wp = batch.wp
    n, every = len(runs[0].inputs), runs[0].record_every
    nrec = (n - 1) // every + 1
    recorded = [plugin.FIELD[name] for name in REC_FIELDS[1:]]
    status = plugin.FIELD["status"]
    recs = [np.zeros((REC_ROWS, nrec)) for _ in runs]
    failures: list[tuple[int, str] | None] = [None] * len(runs)
    inputs = np.stack([run.inputs for run in runs])  # (worlds, steps, channels)
    batch.reset()
    for step in range(n):
        batch.set_ctrl(inputs[:, step])
        batch.step(1)
        state = batch.state.numpy()
        bad = np.flatnonzero(state[:, status] != 0)
        for i in bad:
            if failures[i] is None:
                failures[i] = (step, state_failure(state[i].astype(float)))
        if step % every == 0:
            j = step // every
            for i, rec in enumerate(recs):
                if failures[i] is None or failures[i][0] >= step:
                    rec[0, j] = step * batch.dt
                    rec[1:, j] = state[i, recorded]
    wp.synchronize()
    return list(zip(recs, failures))
