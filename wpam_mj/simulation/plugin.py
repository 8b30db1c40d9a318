"""The muscle as a native MuJoCo actuator plugin, ``wpam_mj.muscle``: build, load, layout.

`muscle_plugin.c` is compiled at first use against the installed mujoco wheel (its
``include/`` and ``libmujoco.so.<version>``), cached per user in
``$XDG_CACHE_HOME/wpam_mj`` (default ``~/.cache/wpam_mj``) under a name that hashes the
C source, the generated tables, the compiler flags and the MuJoCo version, and registered
with ``mujoco.mj_loadPluginLibrary``. `load()` does this once per process; `import
wpam_mj` calls it, so any MJCF that names the plugin compiles after the import.

Nothing is copied by hand between Python and C: `tables_header()` writes every parameter
(``section.field`` names, units, ranges, each preset's values) from `wpam_mj.physics.params`, the
state layout `STATE_FIELDS`, the control modes `CONTROLS` and the physical constants of
`wpam_mj.physics.pneumatics` as C tables (floats as exact hex literals), and the library reports
their hash, which must match.

Set ``WPAM_MJ_NO_COMPILE=1`` to skip the build (`available()` is then False and the Python
engine runs).
"""

from __future__ import annotations

import dataclasses
import hashlib
import os
import shutil
from dataclasses import dataclass
from pathlib import Path

import mujoco

from wpam_mj.physics import params as prm
from wpam_mj.physics import pneumatics as pn
from wpam_mj.units import MM, MPA

NAME = "wpam_mj.muscle"
SOURCE = Path(__file__).with_name("muscle_plugin.c")
MUJOCO_DIR = Path(mujoco.__file__).resolve().parent
# -ffp-contract=off: no FMA contraction; no -ffast-math: IEEE order of operations kept.
# Both make the plugin bit-identical to the Python engine's floats.
CFLAGS = ("-O2", "-fPIC", "-shared", "-std=c11", "-ffp-contract=off", "-fno-fast-math")

# The plugin state of one instance, in order; the first eleven are also the recorded
# series of a run (`wpam_mj.simulation.loop_contract.REC_FIELDS` after time). Pressures pi, po are
# gauge [Pa] (what the force used this step), p_i, p_o the chambers' absolute pressures
# [Pa]; the regulators' dead-time queues follow the named fields (2 x delay steps).
STATE_FIELDS = (
    "x", "velocity", "x_ref", "pi", "po", "pi_cmd", "po_cmd", "tension", "friction",
    "pi_reg", "po_reg",  # recorded: the step's inputs, outputs and regulator set points
    "p_i", "p_o",  # chamber pressures at the start of the next step, absolute [Pa]
    "integral", "derivative", "e_prev", "has_prev",  # PoFeedback's committed state
    "next_integral", "next_derivative", "next_e",  # what advance commits
    "rest_pending", "status", "head")  # start at rest; FAIL_* code; dead-time ring head
FAIL_CONTRACTION, FAIL_PRESSURE = 1, 2  # values of the "status" field
FIELD = {name: i for i, name in enumerate(STATE_FIELDS)}  # offset of each named field


@dataclass(frozen=True)
class Control:
    """A control mode of the plugin: its input channels (ctrl of the actuators that name
    the instance, in model order), of which the first `required` must be present."""

    name: str
    channels: tuple[str, ...]
    required: int
    feedback: bool


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
# run starts at rest at its first commands, the load the Pi feedforward holds [N], and the
# muscle's contraction in the model's reference pose [m] (x = contraction0 + tendon length
# at qpos0 - tendon length; nonzero for muscles mounted pre-contracted, as in a pair).
INSTANCE_KEYS = ("preset", "control", "start", "feedforward_load", "contraction0")


def parameter_fields() -> list[tuple[str, dataclasses.Field]]:
    """Every parameter as ("section.field", its dataclass field), in `Params` order."""
    return [(f"{section}.{f.name}", f) for section, cls in prm._SECTIONS.items()
            for f in dataclasses.fields(cls)]


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


def _c(value: float) -> str:
    """A double as an exact C99 hex literal."""
    return "INFINITY" if value == float("inf") else float(value).hex()


def tables_header() -> str:
    """The generated C tables of `muscle_plugin.c` (see the module docstring)."""
    presets = [prm.preset(name) for name in prm.PRESETS]
    fields = parameter_fields()
    lines = ["/* Generated by wpam_mj/simulation/plugin.py from wpam_mj/physics/params.py: "
             "do not edit. */",
             "#define WPAM_PARAMS(ENTRY) \\"]
    for key, f in fields:
        md = f.metadata
        lines.append(f'  ENTRY({key.replace(".", "_").upper()}, "{key}", "{md["unit"]}", '
                     f'{_c(md["lo"])}, {_c(md["hi"])}, {int(md["lo_open"])}) \\')
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
              f"#define WPAM_MAX_CHANNELS {max(len(c.channels) for c in CONTROLS)}",
              "#define WPAM_INSTANCE_KEYS " + " ".join(f'"{k}",' for k in INSTANCE_KEYS),
              f"#define WPAM_RT0 {_c(pn.RT0)}", f"#define WPAM_RHO_0 {_c(pn.RHO_0)}",
              f"#define WPAM_R_LAMINAR {_c(pn.R_LAMINAR)}", f"#define WPAM_MM {_c(MM)}",
              f"#define WPAM_MPA {_c(MPA)}",
              f"#define WPAM_FAIL_CONTRACTION {FAIL_CONTRACTION}",
              f"#define WPAM_FAIL_PRESSURE {FAIL_PRESSURE}"]
    body = "\n".join(lines) + "\n"
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
