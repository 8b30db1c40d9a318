"""The muscle's physics is written once (wpam_mj/physics/kernel.py): the generator's C and
numpy forms compute what the Python functions compute, bit for bit; the plugin's C keeps
no physics of its own; a change of the kernel changes what every engine runs."""

from __future__ import annotations

import ctypes
import importlib.util
import math
import re
import shutil
import subprocess
import textwrap

import numpy as np
import pytest

from wpam_mj.physics import kernel, kernel_codegen
from wpam_mj.physics.kernel_codegen import KernelSyntaxError
from wpam_mj.simulation import plugin

SMALL = '''
import math

GAIN = 0.1  # a named constant

def ramp(x: float, lo: float, hi: float) -> float:
    """min/max with Python's semantics, a conditional expression."""
    return min(max(x, lo), hi) * GAIN if x == x else -1.0

def split(x: float, on: bool) -> tuple[float, float]:
    if on and x > 0.0:
        y = math.sqrt(x)
        z = y * 3.0 - x / 7.0
    elif x < -1.0:
        y = -x
        z = y ** 2
    else:
        y = 0.5
        z = ramp(x, -0.25, 0.25)
    return y, z + y
'''


def load_module(tmp_path, name: str, text: str):
    path = tmp_path / f"{name}.py"
    path.write_text(textwrap.dedent(text))
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


INPUTS = [0.0, -0.0, 0.1, 0.3, -0.25, 0.25, 2.0, -3.0, 1e300, -1e-300, math.inf, -math.inf,
          math.nan, 1.0 / 3.0]


@pytest.mark.skipif(shutil.which("gcc") is None, reason="needs gcc")
def test_the_generated_c_of_a_small_module_computes_pythons_floats(tmp_path):
    module = load_module(tmp_path, "small_kernel", SMALL)
    wrappers = textwrap.dedent("""
        double ramp_(double x, double lo, double hi) { return kernel_ramp(x, lo, hi); }
        void split_(double x, int on, double* y, double* z) { kernel_split(x, on, y, z); }
    """)
    source = tmp_path / "small.c"
    source.write_text("#include <math.h>\n" + kernel_codegen.c_source(module) + wrappers)
    lib = tmp_path / "small.so"
    subprocess.run(["gcc", "-O2", "-fPIC", "-shared", "-ffp-contract=off", "-fno-fast-math",
                    str(source), "-o", str(lib), "-lm"], check=True)
    c = ctypes.CDLL(str(lib))
    c.ramp_.restype = ctypes.c_double
    c.ramp_.argtypes = [ctypes.c_double] * 3
    y, z = ctypes.c_double(), ctypes.c_double()
    same = np.testing.assert_array_equal  # NaN equals NaN, -0.0 vs 0.0 checked below
    for x in INPUTS:
        for lo, hi in ((-0.25, 0.25), (0.0, -0.0), (math.nan, 1.0)):
            expected = module.ramp(x, lo, hi)
            got = c.ramp_(x, lo, hi)
            same(got, expected)
            assert math.copysign(1.0, got) == math.copysign(1.0, expected)
        for on in (False, True):
            c.split_(ctypes.c_double(x), on, ctypes.byref(y), ctypes.byref(z))
            same((y.value, z.value), module.split(x, on))


def test_the_array_form_is_the_scalar_form_element_by_element(tmp_path):
    module = load_module(tmp_path, "small_kernel_np", SMALL)
    arrays = kernel_codegen.array_kernel(module)
    x = np.array(INPUTS)
    for on in (False, True):
        y, z = arrays.split(x, on)
        expected = np.array([module.split(v, on) for v in INPUTS])
        np.testing.assert_array_equal(np.stack([y, z], axis=1), expected)


def test_the_physics_array_form_is_the_kernels(tmp_path):
    """A few kernel functions on arrays against the scalar kernel, edge cases included."""
    rng = np.random.default_rng(0)
    arrays = kernel_codegen.array_kernel()
    source = np.concatenate([[1e5, 2e5, 3e5, 1e5], rng.uniform(0.9e5, 6e5, 200)])
    chamber = np.concatenate([[1e5, 1e5, 3e5 * 0.995, 2e5], rng.uniform(0.9e5, 6e5, 200)])
    flow = arrays.mass_flow(source, chamber, 2.6e-9, 0.3)
    assert flow.tolist() == [kernel.mass_flow(a, b, 2.6e-9, 0.3)
                             for a, b in zip(source, chamber)]
    x = np.concatenate([[-0.01, 0.0, 0.05, 0.5], rng.uniform(-0.01, 0.1, 100)])
    args = (0.15, 0.04, 4e-3, 0.09)
    assert arrays.area(x, *args).tolist() == [kernel.area(v, *args) for v in x]
    e = rng.normal(0.0, 1e-3, 100)
    scalar = [kernel.po_feedback(v, 0.0, 0.0, 1.0, 0.0, 0.0, True, 0.1, 0.008, 0.004, 0.01,
                                 1e6, 5e3, 8e4, 1e-3) for v in e]
    vector = arrays.po_feedback(e, 0.0, 0.0, 1.0, 0.0, 0.0, True, 0.1, 0.008, 0.004, 0.01,
                                1e6, 5e3, 8e4, 1e-3)
    np.testing.assert_array_equal(np.stack(vector, axis=1), np.array(scalar))


def test_the_plugin_header_holds_every_kernel_function_and_the_c_none_of_its_own():
    header = plugin.tables_header()
    for name in kernel_codegen.parse().functions:
        assert re.search(rf"^static \w+ kernel_{name}\(.*\) {{$", header, re.M), name
    for path in (*plugin.SOURCES, *plugin.HEADERS):
        code = re.sub(r"/\*.*?\*/", "", path.read_text(), flags=re.S)
        # no math of its own: every physics equation is the kernel's
        for word in ("sqrt(", "pow(", "exp", "sin(", "cos(", "asin(", "mjPI", "RHO", "RT0"):
            assert word not in code, f"{path.name} computes {word} itself"
        assert "double py_max" not in code, path.name  # the kernel's, from the header


def test_one_edit_of_the_kernel_changes_both_engines(tmp_path, monkeypatch):
    """An equation changed in the kernel's source changes the plugin's C (and the tables'
    hash, so the plugin rebuilds), and the Python engine's physics, which looks the
    functions up in the kernel module at every call."""
    source = (kernel_codegen.inspect.getsource(kernel)
              .replace("return friction_coeff * pressure_difference(pi, po) * area "
                       "+ friction_const",
                       "return 2.0 * friction_coeff * pressure_difference(pi, po) * area "
                       "+ friction_const"))
    assert "2.0 * friction_coeff" in source
    edited = load_module(tmp_path, "edited_kernel", source)
    before, after = kernel_codegen.c_source(kernel), kernel_codegen.c_source(edited)
    assert "(((0x1.0000000000000p+1 * friction_coeff)" in after and before != after
    tables_hash = plugin.tables_header().rsplit('"', 2)[-2]
    monkeypatch.setattr(kernel_codegen, "c_source", lambda module=kernel: after)
    assert plugin.tables_header().rsplit('"', 2)[-2] != tables_hash
    from wpam_mj import preset  # noqa: PLC0415
    from wpam_mj.physics.muscle import MuscleModel  # noqa: PLC0415

    muscle = MuscleModel.from_params(preset("wpam"))
    level = muscle.friction(0.02, 0.3e6, 0.05e6)
    monkeypatch.setattr(kernel, "friction_level", edited.friction_level)
    assert muscle.friction(0.02, 0.3e6, 0.05e6) == pytest.approx(
        2.0 * level - muscle.friction_const)


@pytest.mark.parametrize("text, what", [
    ("def f(x: float) -> float:\n    for i in x:\n        pass\n    return x\n", "For"),
    ("def f(x: float) -> float:\n    return abs(x)\n", "calls kernel functions"),
    ("def f(x) -> float:\n    return x\n", "needs a float or bool annotation"),
    ("def f(x: float) -> float:\n    if x > 0.0:\n        y = 1.0\n    return y\n",
     "assigned on one side of the branch only"),
    ("def f(x: float) -> float:\n    return 0.0 < x < 1.0\n", "one comparison at a time"),
])
def test_code_outside_the_subset_is_refused_in_one_line(tmp_path, text, what):
    module = load_module(tmp_path, "bad_kernel", text)
    with pytest.raises(KernelSyntaxError, match=what) as err:
        kernel_codegen.numpy_source(module)
    assert "\n" not in str(err.value) and "kernel line" in str(err.value)
