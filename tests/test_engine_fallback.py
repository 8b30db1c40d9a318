"""Where the plugin cannot be built (no compiler; here: WPAM_MJ_NO_COMPILE=1), the Python
engine runs everything, and a model compiled directly refuses to run without its muscle."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

SCRIPT = textwrap.dedent("""
    import mujoco, numpy as np
    import wpam_mj
    from wpam_mj import preset
    from wpam_mj.simulation import plugin
    from wpam_mj.environments.dm_env_task import make_env
    from wpam_mj.experiments.drives import step_run
    from wpam_mj.paths import MODEL_XML
    assert not plugin.available()
    run = step_run(preset(), 100.0, "pi", levels_mm=(0, 10), hold=2.0)
    assert abs(run.x[-1] - 0.010) < 1e-3, run.x[-1]
    env = make_env(seed=0, load=100.0)
    env.reset()
    assert np.isfinite(env.step([0.02e6]).observation["x_m"][0])
    try:
        mujoco.MjModel.from_xml_path(str(MODEL_XML))
    except ValueError:
        print("refused")
""")


def test_without_the_plugin_the_python_engine_runs_and_plain_compiles_refuse():
    env = {**os.environ, "WPAM_MJ_NO_COMPILE": "1"}
    proc = subprocess.run([sys.executable, "-c", SCRIPT], env=env, capture_output=True,
                          text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "refused"
    assert "load it on the Python engine instead: model, muscles = " in proc.stderr
