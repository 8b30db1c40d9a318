"""Staircase step experiment (paper Figs. 12-15); same flags as `wpam step`.

Usage: python scripts/run_step_experiment.py --help
"""

import sys

from wpam_mj.cli import main as wpam_main


def main() -> int:
    return wpam_main(["step", *sys.argv[1:]])


if __name__ == "__main__":
    sys.exit(main())
