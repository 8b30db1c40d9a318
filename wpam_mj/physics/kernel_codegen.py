"""`wpam_mj.physics.kernel` as C and as numpy array code, from its syntax tree.

`c_source()` is the C the compiled plugin calls (`wpam_mj.simulation.plugin.tables_header`
puts it in the generated header, under the tables' hash): each kernel function becomes
``static double kernel_<name>(double ..., int ...)``, or for one returning a tuple
``static void kernel_<name>(..., double* out0, double* out1, ...)``; each constant
``KERNEL_<NAME>`` as an exact hex float. `array_kernel()` is the same functions written
for numpy arrays (elementwise, the values of the scalar functions bit for bit): a branch
becomes ``np.where`` over both sides' values, evaluated everywhere with floating-point
warnings off, so an array function returns what the scalar one returns element by
element.

Both translations keep every operation's operands and order: each binary operation is
written with its own parentheses, `min`/`max` keep Python's semantics (``py_min``/
``py_max``: the first argument unless the second is strictly smaller/greater), and
``**`` is C's ``pow`` (which CPython's float power calls). The subset is checked
(`KernelSyntaxError` names the line); the kernel module's docstring lists it.
"""

from __future__ import annotations

import ast
import functools
import inspect
import math
import types
from dataclasses import dataclass

import numpy as np

from wpam_mj.physics import kernel as kernel_module

MATH_FUNCTIONS = ("sqrt", "cos", "sin", "asin", "expm1")
MATH_CONSTANTS = {"pi": math.pi, "inf": math.inf}
_C_BINARY = {ast.Add: "+", ast.Sub: "-", ast.Mult: "*", ast.Div: "/"}
_C_COMPARE = {ast.Lt: "<", ast.LtE: "<=", ast.Gt: ">", ast.GtE: ">=", ast.Eq: "==",
              ast.NotEq: "!="}
_TYPES = {"float": "double", "bool": "int"}
_ALLOWED = (ast.BinOp, ast.UnaryOp, ast.BoolOp, ast.Compare, ast.IfExp, ast.Constant,
            ast.Name, ast.Load, ast.Tuple, ast.Call, ast.Attribute, ast.Pow, ast.USub,
            ast.UAdd, ast.Not, ast.And, ast.Or, *_C_BINARY, *_C_COMPARE)


class KernelSyntaxError(ValueError):
    """Kernel code outside the subset both targets translate (one line, with where)."""


@dataclass(frozen=True)
class Function:
    """One kernel function: its name, arguments (name, C type), the number of values it
    returns (1, or the length of its tuple), and its syntax tree."""

    name: str
    args: tuple[tuple[str, str], ...]
    returns: int
    tree: ast.FunctionDef


@dataclass(frozen=True)
class Kernel:
    """A parsed kernel module: its functions in order and the constants they use."""

    functions: dict[str, Function]
    constants: dict[str, float]


def _fail(node: ast.AST, what: str) -> KernelSyntaxError:
    return KernelSyntaxError(f"kernel line {getattr(node, 'lineno', '?')}: {what}")


def _returns(node: ast.FunctionDef) -> int:
    ann = node.returns
    if isinstance(ann, ast.Name) and ann.id == "float":
        return 1
    if (isinstance(ann, ast.Subscript) and isinstance(ann.value, ast.Name)
            and ann.value.id == "tuple" and isinstance(ann.slice, ast.Tuple)
            and all(isinstance(e, ast.Name) and e.id == "float" for e in ann.slice.elts)):
        return len(ann.slice.elts)
    raise _fail(node, f"{node.name} must return float or tuple[float, ...]")


def parse(module: types.ModuleType = kernel_module) -> Kernel:
    """The functions of `module` and the module constants they read, checked against the
    subset (a `KernelSyntaxError` otherwise)."""
    tree = ast.parse(inspect.getsource(module))
    functions: dict[str, Function] = {}
    for node in tree.body:
        if isinstance(node, ast.FunctionDef):
            args = []
            if node.args.vararg or node.args.kwarg or node.args.kwonlyargs \
                    or node.args.defaults or node.decorator_list:
                raise _fail(node, f"{node.name}: plain positional arguments only")
            for a in node.args.args:
                if not (isinstance(a.annotation, ast.Name) and a.annotation.id in _TYPES):
                    raise _fail(a, f"{node.name}: argument {a.arg} needs a float or bool "
                                   "annotation")
                args.append((a.arg, _TYPES[a.annotation.id]))
            functions[node.name] = Function(node.name, tuple(args), _returns(node), node)
    constants: dict[str, float] = {}
    for f in functions.values():
        _check_body(f, functions, module, constants)
    return Kernel(functions, constants)


def _check_body(f: Function, functions: dict[str, Function], module: types.ModuleType,
                constants: dict[str, float]) -> None:
    body = _docstring_free(f.tree.body)
    if not body or not isinstance(body[-1], ast.Return) or body[-1].value is None:
        raise _fail(f.tree, f"{f.name} must end with its one return")
    known = {name for name, _ in f.args}

    def names(node: ast.AST) -> None:
        modules = {id(a.value) for a in ast.walk(node) if isinstance(a, ast.Attribute)}
        for sub in ast.walk(node):
            if isinstance(sub, ast.Name) and isinstance(sub.ctx, ast.Load):
                if id(sub) in modules or sub.id in known or sub.id in functions \
                        or sub.id in ("min", "max"):
                    continue
                value = getattr(module, sub.id, None)
                if type(value) is not float:
                    raise _fail(sub, f"{f.name}: {sub.id} is neither an argument, a local "
                                     "assigned before, a kernel function nor a float constant")
                constants[sub.id] = value
            elif isinstance(sub, ast.Call):
                _check_call(sub, f, functions)
            elif isinstance(sub, ast.Attribute):
                if not (isinstance(sub.value, ast.Name) and sub.value.id == "math"
                        and sub.attr in (*MATH_FUNCTIONS, *MATH_CONSTANTS)):
                    raise _fail(sub, f"{f.name}: only math.{', math.'.join(MATH_FUNCTIONS)}"
                                     ", math.pi and math.inf")
            elif isinstance(sub, ast.Compare) and len(sub.ops) != 1:
                raise _fail(sub, f"{f.name}: one comparison at a time (no a < b < c)")
            elif isinstance(sub, ast.Constant) and type(sub.value) not in (int, float, bool):
                raise _fail(sub, f"{f.name}: numbers only")
            elif isinstance(sub, ast.Tuple) and sub is not body[-1].value:
                raise _fail(sub, f"{f.name}: a tuple only as what it returns")
            elif not isinstance(sub, _ALLOWED):
                raise _fail(sub, f"{f.name}: {type(sub).__name__} is outside the subset")

    def statements(nodes: list[ast.stmt]) -> None:
        for s in nodes:
            if isinstance(s, ast.Assign) and len(s.targets) == 1:
                names(s.value)
                target = s.targets[0]
                if isinstance(target, ast.Name):
                    if isinstance(s.value, ast.Call) and _returns_tuple(s.value, functions):
                        raise _fail(s, f"{f.name}: unpack a tuple-returning call into names")
                    known.add(target.id)
                elif isinstance(target, ast.Tuple) and all(isinstance(e, ast.Name)
                                                             for e in target.elts) \
                        and isinstance(s.value, ast.Call) and _returns_tuple(s.value, functions) \
                        and len(target.elts) == functions[s.value.func.id].returns:
                    known.update(e.id for e in target.elts)
                else:
                    raise _fail(s, f"{f.name}: assign to one name (or unpack a call's tuple)")
            elif isinstance(s, ast.If):
                names(s.test)
                statements(s.body)
                statements(s.orelse)
            elif s is body[-1]:
                value = s.value
                count = len(value.elts) if isinstance(value, ast.Tuple) else 1
                if count != f.returns:
                    raise _fail(s, f"{f.name} returns {count} values, annotated {f.returns}")
                names(value)
            else:
                raise _fail(s, f"{f.name}: {type(s).__name__} is outside the subset "
                               "(assignments, if/else of assignments, one return at the end)")

    statements(body)


def _returns_tuple(call: ast.Call, functions: dict[str, Function]) -> bool:
    return isinstance(call.func, ast.Name) and call.func.id in functions \
        and functions[call.func.id].returns > 1


def _check_call(call: ast.Call, f: Function, functions: dict[str, Function]) -> None:
    if call.keywords:
        raise _fail(call, f"{f.name}: positional arguments only")
    func = call.func
    if isinstance(func, ast.Attribute):
        if not (isinstance(func.value, ast.Name) and func.value.id == "math"
                and func.attr in MATH_FUNCTIONS and len(call.args) == 1):
            raise _fail(call, f"{f.name}: math.{func.attr} is outside the subset")
    elif isinstance(func, ast.Name) and func.id in ("min", "max"):
        if len(call.args) != 2:
            raise _fail(call, f"{f.name}: {func.id} of two arguments")
    elif isinstance(func, ast.Name) and func.id in functions:
        if len(call.args) != len(functions[func.id].args):
            raise _fail(call, f"{f.name}: {func.id} takes {len(functions[func.id].args)} "
                              "arguments")
    else:
        raise _fail(call, f"{f.name}: calls kernel functions, min, max and math only")


def _docstring_free(body: list[ast.stmt]) -> list[ast.stmt]:
    """A function's statements after its docstring."""
    if body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant):
        return body[1:]
    return body


# ---- C ----

def _c_float(value: float) -> str:
    if math.isinf(value):
        return "INFINITY" if value > 0 else "(-INFINITY)"
    return float(value).hex()


class _C:
    """The C of one function body."""

    def __init__(self, kernel: Kernel) -> None:
        self.k = kernel

    def expr(self, n: ast.expr) -> str:
        if isinstance(n, ast.BinOp):
            if isinstance(n.op, ast.Pow):
                return f"pow({self.expr(n.left)}, {self.expr(n.right)})"
            return f"({self.expr(n.left)} {_C_BINARY[type(n.op)]} {self.expr(n.right)})"
        if isinstance(n, ast.UnaryOp):
            op = {ast.USub: "-", ast.UAdd: "+", ast.Not: "!"}[type(n.op)]
            return f"({op}{self.expr(n.operand)})"
        if isinstance(n, ast.BoolOp):
            op = " && " if isinstance(n.op, ast.And) else " || "
            return "(" + op.join(self.expr(v) for v in n.values) + ")"
        if isinstance(n, ast.Compare):
            return (f"({self.expr(n.left)} {_C_COMPARE[type(n.ops[0])]} "
                    f"{self.expr(n.comparators[0])})")
        if isinstance(n, ast.IfExp):
            return f"({self.expr(n.test)} ? {self.expr(n.body)} : {self.expr(n.orelse)})"
        if isinstance(n, ast.Constant):
            return str(int(n.value)) if isinstance(n.value, bool) else _c_float(n.value)
        if isinstance(n, ast.Attribute):
            return _c_float(MATH_CONSTANTS[n.attr])
        if isinstance(n, ast.Name):
            return f"KERNEL_{n.id}" if n.id in self.k.constants and n.id not in self.local \
                else n.id
        if isinstance(n, ast.Call):
            args = ", ".join(self.expr(a) for a in n.args)
            if isinstance(n.func, ast.Attribute):
                return f"{n.func.attr}({args})"
            if n.func.id in ("min", "max"):
                return f"py_{n.func.id}({args})"
            return f"kernel_{n.func.id}({args})"
        raise _fail(n, f"no C for {type(n).__name__}")

    def function(self, f: Function) -> str:
        self.local = {name for name, _ in f.args}
        body = _docstring_free(f.tree.body)
        assigned: list[str] = []
        for s in ast.walk(ast.Module(body=body, type_ignores=[])):
            if isinstance(s, ast.Assign):
                t = s.targets[0]
                for name in ([t] if isinstance(t, ast.Name) else t.elts):
                    if name.id not in self.local and name.id not in assigned:
                        assigned.append(name.id)
        self.local.update(assigned)
        lines = [self.signature(f) + " {"]
        if assigned:
            lines.append("  double " + ", ".join(assigned) + ";")
        lines += self.statements(body, f, "  ")
        lines.append("}")
        return "\n".join(lines)

    def signature(self, f: Function) -> str:
        args = [f"{ctype} {name}" for name, ctype in f.args]
        if f.returns > 1:
            args += [f"double* out{i}" for i in range(f.returns)]
        kind = "double" if f.returns == 1 else "void"
        return f"static {kind} kernel_{f.name}({', '.join(args)})"

    def statements(self, body: list[ast.stmt], f: Function, pad: str) -> list[str]:
        lines = []
        for s in body:
            if isinstance(s, ast.Assign):
                t = s.targets[0]
                if isinstance(t, ast.Name):
                    lines.append(f"{pad}{t.id} = {self.expr(s.value)};")
                else:
                    call = self.expr(s.value)[:-1]  # kernel_f(args
                    outs = ", ".join(f"&{e.id}" for e in t.elts)
                    lines.append(f"{pad}{call}{', ' if s.value.args else ''}{outs});")
            elif isinstance(s, ast.If):
                lines.append(f"{pad}if ({self.expr(s.test)}) {{")
                lines += self.statements(s.body, f, pad + "  ")
                if s.orelse:
                    lines.append(f"{pad}}} else {{")
                    lines += self.statements(s.orelse, f, pad + "  ")
                lines.append(f"{pad}}}")
            elif isinstance(s, ast.Return) and f.returns == 1:
                lines.append(f"{pad}return {self.expr(s.value)};")
            else:
                for i, e in enumerate(s.value.elts):
                    lines.append(f"{pad}*out{i} = {self.expr(e)};")
        return lines


@functools.cache
def c_source(module: types.ModuleType = kernel_module) -> str:
    """The kernel as C (the module docstring): Python's min/max, the constants, every
    function's prototype, then every function."""
    k = parse(module)
    gen = _C(k)
    lines = ["/* Generated by wpam_mj/physics/kernel_codegen.py from "
             f"{module.__name__}: do not edit. */",
             "static double py_max(double a, double b) { return b > a ? b : a; }",
             "static double py_min(double a, double b) { return b < a ? b : a; }"]
    lines += [f"#define KERNEL_{name} {_c_float(v)}" for name, v in k.constants.items()]
    lines += [gen.signature(f) + ";" for f in k.functions.values()]
    lines += [gen.function(f) for f in k.functions.values()]
    return "\n".join(lines) + "\n"


# ---- numpy ----

class _Numpy:
    """The numpy source of one function: straight-line, each branch's assignments
    merged by np.where (the module docstring)."""

    def __init__(self, kernel: Kernel) -> None:
        self.k = kernel
        self.count = 0

    def expr(self, n: ast.expr, env: dict[str, str]) -> str:
        if isinstance(n, ast.BinOp):
            op = "**" if isinstance(n.op, ast.Pow) else _C_BINARY[type(n.op)]
            return f"({self.expr(n.left, env)} {op} {self.expr(n.right, env)})"
        if isinstance(n, ast.UnaryOp):
            if isinstance(n.op, ast.Not):
                return f"_np.logical_not({self.expr(n.operand, env)})"
            return f"({'-' if isinstance(n.op, ast.USub) else '+'}{self.expr(n.operand, env)})"
        if isinstance(n, ast.BoolOp):
            fn = "_np.logical_and" if isinstance(n.op, ast.And) else "_np.logical_or"
            out = self.expr(n.values[0], env)
            for v in n.values[1:]:
                out = f"{fn}({out}, {self.expr(v, env)})"
            return out
        if isinstance(n, ast.Compare):
            return (f"({self.expr(n.left, env)} {_C_COMPARE[type(n.ops[0])]} "
                    f"{self.expr(n.comparators[0], env)})")
        if isinstance(n, ast.IfExp):
            return (f"_np.where({self.expr(n.test, env)}, {self.expr(n.body, env)}, "
                    f"{self.expr(n.orelse, env)})")
        if isinstance(n, ast.Constant):
            return repr(float(n.value)) if not isinstance(n.value, bool) else repr(n.value)
        if isinstance(n, ast.Attribute):
            return repr(MATH_CONSTANTS[n.attr]).replace("inf", "_np.inf")
        if isinstance(n, ast.Name):
            return env[n.id] if n.id in env else repr(self.k.constants[n.id])
        if isinstance(n, ast.Call):
            args = ", ".join(self.expr(a, env) for a in n.args)
            if isinstance(n.func, ast.Attribute):
                return f"_np.{n.func.attr}({args})"
            if n.func.id in ("min", "max"):
                return f"_py_{n.func.id}({args})"
            return f"_{n.func.id}({args})"
        raise _fail(n, f"no numpy for {type(n).__name__}")

    def temp(self, name: str) -> str:
        self.count += 1
        return f"{name}_{self.count}"

    def statements(self, body: list[ast.stmt], env: dict[str, str], lines: list[str],
                   pad: str) -> dict[str, str]:
        env = dict(env)
        for s in body:
            if isinstance(s, ast.Assign):
                t = s.targets[0]
                value = self.expr(s.value, env)
                targets = [t] if isinstance(t, ast.Name) else t.elts
                temps = [self.temp(e.id) for e in targets]
                lines.append(f"{pad}{', '.join(temps)}{',' if len(temps) > 1 else ''} = {value}")
                env.update({e.id: tmp for e, tmp in zip(targets, temps)})
            elif isinstance(s, ast.If):
                test = self.temp("test")
                lines.append(f"{pad}{test} = {self.expr(s.test, env)}")
                yes = self.statements(s.body, env, lines, pad)
                no = self.statements(s.orelse, env, lines, pad)
                for name in dict.fromkeys([*yes, *no]):
                    if yes.get(name) == no.get(name):
                        continue
                    if name not in yes or name not in no:
                        raise _fail(s, f"{name} is assigned on one side of the branch only "
                                       "and not before it")
                    merged = self.temp(name)
                    lines.append(f"{pad}{merged} = _np.where({test}, {yes[name]}, {no[name]})")
                    env[name] = merged
            else:
                value = s.value
                parts = value.elts if isinstance(value, ast.Tuple) else [value]
                lines.append(f"{pad}return {', '.join(self.expr(p, env) for p in parts)}")
        return env

    def function(self, f: Function) -> str:
        lines = [f"def _{f.name}({', '.join(name for name, _ in f.args)}):"]
        self.statements(_docstring_free(f.tree.body), {n: n for n, _ in f.args}, lines, "    ")
        return "\n".join(lines)


def numpy_source(module: types.ModuleType = kernel_module) -> str:
    """The kernel as numpy array functions ``_<name>`` (the module docstring)."""
    k = parse(module)
    gen = _Numpy(k)
    return "\n\n".join(gen.function(f) for f in k.functions.values()) + "\n"


def _py_max(a, b):
    return np.where(b > a, b, a)


def _py_min(a, b):
    return np.where(b < a, b, a)


def _quiet(fn):
    @functools.wraps(fn)
    def call(*args):
        with np.errstate(all="ignore"):  # both sides of a branch are evaluated everywhere
            return fn(*args)
    return call


@functools.cache
def array_kernel(module: types.ModuleType = kernel_module) -> types.SimpleNamespace:
    """The kernel's functions on numpy arrays (or numbers), by the kernel's names."""
    namespace: dict = {"_np": np, "_py_max": _py_max, "_py_min": _py_min}
    exec(compile(numpy_source(module), f"<{module.__name__} as numpy>", "exec"), namespace)
    return types.SimpleNamespace(**{name: _quiet(namespace[f"_{name}"])
                                    for name in parse(module).functions})
