"""`wpam`: the paper's experiments from the command line.

Subcommands (each has --help):
  static     open-loop Pi ramp up and down (paper Figs. 3, 8, 9)
  step       staircase target 0 -> 50 -> 0 mm (Figs. 12-15)
  table2     hysteresis-loop areas of Table 2, beside the paper's
  sweep      frequency response to a sinusoidal target (Figs. 17-19)
  reproduce  all of the above into one folder with report.md
  calibrate  fit the parameters the paper does not give
  search     global search of the credible box and the protocol readings, and the
             feasibility map of the paper's findings
  fit        fit the parameters to your own measured experiments (CSV)
  synth      synthetic measurements in that CSV format
  render     offscreen video of a simulated run
  view       MuJoCo's interactive viewer on the muscle, stepped live (needs a display)
  linear     the paper's §3 linear model beside the simulated frequency response
  study      a design-space study from a study file, on local processes or Dask

Units at this edge: loads in N, pressures in MPa, lengths in mm, times in s, frequencies
in Hz (the library is SI inside). Exit status: 0 success, 1 the run failed (simulation
diverged, rendering or file system error), 2 bad arguments (one line on stderr), 130
interrupted (Ctrl-C), 143 terminated (SIGTERM), 129 hung up (SIGHUP), 141 stdout closed
early (e.g. `| head`).
static, step, table2, sweep, linear, reproduce and render write `manifest-<run id>.json`
beside their files (`wpam_mj.infra.manifest`).
"""

from __future__ import annotations

import argparse
import os
import sys
from concurrent.futures import BrokenExecutor
from typing import Sequence

from wpam_mj.cli import design, experiments, fitting, pictures, reproduction
from wpam_mj.cli.arguments import Parser, UsageError, common_options
from wpam_mj.cli.runs import RunFailed
from wpam_mj.infra import outputs
from wpam_mj.infra.streams import reopen_closed
from wpam_mj.infra.termination import Interrupted, exit_now, handle_signals, stopped_by_signal
from wpam_mj.errors import ParameterError
from wpam_mj.simulation.simulate import SimulationDiverged
from wpam_mj.version import __version__


def _description() -> str:
    """The module docstring without its list of subcommands (argparse lists them)."""
    paragraphs = __doc__.split("\n\n")
    return "\n\n".join(p for p in paragraphs if not p.startswith("Subcommands"))


def build_parser() -> argparse.ArgumentParser:
    """The `wpam` parser: one subcommand per command, each group's from its module."""
    parser = Parser(prog="wpam", description=_description(),
                    formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--version", action="version", version=f"wpam-mj {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    common = [common_options()]

    def add(name: str, help_: str, handler) -> argparse.ArgumentParser:
        p = sub.add_parser(name, help=help_, description=help_, parents=common)
        p.set_defaults(handler=handler)
        return p

    experiments.add_parsers(add)
    reproduction.add_parsers(add)
    pictures.add_parsers(add)
    design.add_parsers(add, sub)
    fitting.add_parsers(add)
    return parser


def _one_line(err: BaseException) -> str:
    return " ".join(str(err).split()) or type(err).__name__


def main(argv: Sequence[str] | None = None) -> int:
    """Run the `wpam` command line; returns the exit status."""
    closed = reopen_closed()  # `wpam ... >&-`: before any file takes descriptor 1
    code = 1
    with handle_signals():  # also over the cleanup: a second signal cannot interrupt it
        try:
            code = _main(argv)
        finally:
            outputs.release(failed=code != 0)
    if code == 0 and "stdout" in closed:
        code = 141  # as for a reader gone before the first line (below)
    if argv is None and stopped_by_signal():  # the process's own command line
        exit_now(code)  # cleanup is done; skip the interpreter's ~1 s teardown
    return code


def _main(argv: Sequence[str] | None) -> int:
    parser = build_parser()
    args = None
    try:
        args = parser.parse_args(argv)
        args.argv = list(sys.argv[1:] if argv is None else argv)
        code = args.handler(args)
        sys.stdout.flush()  # a closed pipe shows here, not at interpreter exit
        return code
    except SystemExit as exc:  # --help, --version
        return exc.code if isinstance(exc.code, int) else 0
    except (UsageError, ParameterError) as err:
        print(f"wpam: error: {_one_line(err)}", file=sys.stderr)
        return 2
    except (SimulationDiverged, RunFailed, BrokenExecutor) as err:
        print(f"wpam: error: {_one_line(err)}", file=sys.stderr)
        return 1
    except BrokenPipeError:  # stdout piped into e.g. `head`, which has exited: quietly,
        # with the status a POSIX tool killed by SIGPIPE has (128 + 13)
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # no flush error
        return 141
    except OSError as err:
        print(f"wpam: error: {_one_line(err)}", file=sys.stderr)
        return 1
    except MemoryError:  # what the run budgets did not foresee: one line, no traceback
        what = f"wpam {args.command}" if args is not None else "wpam"
        print(f"wpam: error: {what} ran out of the memory this process may use (ulimit -v, "
              "or the machine's); give it smaller inputs or more memory", file=sys.stderr)
        return 1
    except KeyboardInterrupt as stop:  # SIGINT, SIGTERM, SIGHUP (`wpam_mj.infra.termination`)
        stop = stop if isinstance(stop, Interrupted) else Interrupted()
        print(f"wpam: {stop.message}", file=sys.stderr)
        return stop.status
