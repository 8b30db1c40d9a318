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

`run_warp(runs)` simulates validated `Run`s on this backend (what `wpam_mj.execute(jobs,
backend="warp", device=...)` runs them with): one batch per model layout and length, the
record as the plugin's, in float32.
"""

from __future__ import annotations

import dataclasses
import sys

import mujoco
import numpy as np

from wpam_mj.errors import ParameterError
from wpam_mj.simulation import engine
from wpam_mj.simulation import plugin
from wpam_mj.simulation import warp_muscle
from wpam_mj.simulation.loop_contract import (REC_FIELDS, REC_ROWS, SimulationDiverged,
                                              state_failure)

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
    """Worlds of one model layout, each its own MjSpec, stepped together on `device`.

    per_world: model fields held per world whether or not they differ now (those a later
    `load_world` changes); nsub: the physics steps of one `step_synced`; delay: room for
    dead-time queues of at least this many steps (a later `load_world` may need more)."""

    force_host_copies = False  # tests: the CUDA path's host copies on the CPU device

    def __init__(self, specs: list[mujoco.MjSpec], device: str = "cpu", *,
                 per_world: tuple[str, ...] | list[str] = (), nsub: int = 1,
                 delay: int = 0) -> None:
        wp, mjw = warp_muscle.require_warp()
        self.wp, self.mjw = wp, mjw
        self.device = check_device(device)
        self.nsub = nsub
        built: dict[int, tuple] = {}  # one compile per distinct spec
        for spec in specs:
            if id(spec) not in built:
                built[id(spec)] = engine.python_model(spec.copy())  # (it edits the spec)
        worlds = [built[id(spec)] for spec in specs]
        self.models = [model for model, _ in worlds]
        mjm = self.models[0]
        for model, muscles in built.values():
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
        self.muscles = [muscles[0] for _, muscles in worlds]
        first = self.muscles[0]
        self.nworld = len(specs)
        self.tendon, self.force_actuator = first.tendon, first.force_actuator
        self.channels = first.channels
        limits = [c or (-np.inf, np.inf) for c in first.ctrl_limits]
        lo, hi = [c[0] for c in limits], [c[1] for c in limits]
        self.dt = float(mjm.opt.timestep)
        cache: dict[int, dict] = {}
        values = [cache.setdefault(id(m), warp_muscle.world_values(
            m.config, m.length0, self.dt, len(m.channels))) for m in self.muscles]
        self.delay = int(max(delay, *(v["delay_steps"] for v in values)))
        self.width = len(plugin.STATE_FIELDS) + 2 * self.delay
        self._initial = self._initial_state(values)
        self.kernels = warp_muscle.kernels()
        with wp.ScopedDevice(self.device):
            self.model = self._put_model(mjm, set(per_world))
            self.data = mjw.make_data(mjm, nworld=self.nworld)
            self.world = warp_muscle.world_struct(values, self.device)
            self.state = wp.array(self._initial, dtype=float)
            self._channels = wp.array(np.array(self.channels, dtype=np.int32), dtype=int)
            self._lo = wp.array(np.array(lo, dtype=np.float32), dtype=float)
            self._hi = wp.array(np.array(hi, dtype=np.float32), dtype=float)
        self.model.callback.control = self._compute
        self._graphs: dict[int, object] = {}
        self._host: dict[str, np.ndarray] = {}
        self._staged: set[str] = set()
        # host mirrors are copies kept in step on CUDA (views on the CPU device, unless a
        # test asks for the CUDA path's copies there)
        self.host_copies = self.device.startswith("cuda") or self.force_host_copies

    def _put_model(self, mjm: mujoco.MjModel, per_world: set[str]):
        """`mujoco_warp.put_model`, with every batched field that differs between the worlds'
        models, or is named in `per_world`, held per world."""
        self.per_world = {}
        distinct = list({id(m): m for m in self.models}.values())  # compared once each
        which = {id(m): k for k, m in enumerate(distinct)}
        index = np.array([which[id(m)] for m in self.models])
        for name in _batched_fields(self.mjw):
            if not hasattr(mjm, name):
                continue
            values = [np.asarray(getattr(m, name)) for m in distinct]
            if name in per_world or any(not np.array_equal(v, values[0]) for v in values[1:]):
                self.per_world[name] = np.stack(values)[index]
        model = self.mjw.put_model(mjm, batch_sizes={n: self.nworld for n in self.per_world})
        for name, stacked in self.per_world.items():
            arr = getattr(model, name)
            shape = arr.shape + tuple(getattr(arr.dtype, "_shape_", ()))
            if stacked.size != int(np.prod(shape)):
                raise ParameterError(f"backend = 'warp': model field {name} differs between "
                                     "worlds in a way MuJoCo Warp cannot hold per world")
            setattr(model, name, self.wp.array(stacked.reshape(shape), dtype=arr.dtype,
                                               device=self.device))
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

    def initial_row(self, i: int) -> np.ndarray:
        """World i's muscle state at reset (the plugin's layout)."""
        return self._initial[i].copy()

    def _compute(self, m, d) -> None:
        """The control callback: the muscle's compute, every world."""
        self.wp.launch(self.kernels.compute, dim=self.nworld, inputs=[
            self.world, self.state, d.ten_length, d.ten_velocity, d.ctrl, d.nefc, d.efc.type,
            d.efc.id, d.efc.frictionloss, self._channels, self._lo, self._hi, self.tendon,
            self.force_actuator])

    def _steps(self, nstep: int, forward: bool) -> None:
        for _ in range(nstep):
            self.mjw.step(self.model, self.data)
            self.wp.launch(self.kernels.advance, dim=self.nworld, inputs=[self.world,
                                                                           self.state])
        if forward:  # positions and velocities of the new state (mj_step1's), for readers
            self.mjw.fwd_position(self.model, self.data, factorize=False)
            self.mjw.fwd_velocity(self.model, self.data)

    def step(self, nstep: int = 1, *, forward: bool = False) -> None:
        """`nstep` physics steps of every world (on CUDA, a captured graph per nstep);
        with `forward`, then the tendon lengths and velocities of the new state."""
        wp = self.wp
        with wp.ScopedDevice(self.device):
            if not self.device.startswith("cuda"):
                self._steps(nstep, forward)
                return
            key = (nstep, forward)
            if key not in self._graphs:
                state = [wp.clone(a) for a in self._state_arrays()]
                self._steps(nstep, forward)  # load every kernel before capturing
                for a, saved in zip(self._state_arrays(), state):
                    wp.copy(a, saved)  # the warm-up leaves no trace
                try:
                    with wp.ScopedCapture() as capture:
                        self._steps(nstep, forward)
                    self._graphs[key] = capture.graph
                except Exception as err:  # noqa: BLE001 (no graphs here: launch each kernel)
                    print(f"wpam_mj: CUDA graph capture failed ({err}); stepping without",
                          file=sys.stderr)
                    self._graphs[key] = None
            if self._graphs[key] is None:
                self._steps(nstep, forward)
            else:
                wp.capture_launch(self._graphs[key])

    def _state_arrays(self) -> list:
        d = self.data
        return [a for a in (d.qpos, d.qvel, d.act, d.time, d.qacc_warmstart, d.ctrl,
                            self.state) if a.size]

    def reset(self) -> None:
        """Every world at its model's initial state and its muscle at the plugin's reset."""
        with self.wp.ScopedDevice(self.device):
            self.mjw.reset_data(self.model, self.data)
            self.state.assign(self._initial)
        for name, host in self._host.items():  # host mirrors follow
            host[...] = self._array(name).numpy()

    def set_ctrl(self, values: np.ndarray) -> None:
        """The input channels of every world, (nworld, channels)."""
        ctrl = self.data.ctrl.numpy()
        ctrl[:, self.channels] = values
        self.data.ctrl.assign(ctrl)

    # ---- host mirrors: numpy views on Warp's CPU device, copies kept in step on CUDA ----

    def _array(self, name: str):
        if name == "state":
            return self.state
        if name.startswith("world."):
            return getattr(self.world, name[6:])
        if name.startswith("model."):
            return getattr(self.model, name[6:])
        return getattr(self.data, name)

    def _mirror(self, name: str) -> np.ndarray:
        if name not in self._host:
            host = self._array(name).numpy()  # a view on the CPU device
            self._host[name] = host.copy() if self.host_copies else host
        return self._host[name]

    def host_view(self) -> dict[str, np.ndarray]:
        """Host arrays of what the vector environment reads and writes: ten_length,
        ten_velocity, time, ctrl and the muscle state, (nworld, ...) each."""
        return {name: self._mirror(name) for name in
                ("ten_length", "ten_velocity", "time", "ctrl", "state")}

    @property
    def time(self) -> np.ndarray:
        """Each world's time [s], on the host (as `mujoco.batch.Batch.time`)."""
        return self._mirror("time")

    def load_world(self, i: int, data: mujoco.MjData, model: mujoco.MjModel,
                   state: np.ndarray, values: dict[str, float]) -> None:
        """World i takes a MuJoCo data's integration state, a muscle state row, a model's
        per-world fields and the muscle's `world_values` (sent by `upload`)."""
        for name in ("qpos", "qvel", "act", "time", "qacc_warmstart"):
            self._stage(name)[i] = getattr(data, name)
        row = self._stage("state")[i]
        row[:] = self._initial[i]
        row[:len(state)] = state
        for name in self.per_world:  # (a plugin model lacks the force motor: its rows first)
            value = np.asarray(getattr(model, name))
            self._stage(f"model.{name}")[i][:len(value)] = value.reshape(
                (len(value), *self._stage(f"model.{name}").shape[2:]))
        for name, value in values.items():
            self._stage(f"world.{name}")[i] = value

    def _stage(self, name: str) -> np.ndarray:
        """The host array of `name` to change rows of; on CUDA fetched first, so that the
        upload leaves the other worlds as the device has them."""
        host = self._mirror(name)
        if name not in self._staged and self.host_copies:
            host[...] = self._array(name).numpy()
        self._staged.add(name)
        return host

    def upload(self) -> None:
        """Send what `load_world` staged to the device (nothing to send on the CPU)."""
        if self.host_copies:
            for name in self._staged:
                self._array(name).assign(self._host[name])
        self._staged.clear()

    def step_synced(self, nstep: int | None = None) -> None:
        """`nsub` (or `nstep`) physics steps with the host's ctrl, then the host mirrors of
        the state the vector environment reads."""
        if self.host_copies:
            self.data.ctrl.assign(self._host["ctrl"])
        self.step(self.nsub if nstep is None else nstep, forward=True)
        if self.host_copies:
            for name in ("ten_length", "ten_velocity", "time", "state"):
                self._host[name][...] = self._array(name).numpy()


def run_warp(runs: list, *, device: str = "cpu") -> list:
    """Each run's `SimResult` or the SimulationDiverged it raises (returned, not raised),
    on MuJoCo Warp: runs of one model layout and length share a batch (any presets, loads
    and the plugin's control modes). Records as the plugin does, in float32."""
    for run in runs:  # the kernels are the plugin's: a Python-only controller would not run
        control = run.context.control
        if control not in plugin.CONTROL_BY_NAME:
            raise ParameterError(f"controller {control!r} runs on the Python engine only; "
                                 f"backend = 'warp' runs {', '.join(plugin.CONTROL_BY_NAME)}")
    warp_muscle.require_warp()
    out: dict[int, object] = {}
    groups: dict[tuple, list[int]] = {}
    for i, run in enumerate(runs):
        key = (len(run.inputs), run.record_every, run.inputs.shape[1], run.context.dt)
        groups.setdefault(key, []).append(i)
    for ids in groups.values():
        for i, (rec, failure) in zip(ids, _run_group([runs[i] for i in ids], device)):
            try:
                out[i] = runs[i].result(rec, failure)
            except SimulationDiverged as err:  # returned, as execute's runs return it
                out[i] = err
    return [out[i] for i in range(len(runs))]


def _run_group(runs: list, device: str) -> list[tuple[np.ndarray, tuple[int, str] | None]]:
    """Runs of one layout and length on one WarpBatch: (record, failure) per run."""
    batch = WarpBatch([run.spec for run in runs], device)
    wp = batch.wp
    n, every = len(runs[0].inputs), runs[0].record_every
    nrec = (n - 1) // every + 1
    first = plugin.FIELD[REC_FIELDS[1]]
    recorded = slice(first, first + REC_ROWS - 1)  # side by side, as simulate reads them
    status = plugin.FIELD["status"]
    # every world's sample j in one contiguous block recs[j], written whole: the host's work
    # per step must not grow with a Python loop over thousands of worlds
    recs = np.zeros((nrec, len(runs), REC_ROWS))
    failures: list[tuple[int, str] | None] = [None] * len(runs)
    alive = np.ones(len(runs), bool)  # no failure yet: a failed world's record stops there
    inputs = np.stack([run.inputs for run in runs], axis=1)  # (steps, worlds, channels)
    batch.reset()
    for step in range(n):
        batch.set_ctrl(inputs[step])
        batch.step(1)
        state = batch.state.numpy()
        if step % every == 0:  # the failing step itself is still recorded
            sample = recs[step // every]
            if alive.all():
                sample[:, 0] = step * batch.dt
                sample[:, 1:] = state[:, recorded]
            else:
                sample[alive, 0] = step * batch.dt
                sample[alive, 1:] = state[alive, recorded]
        for i in np.flatnonzero((state[:, status] != 0) & alive):
            failures[i] = (step, state_failure(state[i].astype(float)))
            alive[i] = False
    wp.synchronize()
    return [(recs[:, i].T, failure) for i, failure in enumerate(failures)]
