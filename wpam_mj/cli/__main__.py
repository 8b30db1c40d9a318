"""`python -m wpam_mj.cli`: the `wpam` command line."""

import sys

from wpam_mj.cli import main

if __name__ == "__main__":
    sys.exit(main())
