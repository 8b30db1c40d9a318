"""The muscle as a native MuJoCo actuator plugin, ``wpam_mj.muscle``: build, load, layout.

The plugin's C (`SOURCES`, sharing `HEADERS`) is compiled at first use against the
installed mujoco wheel (its ``include/`` and ``libmujoco.so.<version>``), cached per user
in ``$XDG_CACHE_HOME/wpam_mj`` (default ``~/.cache/wpam_mj``) under a name that hashes the
C sources, the generated tables, the compiler flags and the MuJoCo version, and registered
with ``mujoco.mj_loadPluginLibrary``. `load()` does this once per process; `import
wpam_mj` calls it, so any MJCF that names the plugin compiles after the import.

Nothing is copied by hand between Python and C: `tables_header()` writes every parameter
(``section.field`` names, units, ranges, each preset's values) from `wpam_mj.physics.params`,
the rule table of `wpam_mj.physics.rules` (the instance's numbers, the derived quantities,
the rules between quantities), the state layout `STATE_FIELDS` and its status bits, the
control modes `CONTROLS` as C
tables (floats as exact hex literals), and the muscle's physics, `wpam_mj.physics.kernel`,
as C (`wpam_mj.physics.kernel_codegen.c_source`); the library reports the hash of it all,
which must match, so a change of the kernel rebuilds the plugin.

Set ``WPAM_MJ_NO_COMPILE=1`` to skip the build (`available()` is then False and the Python
engine runs).
"""

from __future__ import annotations

import hashlib
import os
import shutil
from dataclasses import dataclass
from pathlib import Path

import mujoco

from wpam_mj.physics import kernel_codegen
from wpam_mj.physics import params as prm
from wpam_mj.physics import rules
from wpam_mj.units import MPA

NAME = "wpam_mj.muscle"
# The plugin's C: the files compiled, and the header they share, which says what each
# holds. Every one of them enters the cached library's name (`plugin_build.library_path`).
SOURCES = tuple(Path(__file__).with_name(name)
                for name in ("muscle_plugin.c", "muscle_config.c", "muscle_handles.c"))
HEADERS = (Path(__file__).with_name("muscle_plugin.h"),)
MUJOCO_DIR = Path(mujoco.__file__).resolve().parent
# -ffp-contract=off: no FMA contraction; no -ffast-math: IEEE order of operations kept.
# Both make the plugin bit-identical to the Python engine's floats.
CFLAGS = ("-O2", "-fPIC", "-shared", "-std=c11", "-ffp-contract=off", "-fno-fast-math")

# The plugin state of one instance, in order; the first eleven are also the recorded
# series of a run (`wpam_mj.simulation.loop_contract.REC_FIELDS` after time). Pressures pi, po are
# gauge [Pa] (what the force used this step), p_i, p_o the chambers' absolute pressures
# [Pa]; "tension" is the force the muscle pulls its tendon with [N]; the regulators'
# dead-time queues follow the named fields (2 x delay steps).
MAX_CHANNELS = 3  # the most input channels a control mode takes (`CONTROLS`)
STATE_FIELDS = (
    "x", "velocity", "x_ref", "pi", "po", "pi_cmd", "po_cmd", "tension", "friction",
    "pi_reg", "po_reg",  # recorded: the step's inputs, outputs and regulator set points
    "p_i", "p_o",  # chamber pressures at the start of the next step, absolute [Pa]
    "integral", "derivative", "e_prev", "has_prev",  # PoFeedback's committed state
    "next_integral", "next_derivative", "next_e",  # what advance commits
    "rest_pending", "status", "head",  # start at rest; STATUS_* bits; dead-time ring head
    *(f"input{i}" for i in range(MAX_CHANNELS)))  # each channel's last finite command
FIELD = {name: i for i, name in enumerate(STATE_FIELDS)}  # offset of each named field

# MuJoCo's integrators by their mjtIntegrator values, as messages name them
INTEGRATORS = ("Euler", "RK4", "implicit", "implicitfast")

# Bits of the "status" field (docs/plugin.md), 0 while the muscle is well:
STATUS_STROKE = 1  # the contraction left the stroke [0, full bag] by more than the tolerance
STATUS_PRESSURE = 2  # a chamber pressure left its range: the muscle stops
STATUS_MODEL = 4  # the model changed under the muscle after compile: the muscle stops
# How far past an end of its stroke the contraction may go before STATUS_STROKE [m]: a
# soft joint or tendon limit at the end lets it by a little (on the rig's lower stop
# 0.09 mm at 50 N; 1.0 mm at its harshest, a 1 N load under 0.5 MPa of Po).
STROKE_TOLERANCE = 5e-3


def status_message(status: float, x: float, p_i: float, p_o: float) -> str:
    """The one line of a muscle's `status` (its bits) from its state's contraction x [m]
    and absolute chamber pressures [Pa]; "" when it is 0."""
    bits = int(status)
    lines = []
    if bits & STATUS_STROKE:
        lines.append(f"contraction x = {x!r} m left the muscle's stroke (from 0 to the full "
                     f"bag) by more than {STROKE_TOLERANCE:g} m")
    if bits & STATUS_PRESSURE:
        lines.append(f"chamber pressure Pi = {p_i!r} Pa, Po = {p_o!r} Pa (absolute)")
    if bits & STATUS_MODEL:
        lines.append("the model's timestep or integrator changed after it compiled, or its "
                     "tendon's frictionloss or MuJoCo's friction flags left the muscle no "
                     "friction row; the muscle stopped (change it back and reset, or "
                     "recompile)")
    return "; ".join(lines)


@dataclass(frozen=True)
class Control:
    """A control mode of the plugin: its input channels (ctrl of the actuators that name
    the instance, in model order), of which the first `required` must be present."""

    name: str
    channels: tuple[str, ...]
    required: int
    feedback: bool

    def channels_for(self, outer_chamber: bool) -> tuple[str, ...]:
        """The channels a muscle takes in this mode: without an outer chamber (rlam,
        mckibben) there is nothing for Po to fill, so no Po command channel."""
        return self.channels if outer_chamber else tuple(c for c in self.channels
                                                         if c != "po_cmd")


# Channel meanings: pi_cmd, po_cmd: regulator commands [Pa gauge]; x_ref: target
# contraction [m]; under feedback a pi_cmd channel replaces the in-plugin Pi feedforward
# and po_cmd is added to the feedback's Po command (pi_ff's feedforward of the air).
CONTROLS = (
    Control("open", ("pi_cmd", "po_cmd"), 2, False),
    Control("pi", ("x_ref", "pi_cmd"), 1, True),
    Control("pid", ("x_ref", "pi_cmd"), 1, True),
    Control("pi_ff", ("x_ref", "pi_cmd", "po_cmd"), 3, True),
)
CONTROL_BY_NAME = {c.name: c for c in CONTROLS}


def control_mode(name: str) -> Control:
    """The control mode `name`: the plugin's, or for a controller of
    `wpam_mj.control.controllers.CONTROLLERS` that only the Python engine runs, the channels of the
    plugin's most general mode of its kind (pi_ff under feedback, else open)."""
    from wpam_mj.control.controllers import check_control, CONTROLLERS  # noqa: PLC0415 (no cycle at import)

    if name in CONTROL_BY_NAME:
        return CONTROL_BY_NAME[name]
    feedback = CONTROLLERS[check_control(name)].feedback
    like = CONTROL_BY_NAME["pi_ff" if feedback else "open"]
    return Control(name, like.channels, like.required, feedback)
# Attributes besides the parameters (docs/plugin.md): preset, control mode, whether the
# run starts at rest at its first commands, whether the end fittings are guided (can carry
# the outer bag's push, `wpam_mj.physics.muscle`), then the instance's numbers
# (`wpam_mj.physics.rules.INSTANCE_NUMBERS`: the load the Pi feedforward holds [N], the
# muscle's contraction in the model's reference pose [m]: x = contraction0 + tendon length
# at qpos0 - tendon length).
INSTANCE_WORDS = {"preset": prm.PRESETS, "control": tuple(c.name for c in CONTROLS),
                  "start": ("vented", "rest"), "end_fittings": ("free", "guided")}
INSTANCE_KEYS = (*INSTANCE_WORDS, *rules.INSTANCE_NUMBERS)
parameter_fields = prm.parameter_fields


def attribute_names() -> tuple[str, ...]:
    """Every configuration attribute of the plugin, in its declared order."""
    return (*INSTANCE_KEYS, *(key for key, _ in parameter_fields()))


def config_of(model, instance: int) -> dict[str, str]:
    """The attributes an instance of a compiled model was given ({} entries left out):
    MuJoCo stores one NUL-terminated value per declared attribute."""
    raw = model.plugin_attr.tobytes()[model.plugin_attradr[instance]:]
    values = raw.split(b"\0")[:len(attribute_names())]
    return {k: v.decode() for k, v in zip(attribute_names(), values) if v}


def state_address(model, instance: int | str = 0) -> int:
    """Where an instance's state starts in `data.plugin_state`, by id or name."""
    if isinstance(instance, str):
        instance = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_PLUGIN, instance)
    return int(model.plugin_stateadr[instance])


def state_of(model, data, instance: int | str = 0) -> dict[str, float]:
    """The named fields of a muscle's state (`STATE_FIELDS`; SI, pressures `pi`, `po` gauge
    and `p_i`, `p_o` absolute [Pa]) in `data`, the instance given by id or name."""
    start = state_address(model, instance)
    return dict(zip(STATE_FIELDS, map(float, data.plugin_state[start:start + len(STATE_FIELDS)])))


@dataclass(frozen=True)
class TendonRange:
    """The lengths [m] of a muscle's tendon across its stroke 0 <= x <= x_max: the range
    to give the tendon (MJCF ``limited="true" range="lower upper"``) so that no load
    stretches the braid past its natural length (it is inextensible there) nor contracts
    it past the full bag."""

    lower: float  # at the full bag, x = x_max: natural length - max_contraction
    upper: float  # at the muscle's natural length, x = 0
    max_contraction: float  # x_max, BraidGeometry.max_contraction

    @property
    def mjcf(self) -> str:
        """The tendon's attributes that give this range."""
        return f'limited="true" range="{self.lower:.6g} {self.upper:.6g}"'


def tendon_range(model, instance: int | str = 0) -> TendonRange:
    """The range of the tendon of a muscle of a compiled `model` (instance by id or name).

    x = contraction0 + (tendon length at qpos0 - tendon length) (docs/plugin.md), so the
    tendon is `upper` = tendon_length0 + contraction0 long at the natural length (x = 0)
    and `upper` - x_max at the full bag, x_max from the instance's braid parameters
    (`wpam_mj.physics.geometry.BraidGeometry`). Compile the model once (with any range or
    none) and give its tendon this one."""
    from wpam_mj.physics.geometry import BraidGeometry  # noqa: PLC0415 (no cycle at import)
    from wpam_mj.simulation.engine import InstanceConfig  # noqa: PLC0415 (it imports this module)

    if isinstance(instance, str):
        instance = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_PLUGIN, instance)
    name = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_PLUGIN, instance)
    config = InstanceConfig.from_config(name, config_of(model, instance),
                                        model.opt.timestep, int(model.opt.integrator))
    first = list(model.actuator_plugin).index(instance)  # the channel carrying the force
    natural = (float(model.tendon_length0[model.actuator_trnid[first, 0]])
               + config.contraction0)
    x_max = BraidGeometry.from_params(config.params.braid).max_contraction
    return TendonRange(natural - x_max, natural, x_max)


def status_of(model, data, instance: int | str = 0) -> str:
    """The one line of a muscle's `status` in `data` ("" while it is well)."""
    s = state_of(model, data, instance)
    return status_message(s["status"], s["x"], s["p_i"], s["p_o"])


def _c(value: float) -> str:
    """A double as an exact C99 hex literal."""
    if value in (float("inf"), float("-inf")):
        return "INFINITY" if value > 0 else "-INFINITY"
    return float(value).hex()


def _q(name: str) -> str:
    """The C name of a quantity of the rules."""
    return name.replace(".", "_").upper()


def _bound(value: float | str) -> str:
    return f"Q({_q(value)})" if isinstance(value, str) else _c(value)


def tables_header() -> str:
    """The generated C tables the plugin's C includes (see the module docstring)."""
    presets = [prm.preset(name) for name in prm.PRESETS]
    fields = parameter_fields()
    lines = ["/* Generated by wpam_mj/simulation/plugin.py from wpam_mj/physics: do not edit. */",
             "#define WPAM_PARAMS(ENTRY) \\"]
    for key, f in fields:
        md = f.metadata
        lines.append(f'  ENTRY({_q(key)}, "{key}", "{md["unit"]}", '
                     f'{_c(md["lo"])}, {_c(md["hi"])}, {int(md["lo_open"])}) \\')
    lines.append("")
    lines.append("#define WPAM_NUMBERS(ENTRY) " + " ".join(
        f'ENTRY({_q(k)}, "{k}", "{n.unit}", {_c(n.lo)}, {_c(n.hi)}, 0)'
        for k, n in rules.INSTANCE_NUMBERS.items()))
    lines.append("#define WPAM_DERIVED(ENTRY) " + " ".join(
        f'ENTRY({_q(k)}, "{k}", "{d.unit}")' for k, d in rules.DERIVED.items()))
    lines.append("#define WPAM_RULES(RULE) \\")
    for r in rules.CROSS_RULES:
        lines.append(f'  RULE({_q(r.subject)}, {_bound(r.lo)}, {int(r.lo_open)}, '
                     f'{_bound(r.hi)}, {int(r.hi_open)}, "{r.why}") \\')
    lines.append("")
    rows = ", ".join("{" + ", ".join(_c(p.value(key)) for key, _ in fields) + "}"
                     for p in presets)
    lines += [f"#define WPAM_PRESET_DEFAULTS {{{rows}}}",
              f"#define WPAM_NPRESET {len(presets)}",
              "#define WPAM_PRESETS " + ", ".join(f'"{n}"' for n in prm.PRESETS),
              f'#define WPAM_PRESET_LIST "{", ".join(prm.PRESETS)}"',
              "#define WPAM_PRESET_OUTER " + ", ".join(
                  str(int(p.outer_chamber)) for p in presets),
              "#define WPAM_STATE(ENTRY) " + " ".join(
                  f"ENTRY({n.upper()}, {n})" for n in STATE_FIELDS),
              "#define WPAM_CONTROLS(ENTRY) " + " ".join(
                  f"ENTRY({c.name.upper()}, {c.name}, {c.required}, {len(c.channels)}, "
                  f"{int(c.feedback)})" for c in CONTROLS),
              f'#define WPAM_CONTROL_LIST "{", ".join(CONTROL_BY_NAME)}"',
              "#define WPAM_CONTROL_NMAX_BARE " + ", ".join(
                  str(len(c.channels_for(False))) for c in CONTROLS),
              f"#define WPAM_MAX_CHANNELS {MAX_CHANNELS}",
              "#define WPAM_INTEGRATORS " + ", ".join(f'"{n}"' for n in INTEGRATORS),
              "#define WPAM_INSTANCE_KEYS " + " ".join(f'"{k}",' for k in INSTANCE_KEYS),
              f"#define WPAM_MPA {_c(MPA)}",
              f"#define WPAM_MAX_QUEUE_STEPS {_c(rules.MAX_QUEUE_STEPS)}",
              f"#define WPAM_STROKE_TOLERANCE {_c(STROKE_TOLERANCE)}",
              f"#define WPAM_STATUS_STROKE {STATUS_STROKE}",
              f"#define WPAM_STATUS_PRESSURE {STATUS_PRESSURE}",
              f"#define WPAM_STATUS_MODEL {STATUS_MODEL}"]
    body = "\n".join(lines) + "\n" + kernel_codegen.c_source()  # the physics
    digest = hashlib.sha256(body.encode()).hexdigest()[:16]
    return body + f'#define WPAM_TABLES_HASH "{digest}"\n'


def _header_hash(header: str) -> str:
    return header.rsplit('"', 2)[-2]


def compiler() -> str | None:
    """Path of the C compiler ($CC, default gcc), None if absent."""
    return shutil.which(os.environ.get("CC") or "gcc")


def disabled() -> bool:
    """True when WPAM_MJ_NO_COMPILE turns the compiled plugin off."""
    return os.environ.get("WPAM_MJ_NO_COMPILE", "") not in ("", "0")


def load() -> Path | None:
    """Build (once per source, tables and MuJoCo version), check and register the plugin,
    once per process (`wpam_mj.simulation.plugin_build`). Returns the library's path, or
    None when it is unavailable (`unavailable_reason()` says why). Never raises."""
    from wpam_mj.simulation import plugin_build  # noqa: PLC0415 (it imports this module)

    return plugin_build.load()


def available() -> bool:
    """True when the plugin is built (or cached) and registered."""
    return load() is not None


def unavailable_reason() -> str | None:
    """Why `available()` is False (None when it is True)."""
    from wpam_mj.simulation import plugin_build  # noqa: PLC0415 (it imports this module)

    return plugin_build.reason()
