"""How `wpam` reads its arguments: the parser, argument types, and the options several
commands share (model and run options, output folder, ramp time, protocol readings)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any, Callable, Sequence

from wpam_mj.errors import ParameterError
from wpam_mj.experiments.drives import STATIC_RAMP_S
from wpam_mj.experiments.protocol import LOOP_METHODS, SHIPPED
from wpam_mj.infra import pool
from wpam_mj.physics.muscle_types import MUSCLE_TYPES
from wpam_mj.physics.params import PRESETS
from wpam_mj.units import MPA

# --gain-reading: controller.command_scale [MPa/u] (docs/physics.md, the unitless gains)
GAIN_READINGS = {"mpa-per-mm": 1.0, "volts-5": 0.1, "volts-10": 0.05}
JOBS_PER_CPU = 4  # --jobs above this many per CPU is refused: no run gains from it
JOBS_HELP = (f"cores [count]: the runs on as many mujoco.batch threads, figures and files "
             f"on as many processes; 1 to {JOBS_PER_CPU} per CPU (default: the "
             f"number of CPUs, {pool.default_jobs()}); never more than the command has "
             "runs; results do not depend on it")


def scheduler_option(p: argparse.ArgumentParser) -> None:
    """--scheduler ADDRESS: run on a Dask cluster instead of --jobs local cores."""
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="run on the Dask cluster of this scheduler, e.g. tcp://host:8786 "
                        f"(default: ${pool.SCHEDULER_ENV} if set, else this machine; "
                        "docs/cluster.md)")


class UsageError(Exception):
    """Bad command-line arguments: exit status 2."""


class Parser(argparse.ArgumentParser):
    """Reports errors as one line through `main` instead of usage text + SystemExit."""

    def error(self, message: str):  # type: ignore[override]
        raise UsageError(message)


def float_list(text: str) -> tuple[float, ...]:
    try:
        values = tuple(float(v) for v in text.split(",") if v.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"{text!r} is not a comma-separated list of numbers") from None
    if not values:
        raise argparse.ArgumentTypeError("empty list")
    return _once(text, values)


def name_list(text: str) -> tuple[str, ...]:
    return _once(text, tuple(v.strip() for v in text.split(",") if v.strip()))


def named_values(items: Sequence[str], option: str, expected: str,
                 parse: Callable[[str], Any] = float) -> dict[str, Any]:
    """NAME=VALUE items as {name: parse(VALUE)}; an item that does not parse is refused
    in one line: "`option` 'item': expected `expected`"."""
    out = {}
    for item in items:
        name, _, text = item.partition("=")
        try:
            out[name.strip()] = parse(text)
        except ValueError:
            raise ParameterError(f"{option} {item!r}: expected {expected}") from None
    return out


def _once(text: str, values: tuple) -> tuple:
    """`values`, refused when one is repeated (each sweep point is run once)."""
    repeated = [v for i, v in enumerate(values) if v in values[:i]]
    if repeated:
        raise argparse.ArgumentTypeError(f"{text!r} repeats {repeated[0]!r}; give each "
                                         "value once")
    return values


def ramp_top(text: str) -> float:
    """--ramp-top: "per-load" (0) or a Pi [MPa], returned in Pa."""
    if text == "per-load":
        return 0.0
    try:
        return float(text) * MPA
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is neither per-load nor a number") from None


def out_path(text: str) -> Path:
    """An --out path; the empty string is refused (Path("") would mean the current folder)."""
    if not text.strip():
        raise argparse.ArgumentTypeError(f"{text!r} is empty; give a folder or file name")
    return Path(text)


def frame_size(text: str) -> tuple[int, int]:
    try:
        w, h = text.lower().split("x")
        return int(w), int(h)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not WIDTHxHEIGHT, e.g. 640x480") \
            from None


def common_options() -> argparse.ArgumentParser:
    common = Parser(add_help=False)
    g = common.add_argument_group("model and run options")
    g.add_argument("--preset", choices=PRESETS, default="wpam",
                   help="muscle type: " + ", ".join(f"{t.name} ({t.brief})"
                                                    for t in MUSCLE_TYPES.values())
                   + " (default: wpam)")
    g.add_argument("--dt", type=float, default=1e-3, metavar="S",
                   help="physics time step [s] (default: 0.001)")
    g.add_argument("--config", type=Path, metavar="FILE.toml",
                   help="parameter overrides: TOML with sections braid, muscle, "
                        "pneumatics, controller; SI values (m, Pa, N, s)")
    g.add_argument("--jobs", type=int, default=pool.default_jobs(), metavar="N",
                   help=JOBS_HELP)
    g.add_argument("--progress", action=argparse.BooleanOptionalAction, default=None,
                   help="progress bars on stderr (default: when stderr is a terminal)")
    return common


def out_dir_option(p: argparse.ArgumentParser, name: str) -> None:
    p.add_argument("--out", type=out_path, metavar="DIR",
                   help=f"output folder (default: out/{name} under the current folder)")

def ramp_time_option(p: argparse.ArgumentParser) -> None:
    p.add_argument("--ramp-time", type=float, default=STATIC_RAMP_S, metavar="S",
                   help="duration of each open-loop Pi ramp, up and then down [s], "
                        f"1-3600 (default: {STATIC_RAMP_S:g}; the paper does not state "
                        "its own)")

def json_option(p: argparse.ArgumentParser, what: str) -> None:
    p.add_argument("--json", action="store_true", help=f"print {what} on stdout")

def loop_area_option(p) -> None:  # a parser or an argument group
    p.add_argument("--loop-area", choices=LOOP_METHODS, default=None,
                   help="loop area of the open-loop ramps: branches (every lobe of a "
                        "crossing loop counts) or shoelace (signed: lobes cancel) "
                        f"(default: the shipped {SHIPPED.loop_method})")

def protocol_options(p: argparse.ArgumentParser) -> None:
    """The readings the paper does not state (`wpam_mj.experiments.protocol`,
    docs/physics.md)."""
    g = p.add_argument_group("protocol readings (the paper does not state them; "
                             "defaults: the shipped reading)")
    g.add_argument("--ramp-top", type=ramp_top, default=None, metavar="per-load|MPA",
                   help="top of the open-loop Pi ramps: per-load (the Pi whose "
                        "contracting branch reaches 50 mm) or one Pi [MPa] for every load")
    g.add_argument("--top-hold", type=float, default=None, metavar="S",
                   help="seconds Pi is held at its top with Po on before it falls "
                        "(0: Po switched on as Pi starts to fall)")
    loop_area_option(g)
    g.add_argument("--po-feedforward", type=float, default=None, metavar="MPA",
                   help="the Po [MPa] the Pi feedforward assumes "
                        "(controller.po_feedforward)")
    g.add_argument("--feedforward-friction", type=float, default=None, metavar="PHI",
                   help="the share of the friction band the Pi feedforward adds "
                        "(controller.feedforward_friction; 1: eq. 5's contracting branch)")
    g.add_argument("--gain-reading", choices=tuple(GAIN_READINGS), default=None,
                   help="unit of the paper's unitless gains: " + ", ".join(
                       f"{k} ({v:g} MPa/u)" for k, v in GAIN_READINGS.items()))


def feedforward_model_option(p: argparse.ArgumentParser, default: str,
                             ramp_time: bool = True) -> None:
    """--feedforward-model, and --calibration-ramp-time where the command runs ramps of
    its own to fit it to (`ramp_time`; the search fits it to Table 2's own loops)."""
    from wpam_mj.reproduction.feedforward_fit import FEEDFORWARD_MODELS  # noqa: PLC0415
    p.add_argument("--feedforward-model", choices=FEEDFORWARD_MODELS, default=default,
                   help="the controller's equilibrium model (the Pi feedforward): calibrated, "
                        "fitted to the plant's own open-loop loops (Figs. 8-9; a sampled "
                        "plant's own) as the paper's experimenter fits it; or nominal, the "
                        "parameters' own values, a controller that knows the plant exactly "
                        f"(default: {default})")
    if not ramp_time:
        return
    p.add_argument("--calibration-ramp-time", type=float, default=None, metavar="S",
                   help="duration of each open-loop ramp the calibrated model is fitted to "
                        "[s] (default: the static ramps' own, --ramp-time where the command "
                        "takes it)")
