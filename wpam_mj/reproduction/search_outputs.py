"""What `wpam search` writes: the best compromise of a search's archive (best.toml,
best.txt), how it converged (convergence.csv, .png) and its feasibility map
(feasibility.md, .png; `wpam_mj.reproduction.findings_map`).
"""

from __future__ import annotations

import json
import os
import resource
from pathlib import Path
from typing import Sequence

from wpam_mj.fitting import estimation
from wpam_mj.infra.files import write_text_atomic
from wpam_mj.physics.params import Params, preset
from wpam_mj.errors import ParameterError
from wpam_mj.reproduction import findings_map
from wpam_mj.reproduction.search import (GLOBAL, PointJournal, Point, Region, check_same_search,
                                         convergence, point_of, region_of, search,
                                         search_settings)
from wpam_mj.reproduction.search_scoring import (OBJECTIVE_TEXT, OBJECTIVES, PAPER_CHECKS,
                                                 Record)
from wpam_mj.reproduction.static_fit import STATIC_FIT


def describe_point(u: Sequence[float], base: Params, region: Region = GLOBAL) -> str:
    """The point's values, one per line (display units)."""
    p = point_of(u, base, region)
    lines = [f"  {k:<34s} {v:.6g}" if isinstance(v, float) else f"  {k:<34s} {v}"
             for k, v in p.values().items()]
    return "\n".join(lines + [f"  protocol: {p.protocol.describe()}"])


def at_bounds(u: Sequence[float], base: Params, region: Region = GLOBAL,
              tol: float = 1e-3) -> list[str]:
    """The searched and statically fitted values within `tol` (of their range) of a
    bound of their range."""
    point = point_of(u, base, region)
    near = [d.name for d, x in zip(region.dims, u) if x <= tol or x >= 1.0 - tol]
    for name in STATIC_FIT:
        z = estimation.FreeParameter.of(name).to_z(point.params.value(name))
        if z <= tol or z >= 1.0 - tol:
            near.append(name)
    return near


def write_search(out: Path, **kw) -> list[Path]:
    """`search` into `out`, then `write_outputs` of its archive."""
    load0, cpu0 = os.getloadavg()[0], _cpu_seconds()
    r = search(out, **kw)
    timing = (f"{r.evaluations} points in {r.seconds / 60:.1f} min wall, "
              f"{(_cpu_seconds() - cpu0) / 60:.1f} CPU-min (load average {load0:.2f} at "
              f"the start, {os.getloadavg()[0]:.2f} at the end); {r.message}")
    return write_outputs(out, r.records, kw.get("base") or preset("wpam"), timing,
                         kw.get("objective", "cost"), r.region)


def write_map(out: Path, base: Params, objective: str = "cost",
              free: Sequence[str] | None = None, radius: float | None = None) -> list[Path]:
    """`write_outputs` of the points journaled in `out` so far (`wpam search --map-only`),
    refused where there is no journal, no point in it, or it is of another region or base
    point than `free` and `base` say (`radius` is only checked: `region_of`)."""
    region, _ = region_of(free, radius)
    journal = PointJournal(Path(out) / "journal.jsonl", keep=True)
    check_same_search(journal, search_settings(
        base, None if free is None else region.names), "--map-only", ("free", "base"))
    if not journal.records:
        raise ParameterError(f"--map-only: the journal {journal.path} holds no point yet")
    return write_outputs(out, list(journal.records.values()), base, objective=objective,
                         region=region)


def _cpu_seconds() -> float:
    """CPU time of this process and its finished workers [s] (the machine is shared:
    wall time alone says more about the others' load than about the search)."""
    own, kids = resource.getrusage(resource.RUSAGE_SELF), \
        resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


def write_outputs(out: Path, records: Sequence[Record], base: Params,
                  timing: str = "", objective: str = "cost",
                  region: Region = GLOBAL) -> list[Path]:
    """The best compromise of `records` under `objective` (best.toml, best.txt), how the
    search converged (convergence.csv, convergence.png) and their feasibility map
    (feasibility.md, feasibility.png) in `out`."""
    conv = convergence(records, objective)
    written = [write_text_atomic(out / "convergence.csv", findings_map.convergence_csv(conv)),
               findings_map.convergence_figure(
                   {out.name: conv}, out / "convergence.png",
                   f"Convergence of the search: {len(records)} points, "
                   f"{sum(r.margins is not None for r in records)} simulated",
                   OBJECTIVE_TEXT[objective])]
    if not any(r.tracks for r in records):
        return written  # nothing simulated tracks its targets: no map to draw
    pm = findings_map.pair_margins(records)
    best = findings_map.best_compromise(records, OBJECTIVES[objective])
    most = findings_map.most_findings(records)
    return written + [
            write_text_atomic(out / "best.toml", point_toml(point_of(best.u, base, region))),
            write_text_atomic(out / "best.txt", summary(timing, best, base, region) + "\n"
                              + "the point meeting the most findings:\n"
                              + summary("", most, base, region)),
            write_text_atomic(out / "feasibility.md", findings_map.markdown(pm, records)
                              + "\n\n" + findings_map.verdict(pm) + "\n\n"
                              + findings_map.rest_verdict(records) + "\n"),
            findings_map.figure(pm, out / "feasibility.png",
                                f"Feasibility of the paper's findings: {len(records)} "
                                "points of the credible box and protocol readings")]


def point_toml(point: Point) -> str:
    """The point's parameter values as a `--config` TOML and its protocol as comments."""
    sections: dict[str, list[str]] = {}
    for name, v in point.values().items():
        if not name.startswith("protocol."):
            s, n = name.split(".")
            sections.setdefault(s, []).append(f"{n} = {float(v)!r}")
    out = ["# Found by `wpam search` (wpam_mj/reproduction/search.py); SI units.",
           f"# protocol: {point.protocol.describe()}", ""]
    for s, lines in sections.items():
        out += [f"[{s}]", *lines, ""]
    return "\n".join(out)


def summary(timing: str, best: Record, base: Params, region: Region = GLOBAL) -> str:
    """A point of the search and its findings (plain text)."""
    return (f"{timing}\n" * bool(timing)
            + f"cost {best.cost:.4f}, {best.held} of the {len(PAPER_CHECKS)} checks of "
            "`wpam reproduce` met\n"
            + describe_point(best.u, base, region)
            + f"\nat a bound: {', '.join(at_bounds(best.u, base, region)) or 'none'}"
            + "\nmargins:\n" + "\n".join(f"  {k:<24s} {v:+.3f}"
                                         for k, v in (best.margins or {}).items())
            + f"\nfigures: {json.dumps(best.figures)}\n")
