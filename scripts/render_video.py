"""Simulate a run and write an offscreen video; same flags as `wpam render`.

Usage: python scripts/render_video.py --help
"""

import sys

from wpam_mj.cli import main as wpam_main


def main() -> int:
    return wpam_main(["render", *sys.argv[1:]])


if __name__ == "__main__":
    sys.exit(main())
