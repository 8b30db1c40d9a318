"""The package's layout: dependencies point one way, from the physics up to the command line.

Every `wpam_mj` import of every module (lazy ones inside functions included) is read from
the source, so the test fails on the first import that points up a layer.
"""

from __future__ import annotations

import ast
from pathlib import Path

import wpam_mj

PACKAGE = Path(wpam_mj.__file__).parent

# Lowest first; a module may import from its own layer and the ones below it. The modules
# directly in wpam_mj/ are the base: the paper's numbers, units, errors, paths, number formatting,
# the version (the package's __init__, its flat public face, sits on top).
LAYERS = (
    ("units", "errors", "paper", "paths", "display", "version"),
    ("physics",),
    ("control",),
    ("infra",),
    ("simulation",),
    ("experiments",),
    ("fitting", "design", "visualisation"),
    ("reproduction", "environments"),
    ("cli",),
    ("__init__", "__main__"),
)
RANK = {part: rank for rank, parts in enumerate(LAYERS) for part in parts}


def _part(module: str) -> str:
    """The layer part of "wpam_mj.<part>[.<module>]" ("__init__" for the package)."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else "__init__"


def _imports(path: Path) -> set[str]:
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0 \
                and node.module.split(".")[0] == "wpam_mj":
            found |= ({f"wpam_mj.{a.name}" for a in node.names} if node.module == "wpam_mj"
                      else {node.module})
        elif isinstance(node, ast.Import):
            found |= {a.name for a in node.names if a.name.split(".")[0] == "wpam_mj"}
    return found


def _module(path: Path) -> str:
    rel = path.relative_to(PACKAGE.parent).with_suffix("")
    return ".".join(rel.parts[:-1] if rel.name == "__init__" else rel.parts)


def test_every_module_sits_in_a_layer():
    parts = {_part(_module(p)) for p in PACKAGE.rglob("*.py")}
    assert parts <= set(RANK), f"modules outside every layer: {sorted(parts - set(RANK))}"


def test_dependencies_point_down_the_layers():
    upward = []
    for path in sorted(PACKAGE.rglob("*.py")):
        module = _module(path)
        own = RANK[_part(module)]
        for imported in _imports(path):
            if imported.startswith("wpam_mj.models"):
                continue  # package data
            if RANK.get(_part(imported), own) > own:
                upward.append(f"{module} imports {imported}")
    assert not upward, "imports pointing up a layer:\n" + "\n".join(upward)


def test_the_physics_imports_nothing_above_the_paper():
    """The force law, the pneumatics and the parameters stand alone: a reader checks the
    physics without reading anything else of the package."""
    for path in (PACKAGE / "physics").glob("*.py"):
        above = {i for i in _imports(path) if RANK.get(_part(i), 0) > RANK["physics"]}
        assert not above, f"{_module(path)} imports {sorted(above)}"
