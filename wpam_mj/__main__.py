"""`python -m wpam_mj ...` runs the `wpam` command line."""

import sys

from wpam_mj.cli import main

sys.exit(main())
