"""Frequency-response sweep (paper Figs. 17-19); same flags as `wpam sweep`.

Usage: python scripts/run_frequency_sweep.py --help
"""

import sys

from wpam_mj.cli import main as wpam_main


def main() -> int:
    return wpam_main(["sweep", *sys.argv[1:]])


if __name__ == "__main__":
    sys.exit(main())
