"""The hung muscle as the environments step it: `MusclePhysics` (dm_control) and
`RigPhysics` (plain MuJoCo, what the Gymnasium environments step).

Both hold a `wpam_mj.simulation.live.LiveRig` and step it with the project's physics step,
so an episode reproduces `wpam_mj.simulation.simulate` driven by the same commands exactly
(tests/test_env.py). Their readings (contraction, velocity, chamber pressures, load) are
what the task observes. `MusclePhysics`, which dm_control renders (`physics.render`),
holds the rig on the rendering scene (models/wpam/scene.xml: a light, a backdrop, the
"front" and "side" cameras; its extra geoms are static and collide with nothing, so the
dynamics are the bare rig's, bit for bit); `RigPhysics` holds the bare rig, 5-10 %
cheaper to step (the Gymnasium environment draws its frames apart,
`wpam_mj.visualisation.scene`).
"""

from __future__ import annotations

import mujoco
from absl import logging

from wpam_mj.paths import MODEL_XML, SCENE_XML
from wpam_mj.physics.params import Params
from wpam_mj.units import STANDARD_GRAVITY
from wpam_mj.simulation import plugin
from wpam_mj.simulation.live import LiveRig
from wpam_mj.simulation.loop_contract import SimulationDiverged
from wpam_mj.simulation.context import RunContext, check_load
from wpam_mj.visualisation import gl

with gl.quiet_display_probe():  # dm_control probes GLFW on import
    from dm_control.mujoco import engine
    from dm_control.mujoco.wrapper import core as wrapper
    from dm_control.rl import control

_WARNING_NAMES = tuple(mujoco.mjtWarning.__members__)




class _MuscleReadings:
    """What the task reads and sets on the hung muscle, for `MusclePhysics` (dm_control)
    and `RigPhysics` (plain MuJoCo) alike: both hold a `LiveRig` and its MjData, whose
    raw structs `_bind` caches (the step path reads them every control step)."""

    params: Params
    rig: LiveRig
    _m: mujoco.MjModel
    _d: mujoco.MjData
    XML = MODEL_XML  # the MJCF the rig is built on

    @classmethod
    def build_rig(cls, params: Params, load: float, dt: float) -> LiveRig:
        """The rig on `XML` for `params`, `load` [N], physics step `dt` [s]."""
        return LiveRig.build(RunContext(params, dt, load), xml=cls.XML)

    def _setup(self, params: Params, rig: LiveRig) -> None:
        self.params = params
        self.rig = rig
        self._load_body = rig.model.body("load").id
        self._load = float(rig.model.body_mass[self._load_body]) * STANDARD_GRAVITY
        self._p_i = rig.state + plugin.FIELD["p_i"]  # plugin state addresses (plugin only)
        self._p_o = rig.state + plugin.FIELD["p_o"]
        self.pi_cmd = self.po_cmd = 0.0
        self.diverged: str | None = None

    def _bind(self, model: mujoco.MjModel, data: mujoco.MjData) -> None:
        self._m, self._d = model, data
        self._warnings = data.warning.number  # a live view of MuJoCo's warning counters

    def set_load(self, load: float) -> None:
        """Hang `load` [N]: the load body's mass becomes load / g, and the constants MuJoCo
        derives from masses (the constraints' inverse weights) follow, so the model is the
        one built for this load whatever load it held before."""
        self._m.body_mass[self._load_body] = check_load(load) / STANDARD_GRAVITY
        mujoco.mj_setConst(self._m, self._d)
        self._load = float(self._m.body_mass[self._load_body]) * STANDARD_GRAVITY

    def load(self) -> float:
        """Hanging load [N]: the load body's mass times g."""
        return self._load

    def set_commands(self, pi_cmd: float, po_cmd: float) -> None:
        """Regulator commands [Pa] (gauge) applied from the next physics step on."""
        self.pi_cmd, self.po_cmd = float(pi_cmd), float(po_cmd)

    def contraction(self) -> float:
        """x [m]."""
        return self.rig.length0 - float(self._d.ten_length[self.rig.tendon])

    def velocity(self) -> float:
        """dx/dt [m/s]."""
        return -float(self._d.ten_velocity[self.rig.tendon])

    def pressures(self) -> tuple[float, float]:
        """Chamber gauge pressures (Pi, Po) [Pa]."""
        if self.rig.muscles is None:
            s, atm = self._d.plugin_state, self.rig.atmosphere
            return float(s[self._p_i]) - atm, float(s[self._p_o]) - atm
        return self.rig.pressures(self._d)

    def _step_rig(self, nstep: int, warnings_raise: bool = True) -> None:
        """`nstep` physics steps (`LiveRig.step`: the physics step of
        `wpam_mj.simulation.simulate`), ending with `mj_step1` so that positions, sensors and
        rendering match the new state (as dm_control's own step). A divergence, or a
        MuJoCo warning raised meanwhile (dm_control's `check_invalid_state`; only logged
        when not `warnings_raise`), raises dm_control's PhysicsError, and from then on the
        physics refuses to step until reset: its state has no meaning."""
        if self.diverged is not None:
            raise control.PhysicsError(f"the muscle diverged ({self.diverged}); call reset() "
                                       "before stepping again")
        d = self._d
        before = self._warnings.tolist()  # counters only rise between resets
        try:
            self.rig.set_commands(d, self.pi_cmd, self.po_cmd)
            try:
                self.rig.step(d, nstep)
            except SimulationDiverged as err:
                raise control.PhysicsError(f"at t = {d.time:.4f} s: {err}") from err
            after = self._warnings.tolist()
            if after != before:
                names = [n for n, a, b in zip(_WARNING_NAMES, after, before) if a > b]
                message = "Physics state is invalid. Warning(s) raised: " + ", ".join(names)
                if warnings_raise:
                    raise control.PhysicsError(message)
                logging.warning(message)
        except control.PhysicsError as err:
            self.diverged = str(err)
            raise


class MusclePhysics(_MuscleReadings, engine.Physics):
    """dm_control Physics of the hung muscle whose `step` is the project's physics step.

    The muscle is the rig's `wpam_mj.muscle` plugin (or the Python engine where it is
    unavailable), stepped by `wpam_mj.simulation.live.LiveRig`: its pneumatic state lives
    in MuJoCo's data, so `reset` and `copy` carry it. Set the regulator commands with
    `set_commands` before stepping; `render` draws the scene's lights and cameras.
    """

    XML = SCENE_XML

    @classmethod
    def create(cls, params: Params, dt: float = 1e-3, load: float = 100.0) -> MusclePhysics:
        """Build the MJCF model for `params`, physics step `dt` [s], `load` [N]."""
        rig = cls.build_rig(params, load, dt)
        physics = cls(wrapper.MjData(mujoco.MjData(rig.model)))
        physics._setup(params, rig)
        return physics

    def _reload_from_data(self, data) -> None:
        super()._reload_from_data(data)
        self._bind(self.model.ptr, self.data.ptr)

    def render(self, height: int = 240, width: int = 320, camera_id: int | str = "front",
               **kwargs):
        """dm_control's `Physics.render`, from the scene's "front" camera unless told
        otherwise (its free camera, -1, frames the whole floor with the rig small in it)."""
        return super().render(height, width, camera_id, **kwargs)

    def time(self) -> float:
        """Episode time [s] (dm_control's, read without its wrappers)."""
        return self._d.time

    def reset(self, keyframe_id=None) -> None:
        """Reset MuJoCo's state, the pneumatics' with it (chambers vented, regulators at 0:
        the muscle's state lives in the MjData)."""
        super().reset(keyframe_id)
        self.pi_cmd = self.po_cmd = 0.0
        self.diverged = None

    def copy(self, share_model: bool = False) -> MusclePhysics:
        """A copy with its own MuJoCo data, the pneumatic state in it."""
        new = super().copy(share_model)
        new._setup(self.params, self.rig)
        new.pi_cmd, new.po_cmd, new.diverged = self.pi_cmd, self.po_cmd, self.diverged
        return new

    def set_params(self, params: Params) -> None:
        """Use `params` from now on (domain randomisation, at the start of an episode): the
        model is rebuilt for them with the same load and time step, from rest."""
        rig = self.build_rig(params, self.load(), self.rig.model.opt.timestep)
        self._reload_from_data(wrapper.MjData(mujoco.MjData(rig.model)))
        self._setup(params, rig)

    def step(self, nstep: int = 1) -> None:
        """Advance `nstep` physics steps of the muscle and the load (`_step_rig`); MuJoCo
        warnings raise dm_control's PhysicsError (logged inside dm_control's
        `suppress_physics_errors`)."""
        self._step_rig(nstep, self._warnings_cause_exception)


class RigPhysics(_MuscleReadings):
    """The same physics as `MusclePhysics` on plain MuJoCo, without dm_control (which
    does not run on mujoco 4): what the Gymnasium environment steps. `model` and `data`
    are the MjModel and MjData; `create`, `reset`, `after_reset`, `set_params` and `step`
    do what dm_control's Physics does in `MusclePhysics`, in the same order (its forward
    computations with actuation disabled included), so both give the same trajectories."""

    @classmethod
    def create(cls, params: Params, dt: float = 1e-3, load: float = 100.0) -> RigPhysics:
        """Build the MJCF model for `params`, physics step `dt` [s], `load` [N]."""
        physics = cls()
        physics._setup(params, cls.build_rig(params, load, dt))
        return physics

    def _setup(self, params: Params, rig: LiveRig) -> None:
        super()._setup(params, rig)
        self.model, self.data = rig.model, mujoco.MjData(rig.model)
        self._bind(self.model, self.data)
        self.after_reset()

    def time(self) -> float:
        """Episode time [s]."""
        return self.data.time

    def timestep(self) -> float:
        """Physics step [s]."""
        return float(self.model.opt.timestep)

    def reset(self) -> None:
        """MuJoCo's state, the pneumatics' with it, back to rest (chambers vented)."""
        mujoco.mj_resetData(self.model, self.data)
        self.after_reset()
        self.pi_cmd = self.po_cmd = 0.0
        self.diverged = None

    def after_reset(self) -> None:
        """The derived quantities of the state, with actuation disabled (dm_control's
        `Physics.after_reset`, also run by its reset and on new data)."""
        flags = self.model.opt.disableflags
        self.model.opt.disableflags = flags | mujoco.mjtDisableBit.mjDSBL_ACTUATION
        try:
            mujoco.mj_forward(self.model, self.data)
        finally:
            self.model.opt.disableflags = flags

    def set_params(self, params: Params) -> None:
        """Use `params` from now on (domain randomisation): a model rebuilt for them with
        the same load and time step, from rest."""
        self._setup(params, self.build_rig(params, self.load(), self.timestep()))

    def step(self, nstep: int = 1) -> None:
        """`nstep` physics steps (`_step_rig`); a MuJoCo warning raised meanwhile raises
        dm_control's PhysicsError, as `MusclePhysics.step`."""
        self._step_rig(nstep)
