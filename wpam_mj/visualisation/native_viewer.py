"""MuJoCo's own interactive viewer on any MJCF that uses the wpam_mj.muscle plugin.

    python -m wpam_mj.visualisation.native_viewer models/arm/arm.xml

is ``python -m mujoco.viewer --mjcf=FILE`` with the plugin registered: MuJoCo's viewer
loads only the plugins shipped in its wheel, and running this module imports wpam_mj,
which registers ours. The muscle's input channels are the
actuator sliders of the Control panel; the viewer needs a display.
"""

from __future__ import annotations

import sys

import mujoco.viewer


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    if len(args) != 1 or args[0].startswith("-"):
        print("usage: python -m wpam_mj.visualisation.native_viewer MODEL.xml", file=sys.stderr)
        return 2
    mujoco.viewer.launch_from_path(args[0])
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
