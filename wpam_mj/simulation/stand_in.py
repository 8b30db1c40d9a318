"""A stand-in registration of ``wpam_mj.muscle``, so that MJCF naming the plugin parses
where the compiled plugin cannot be built (`register_stand_in`); the Python engine
(`wpam_mj.simulation.engine.python_model`) then removes it before compiling."""

from __future__ import annotations

import ctypes
import re
import sys

from wpam_mj.simulation import plugin


def _plugin_struct() -> type[ctypes.Structure]:
    """ctypes' mjpPlugin, field for field as the installed mujoco's mjplugin.h declares
    it (pointers, function pointers and ints; any other field type is refused)."""
    header = (plugin.MUJOCO_DIR / "include" / "mujoco" / "mjplugin.h").read_text()
    found = re.search(r"typedef struct mjpPlugin_ \{(.*?)\} mjpPlugin;", header, re.S)
    if found is None:
        raise RuntimeError("mjplugin.h declares no mjpPlugin")
    fields = []
    for declaration in re.sub(r"//[^\n]*|/\*.*?\*/", "", found.group(1), flags=re.S).split(";"):
        declaration = " ".join(declaration.split())
        callback = re.fullmatch(r"[^(]*\(\s*\*\s*(\w+)\s*\)\s*\(.*\)", declaration)
        field = re.fullmatch(r"(.*?)\s*(\w+)", declaration)
        if callback:
            fields.append((callback.group(1), ctypes.c_void_p))
        elif field and "*" in field.group(1):
            fields.append((field.group(2), ctypes.c_void_p))
        elif field and field.group(1) == "int":
            fields.append((field.group(2), ctypes.c_int))
        elif declaration:
            raise RuntimeError(f"mjplugin.h: mjpPlugin field '{declaration}' is of a type the "
                               "stand-in does not lay out")
    return type("MjpPlugin", (ctypes.Structure,), {"_fields_": fields})


_NSTATE = ctypes.CFUNCTYPE(ctypes.c_int, ctypes.c_void_p, ctypes.c_int)
_INIT = ctypes.CFUNCTYPE(ctypes.c_int, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_int)
_RESET = ctypes.CFUNCTYPE(None, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p,
                          ctypes.c_int)
_COMPUTE = ctypes.CFUNCTYPE(None, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_int,
                            ctypes.c_int)
_keep: list = []  # the registration's C objects live as long as the process
INSTEAD = ("model, muscles = wpam_mj.simulation.engine.python_model(mujoco.MjSpec.from_file("
           "PATH)), stepped by engine.step(model, data, muscles) (docs/plugin.md)")


def _refuse(model, data, instance) -> int:
    print(f"wpam_mj: this model's muscles need the compiled plugin, unavailable here "
          f"({plugin.unavailable_reason()}); load it on the Python engine instead: {INSTEAD}",
          file=sys.stderr)
    return -1


def register_stand_in() -> None:
    """Register a ``wpam_mj.muscle`` that declares the plugin's attributes and computes
    nothing, so that an MJCF naming the plugin parses where the compiled plugin cannot be
    built; `python_model` then removes it before compiling, and compiling such a model
    directly fails, with one line saying what to call instead. Does nothing when a
    plugin of that name is registered (the compiled one, or the stand-in already)."""
    from wpam_mj.simulation import plugin_build  # noqa: PLC0415 (loaded only here)

    if plugin.available() or plugin_build.registered():
        return
    names = plugin.attribute_names()
    attributes = (ctypes.c_char_p * len(names))(*[n.encode() for n in names])
    name = ctypes.create_string_buffer(plugin.NAME.encode())
    # init fails: a model compiled with the stand-in itself has no muscle and must not run
    callbacks = (_NSTATE(lambda m, i: 0), _INIT(_refuse),
                 _RESET(lambda m, s, p, i: None), _COMPUTE(lambda m, d, i, c: None))
    lib = plugin_build.libmujoco()
    stand_in = _plugin_struct()()
    lib.mjp_defaultPlugin(ctypes.byref(stand_in))
    stand_in.name = ctypes.addressof(name)
    stand_in.nattribute = len(names)
    stand_in.attributes = ctypes.addressof(attributes)
    stand_in.capabilityflags = 1  # mjPLUGIN_ACTUATOR
    for field, callback in zip(("nstate", "init", "reset", "compute"), callbacks):
        setattr(stand_in, field, ctypes.cast(callback, ctypes.c_void_p).value)
    lib.mjp_registerPlugin(ctypes.byref(stand_in))
    _keep.extend([stand_in, name, attributes, callbacks])
