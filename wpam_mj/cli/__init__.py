"""`wpam`, the command line: `main` runs it, `build_parser` is its parser.

One module per group of commands, each with its parsers and its handlers (experiments,
reproduction, pictures, design, fitting); `arguments` reads the arguments, `runs` holds
what every command shares once they are read, `main` puts them together. A signal while
they are imported ends the command with one line and its status, as one during it does.
"""

from wpam_mj.infra.termination import importing

with importing("wpam"):
    from wpam_mj.cli.arguments import JOBS_PER_CPU
    from wpam_mj.cli.main import build_parser, main

__all__ = ["JOBS_PER_CPU", "build_parser", "main"]
