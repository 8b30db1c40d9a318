"""The README's still (docs/still.png): a frame of the hung W-PAM at 50 mm under 100 N.

The paper's PI staircase (`wpam step --load 100 --control pi`) on the shipped plant,
drawn in the middle of its 50 mm plateau, t = 55 s, by
`wpam_mj.visualisation.render.still_frame` (640x480, the front camera).

    python scripts/readme_still.py [--out docs/still.png]
"""

from __future__ import annotations

import argparse
from pathlib import Path

from wpam_mj import preset
from wpam_mj.experiments.drives import step_run
from wpam_mj.visualisation.render import still_frame

LOAD_N = 100.0
AT_S = 55.0  # s: the middle of the staircase's 50 mm plateau


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("docs") / "still.png")
    args = parser.parse_args(argv)
    params = preset("wpam")
    result = step_run(params, LOAD_N, "pi")
    print(f"wrote {still_frame(result, params, AT_S, args.out)}")


if __name__ == "__main__":
    main()
