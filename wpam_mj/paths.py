"""Where the shipped MJCF and parameter files live (one place for every caller).

`models/` sits at the top of the source tree; a regular install copies it into the
package as ``wpam_mj/models`` (see pyproject.toml), so look there first.
"""

from pathlib import Path

_PACKAGE_DIR = Path(__file__).resolve().parent


def _find_models() -> Path:
    for candidate in (_PACKAGE_DIR / "models", _PACKAGE_DIR.parent / "models"):
        if (candidate / "wpam" / "wpam.xml").is_file():
            return candidate
    raise FileNotFoundError(f"wpam-mj model files not found next to {_PACKAGE_DIR}")


MODELS_DIR = _find_models()
MODEL_XML = MODELS_DIR / "wpam" / "wpam.xml"
SCENE_XML = MODELS_DIR / "wpam" / "scene.xml"
