"""The documents that state numbers agree with the code that defines them."""

import subprocess
import sys
from pathlib import Path

from wpam_mj.params import describe_with_ranges, preset

ROOT = Path(__file__).resolve().parent.parent


def test_models_readme_parameter_table_is_current():
    proc = subprocess.run([sys.executable, str(ROOT / "scripts" / "param_table.py"), "--check"],
                          capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr


def test_shipped_values_lie_inside_their_plausible_ranges_and_off_the_bounds():
    """Calibration bounds are the plausible ranges; a fitted value pinned at a bound
    (within 1 % of the range) would have to be reported, and none is."""
    for name, value, _, plausible, _ in describe_with_ranges(preset("wpam")):
        if plausible is None:
            continue
        lo, hi = plausible
        assert lo <= value <= hi, f"{name} = {value} outside [{lo}, {hi}]"
        if name in ("muscle.damping", "pneumatics.time_constant", "pneumatics.dead_time"):
            continue  # measured or estimated, not fitted
        width = hi - lo
        assert lo + 0.01 * width < value < hi - 0.01 * width, f"{name} = {value} at a bound"
