"""The vector environment's episodes on MuJoCo Warp: `make_vec(id, num_envs=N, backend="warp")`.

    envs = gymnasium.make_vec("wpam_mj/WPAMTrack-v0", num_envs=8, backend="warp",
                              device="cuda")          # or device="cpu" (Warp's CPU device)

The same episodes as the default backend's `_BatchedEpisodes` (its tables, its array code,
its resets through each environment's own `WPAMEnv.reset`), with the physics of all N
worlds stepped by `wpam_mj.simulation.warp_backend.WarpBatch` on the Warp device instead
of `mujoco.batch`: the muscle is the kernel's physics compiled by Warp (float32), every
world with its own load, parameters and state. Observations, rewards and infos are numpy
arrays on the host (docs/learning.md); on a CUDA device the physics stays on the GPU and
each step moves the commands in and six numbers per world out.
"""

from __future__ import annotations

import copy
import dataclasses

import mujoco
import numpy as np

from wpam_mj.environments.vector_env import DEAD_TIME, _BatchedEpisodes
from wpam_mj.errors import ParameterError
from wpam_mj.simulation import warp_muscle
from wpam_mj.simulation.loop_contract import state_failure
from wpam_mj.simulation.context import RunContext
from wpam_mj.simulation.model import rig_spec
from wpam_mj.simulation.warp_backend import WarpBatch

BACKENDS = ("mujoco", "warp")


def model_fields_per_load(model: mujoco.MjModel) -> list[str]:
    """The model fields a reset may change (the load's mass and what MuJoCo derives from it,
    the slide's damping, the stroke's joint range): those that differ from `model` in a
    copy with another mass, damping and range."""
    other = copy.copy(model)
    other.body_mass[:] = model.body_mass * 2.0 + 1.0
    other.dof_damping[:] = model.dof_damping * 2.0 + 1.0
    other.jnt_range[:] = model.jnt_range * 0.5
    mujoco.mj_setConst(other, mujoco.MjData(other))
    return [name for name in dir(model) if not name.startswith("_")
            and isinstance(getattr(model, name, None), np.ndarray)
            and not np.array_equal(getattr(model, name), getattr(other, name))]


class WarpEpisodes(_BatchedEpisodes):
    """`_BatchedEpisodes` with the physics on a `WarpBatch` (see the module docstring)."""

    def __init__(self, envs, device: str) -> None:
        self.device = device
        super().__init__(envs, nthread=1)

    def _open(self, model: mujoco.MjModel, n: int, nthread: int) -> None:
        env = self.envs[0]
        physics = env.physics
        spec = rig_spec(RunContext(physics.params, physics.timestep(), physics.load()))
        self.per_world = model_fields_per_load(model)
        ranges = env.task.randomize.ranges if env.task.randomize is not None else {}
        dead_time = max(ranges.get(DEAD_TIME, (0.0, 0.0))[1], physics.params.value(DEAD_TIME))
        self.sim = WarpBatch([spec] * n, self.device, per_world=self.per_world,
                             nsub=self.n_sub, delay=round(dead_time / physics.timestep()))
        self.sim.reset()
        host = self.sim.host_view()
        self.ten_length, self.ten_velocity = host["ten_length"], host["ten_velocity"]
        self.plugin_state, self.ctrl = host["state"], host["ctrl"]

    def _load_states(self, ids) -> None:
        """Each world `ids` takes its environment's state just after its reset: MuJoCo's
        integration state, the muscle's state, its parameters and its model's fields."""
        sim = self.sim
        for i in ids:
            physics = self.envs[i].physics
            data = physics.data
            width = data.plugin_state.size
            if physics.rig.muscles is None:  # the plugin: its state, in the same layout
                state = np.asarray(data.plugin_state[physics.rig.state:], dtype=np.float32)
            else:
                state = sim.initial_row(i)
                width = len(state)
            muscle = sim.muscles[i]
            values = warp_muscle.world_values(dataclasses.replace(
                muscle.config, params=physics.params), muscle.length0, sim.dt,
                len(sim.channels))
            sim.load_world(i, data, physics.model, state[:width], values)
        sim.upload()

    def _advance(self, rows, at: np.ndarray) -> dict[int, str]:
        """One control step of every world; those not in `rows` (resetting this step) are
        put back to their environment's reset state. {position in rows: why} for those that
        diverged (the muscle's status, or a non-finite MuJoCo state)."""
        self.sim.step_synced()
        if not isinstance(rows, slice):
            frozen = np.setdiff1d(np.arange(len(self.envs)), at)
            self._load_states(frozen)
            self.sim.step_synced(0)
        failed = self.plugin_state[rows, self.status] != 0
        bad = ~np.isfinite(self.ten_length[rows]).all(axis=1)
        diverged: dict[int, str] = {}
        for j in np.flatnonzero(failed | bad):
            state = self.plugin_state[at[j]].astype(float)
            diverged[int(j)] = state_failure(state) if failed[j] else \
                "MuJoCo Warp's state became non-finite"
        return diverged


def check_backend(backend: str) -> str:
    """A physics backend of the vector environment: "mujoco" (`mujoco.batch`, the default)
    or "warp" (MuJoCo Warp; needs the gpu extra), refused in one line otherwise."""
    if backend not in BACKENDS:
        raise ParameterError(f"backend = {backend!r}; valid: {', '.join(BACKENDS)}")
    if backend == "warp":
        warp_muscle.require_warp()
    return backend

