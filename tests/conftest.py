"""Shared test setup.

Import wpam_mj first: it registers the muscle's MuJoCo plugin, which the shipped models
name (no GL backend is chosen on import: `wpam_mj.visualisation.gl` does that where
rendering starts).
"""

import wpam_mj  # noqa: F401
