"""Entry points that cannot rot: every benchmark and script imports, `benchmarks/run_all.py
--quick` runs, every repository path a document cites exists, and every figure in the
documents names the command that makes it."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

from wpam_mj.cli import main

ROOT = Path(__file__).resolve().parents[1]
ENTRY_POINTS = sorted([*ROOT.glob("benchmarks/*.py"), *ROOT.glob("scripts/*.py")])
# extras a script may need that the test environment need not have (pyproject.toml)
OPTIONAL = {"torch", "stable_baselines3", "warp", "mujoco_warp"}
DOCS = sorted([*ROOT.glob("*.md"), *ROOT.glob("docs/*.md"), *ROOT.glob("models/**/*.md"),
               *ROOT.glob("examples/**/*.md")])
TOP = {"benchmarks", "docs", "examples", "models", "scripts", "tests", "wpam_mj"}
SUBPACKAGES = {p.name for p in (ROOT / "wpam_mj").iterdir() if p.is_dir()}
CITED = re.compile(r"(?<![\w/.-])((?:[\w.-]+/)+[\w.-]+\.(?:py|md|toml|xml|png|csv|json|sh|c|h"
                   r"|ya?ml|txt|gif|mp4|stl|obj))(?![\w/])")
LINK = re.compile(r"\]\(([^)#\s]+)")
IMAGE = re.compile(r"^!\[[^\]]*\]\(([^)\s]+)\)")
COMMAND = re.compile(r"`(?:wpam (\w+)|python (?:scripts|benchmarks)/[\w.]+\.py)[^`]*`")

IMPORT_ALL = """
import importlib.util, sys
failed = []
for path in sys.argv[1:]:
    sys.path.insert(0, str(__import__("pathlib").Path(path).parent))
    name = "entry_" + path.replace("/", "_")[:-3]
    spec = importlib.util.spec_from_file_location(name, path)
    sys.modules[name] = module = importlib.util.module_from_spec(spec)
    try:
        spec.loader.exec_module(module)
    except ModuleNotFoundError as err:
        if err.name.split(".")[0] not in {optional}:
            failed.append(f"{{path}}: {{err!r}}")
    except BaseException as err:  # noqa: BLE001 (a script that runs or exits on import)
        failed.append(f"{{path}}: {{err!r}}")
    sys.path.pop(0)
print("\\n".join(failed))
sys.exit(1 if failed else 0)
"""


def test_every_benchmark_and_script_imports_without_running():
    """Before: benchmarks/run_all.py and bench_search.py failed at import (`plugin` was
    gone from `execution`) and nothing noticed."""
    proc = subprocess.run([sys.executable, "-c", IMPORT_ALL.format(optional=OPTIONAL),
                           *map(str, ENTRY_POINTS)], capture_output=True, text=True,
                          timeout=300, cwd=ROOT)
    assert proc.returncode == 0, proc.stdout + proc.stderr[-2000:]


def test_run_all_quick_runs_every_benchmark():
    proc = subprocess.run([sys.executable, "benchmarks/run_all.py", "--quick"],
                          capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert proc.returncode == 0, proc.stdout + proc.stderr[-2000:]
    assert "every benchmark ran" in proc.stdout
    for name in ("plugin step", "batch", "vector env", "sweep", "search"):
        assert name in proc.stdout, proc.stdout


def test_the_batch_benchmark_runs_its_process_pool_comparison():
    """run_all leaves the pool out; its own command times it too (it read a field a Run
    no longer has, which --quick could not see)."""
    proc = subprocess.run([sys.executable, "benchmarks/bench_batch.py", "--runs", "2",
                           "--duration", "0.2", "--repeats", "1"],
                          capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert "Traceback" not in proc.stderr, proc.stderr[-2000:]
    assert "process pool of 2" in proc.stdout, proc.stdout


def _cited(doc: Path) -> set[str]:
    """Repository paths `doc` cites that do not exist: `folder/file.ext` from the
    repository root (a sub-package's path from wpam_mj/), and relative links."""
    text, missing = doc.read_text(), set()
    for m in CITED.finditer(text):
        path = m.group(1)
        first = path.split("/")[0]
        if first in TOP and not (ROOT / path).exists() or \
                first in SUBPACKAGES and not (ROOT / "wpam_mj" / path).exists():
            missing.add(path)
    for m in LINK.finditer(text):
        target = m.group(1)
        if "://" not in target and not target.startswith("mailto:") and \
                not (doc.parent / target).exists():
            missing.add(target)
    return missing


@pytest.mark.parametrize("doc", DOCS, ids=lambda p: str(p.relative_to(ROOT)))
def test_every_path_a_document_cites_exists(doc):
    """Before: docs/physics.md and models/README.md cited scripts/itv_models.py, which
    never existed."""
    assert not _cited(doc)


def test_the_cited_path_check_finds_a_missing_path(tmp_path):
    doc = tmp_path / "x.md"
    doc.write_text("See `scripts/itv_models.py`, [here](nowhere.md) and "
                   "`simulation/execution.py`.\n")
    assert _cited(doc) == {"scripts/itv_models.py", "nowhere.md"}


def _figures(doc: Path) -> list[tuple[str, str | None]]:
    """Each image of `doc` and the command on its line or the next, if any."""
    lines = doc.read_text().splitlines()
    out = []
    for i, line in enumerate(lines):
        m = IMAGE.match(line)
        if m:
            beside = COMMAND.search(" ".join(lines[i:i + 2]))
            out.append((m.group(1), beside.group(0) if beside else None))
    return out


@pytest.mark.parametrize("doc", [d for d in DOCS if _figures(d)],
                         ids=lambda p: str(p.relative_to(ROOT)))
def test_every_figure_names_the_command_that_makes_it(doc, capsys):
    for image, command in _figures(doc):
        assert command is not None, f"{image}: no `wpam ...` or `python scripts/...` beside it"
        sub = COMMAND.match(command).group(1)
        if sub is not None:  # a real subcommand
            assert main([sub, "--help"]) == 0, command
    capsys.readouterr()
