"""MuJoCo's own interactive viewer on any MJCF that uses the wpam_mj.muscle plugin.

    python -m wpam_mj.visualisation.native_viewer models/arm/arm.xml

is ``python -m mujoco.viewer --mjcf=FILE`` with the plugin registered: MuJoCo's viewer
loads only the plugins shipped in its wheel, and running this module imports wpam_mj,
which registers ours. The muscle's input channels are the
actuator sliders of the Control panel; the viewer needs a display. Without one it says so
in one line before MuJoCo is asked for a window (MuJoCo's viewer would exit the process
from its window thread), and MuJoCo logs to the console only, never MUJOCO_LOG.TXT into
the working folder.
"""

from __future__ import annotations

import sys

import mujoco.viewer

from wpam_mj.errors import ParameterError, check_regular_file
from wpam_mj.visualisation.viewer import ViewerUnavailable, check_display, console_log_only

WHO = "python -m wpam_mj.visualisation.native_viewer"


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    if len(args) != 1 or args[0].startswith("-"):
        print(f"usage: {WHO} MODEL.xml", file=sys.stderr)
        return 2
    try:
        path = check_regular_file(args[0], "model file")
        check_display(WHO)
    except (ParameterError, ViewerUnavailable) as err:
        print(f"{WHO}: error: {err}", file=sys.stderr)
        return 2 if isinstance(err, ParameterError) else 1
    with console_log_only():
        mujoco.viewer.launch_from_path(str(path))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
