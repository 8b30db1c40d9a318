"""The README's newcomer path: its commands run from a new shell, its snippets run as shown."""

from __future__ import annotations

import os
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

from readme_blocks import README, blocks

ROOT = README.parent
SNIPPETS = blocks("python")


def test_readme_has_the_two_commands_and_snippets() -> None:
    assert len(blocks("bash", "Two commands")) == 2
    assert SNIPPETS, "no ```python block found in README.md"


def _programs(command: str) -> list[tuple[str, bool]]:
    """(program, activated before it) for each `&&`-joined part of a shell command."""
    activated, out = False, []
    for part in command.split("&&"):
        words = shlex.split(part)
        if words[:2] in (["source", ".venv/bin/activate"], [".", ".venv/bin/activate"]):
            activated = True
        else:
            out.append((words[0], activated))
    return out


@pytest.mark.parametrize("command", [b.strip() for b in blocks("bash", "Two commands")])
def test_two_commands_need_no_earlier_activation(command: str) -> None:
    """Each command block works from a new shell: it calls python3 (to make the venv) or
    the venv's own programs, or activates the venv itself first."""
    for program, activated in _programs(command):
        assert program == "python3" or program.startswith(".venv/bin/") or activated, \
            f"{program!r} in {command!r} is not on PATH in a new shell"


@pytest.mark.parametrize("index", range(len(SNIPPETS)))
def test_readme_python_snippet_runs(index: int, tmp_path: Path) -> None:
    """Every ```python block of README.md runs as printed, in a fresh interpreter in an
    empty folder (files it writes land there)."""
    env = {**os.environ, "PYTHONPATH": str(ROOT), "MUJOCO_GL": os.environ.get("MUJOCO_GL",
                                                                              "egl")}
    proc = subprocess.run([sys.executable, "-c", SNIPPETS[index]], cwd=tmp_path, env=env,
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, f"README snippet {index + 1} failed:\n{proc.stderr[-3000:]}"
