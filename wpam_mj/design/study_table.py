"""A study's table on disk: one part file per finished batch (so an interrupted study
resumes), and the table assembled from them in run order (CSV, and Parquet with pyarrow)."""

from __future__ import annotations

import csv
import json
from pathlib import Path
from typing import Any, Mapping

from wpam_mj.design.study_spec import FLAGS, StudySpec, input_column
from wpam_mj.infra.files import csv_text, write_atomic, write_text_atomic
from wpam_mj.errors import ParameterError

PARTS = "parts"  # folder of finished batches in the output folder
TABLE = "study"  # study.csv, study.parquet


def column_kinds(spec: StudySpec) -> dict[str, type]:
    kinds: dict[str, type] = {c: float for c in spec.columns}
    kinds.update(run=int, error=str, **dict.fromkeys(FLAGS, bool))
    kinds[input_column("controller").column] = str
    return kinds


def _read_part(path: Path, kinds: Mapping[str, type]) -> list[dict[str, Any]]:
    parse = {int: int, float: float, str: str, bool: lambda s: s == "true"}
    with open(path, newline="") as fh:
        return [{k: parse[kinds[k]](v) for k, v in row.items()} for row in csv.DictReader(fh)]


def start_parts(out: Path, spec: StudySpec, resume: bool) -> Path:
    """The part folder, emptied unless resuming the same study (checked by digest)."""
    parts = out / PARTS
    stamp = parts / "study.json"
    if resume and stamp.exists():
        if json.loads(stamp.read_text()).get("digest") != spec.digest():
            raise ParameterError(f"--resume: {out} holds the parts of a different study "
                                 "(the study file changed); use another --out")
        return parts
    parts.mkdir(parents=True, exist_ok=True)
    for old in parts.glob("runs_*.csv"):
        old.unlink()
    write_text_atomic(stamp, json.dumps({"digest": spec.digest()}) + "\n")
    return parts


def finished_rows(parts: Path, kinds: Mapping[str, type]) -> dict[int, dict[str, Any]]:
    rows: dict[int, dict[str, Any]] = {}
    for path in sorted(parts.glob("runs_*.csv")):
        rows.update((row["run"], row) for row in _read_part(path, kinds))
    return rows


def write_tables(out: Path, spec: StudySpec, rows: list[dict[str, Any]]) -> list[Path]:
    columns = spec.columns
    written = [write_text_atomic(out / f"{TABLE}.csv", csv_text(rows, columns))]
    try:
        import pyarrow as pa  # noqa: PLC0415 (optional: pip install ".[parquet]")
        import pyarrow.parquet as pq  # noqa: PLC0415
    except ImportError:
        return written
    table = pa.table({c: [row[c] for row in rows] for c in columns})
    written.append(write_atomic(out / f"{TABLE}.parquet",
                                lambda p: pq.write_table(table, p)))
    return written
