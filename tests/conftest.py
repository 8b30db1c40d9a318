"""Shared test setup.

Import wpam_mj first: it registers the muscle's MuJoCo plugin, which the shipped models
name (no GL backend is chosen on import: `wpam_mj.visualisation.gl` does that where
rendering starts).
"""

import importlib

import pytest

import wpam_mj  # noqa: F401
from wpam_mj.simulation import warp_muscle


@pytest.fixture
def without_warp(monkeypatch):
    """Warp and MuJoCo Warp fail to import, as without the gpu extra."""
    real = importlib.import_module

    def missing(name, *args):
        if name in ("warp", "mujoco_warp"):
            raise ModuleNotFoundError(f"No module named '{name}'", name=name)
        return real(name, *args)

    monkeypatch.setattr(importlib, "import_module", missing)
    warp_muscle.require_warp.cache_clear()
    yield
    warp_muscle.require_warp.cache_clear()
