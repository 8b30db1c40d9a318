"""Run manifests: what produced the files in an output folder, as JSON beside them.

The CSVs hold data only (one header line, then numbers), so the run's metadata lives in
``manifest-<run id>.json`` in the same folder:

    {"run_id", "command", "argv", "wpam_mj_version", "versions" (python, mujoco, numpy),
     "settings" (what the command was asked: loads, control, dt, ...),
     "params" (every parameter, SI, by section, and the preset),
     "files": {name: {"sha256", "bytes", and per-file metadata such as load_n; and
               "overwritten_by": <run id> once a later run has rewritten the file}}}

The run id is a digest of what defines the results (version, command, settings,
parameters) and not of the time or the worker count, so a rerun writes the same bytes and
the same manifest. Each file records the run id: a PNG in its metadata (text chunk
``wpam_mj run_id``, see `png_metadata`), a video in its comment (`video_comment`), a CSV
through the SHA-256 the manifest keeps of it (a data column or a comment line would break
plain CSV readers). `check_files` tells
which files still are the ones a manifest describes: two runs writing into one folder at
the same time leave two manifests, and every file matches exactly one of them.
"""

from __future__ import annotations

import hashlib
import json
import os
import platform
import re
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

from wpam_mj.version import __version__
from wpam_mj.physics.params import Params
from wpam_mj.errors import ParameterError
from wpam_mj.infra.files import write_text_atomic

RUN_ID_KEY = "wpam_mj run_id"  # PNG text keyword; "<key> <id>" in video comments
_ID_LENGTH = 16  # hex digits of SHA-256: 64 bits, no collisions among a user's runs


def run_id(command: str, params: Params, settings: Mapping[str, Any]) -> str:
    """Digest of what defines a run's results: version, command, settings and parameters.

    `settings` must hold only result-defining values (load, control, dt, frequencies, ...),
    not --out, --jobs or --progress, so that equal runs get equal ids.
    """
    key = {"version": __version__, "command": command, "settings": _plain(settings),
           "params": _params_dict(params)}
    text = json.dumps(key, sort_keys=True, separators=(",", ":"), allow_nan=True)
    return hashlib.sha256(text.encode()).hexdigest()[:_ID_LENGTH]


def manifest_path(out_dir: str | Path, run: str) -> Path:
    return Path(out_dir) / f"manifest-{run}.json"


def write_manifest(out_dir: str | Path, run: str, command: str, params: Params,
                   files: Sequence[str | Path] | Mapping[str | Path, Mapping[str, Any]], *,
                   settings: Mapping[str, Any] | None = None,
                   argv: Sequence[str] | None = None) -> Path:
    """Write ``manifest-<run>.json`` into `out_dir` (atomically) and return its path.

    Args:
      out_dir: the run's output folder; every file must lie inside it.
      run: the run id (`run_id`).
      command: the subcommand, e.g. "step".
      params: the parameters the run used.
      files: the paths written (as returned by the writers: absolute or relative to the
        current folder), or {path: per-file metadata} (e.g. `SimResult.metadata()`).
      settings: the result-defining settings (as given to `run_id`).
      argv: the command line as typed, for people (not part of the id).
    """
    out_dir = Path(out_dir)
    entries = files if isinstance(files, Mapping) else {f: {} for f in files}
    listed = {}
    for f, meta in entries.items():
        name = _relative(out_dir, Path(f))  # the key in the manifest
        listed[name] = {**_plain(meta), **_digest(out_dir / name)}
    manifest = {
        "run_id": run,
        "command": command,
        "argv": list(argv) if argv is not None else None,
        "wpam_mj_version": __version__,
        "versions": {"python": platform.python_version(), "mujoco": mujoco.__version__,
                     "numpy": np.__version__},
        "settings": _plain(settings or {}),
        "params": _params_dict(params),
        "files": dict(sorted(listed.items())),
    }
    text = json.dumps(manifest, indent=2, allow_nan=False) + "\n"
    return write_text_atomic(manifest_path(out_dir, run), text)


def mark_overwritten(out_dir: str | Path, run: str) -> list[Path]:
    """In the other manifests of `out_dir`, mark each file that run `run` (whose manifest
    is written) has rewritten with other contents: ``"overwritten_by": run`` beside the
    SHA-256 it had, so that no manifest vouches for a file it no longer describes (runs
    into one folder take turns: `wpam_mj.infra.outputs`). Returns the manifests changed."""
    out_dir = Path(out_dir)
    ours = read_manifest(manifest_path(out_dir, run))["files"]
    changed = []
    for path in sorted(out_dir.glob("manifest-*.json")):
        if path == manifest_path(out_dir, run):
            continue
        try:
            other = read_manifest(path)
        except ParameterError:
            continue  # not a manifest of ours: left alone
        hits = [name for name, entry in other["files"].items() if name in ours
                and isinstance(entry, dict) and entry.get("sha256") != ours[name]["sha256"]
                and entry.get("overwritten_by") != run]
        if hits:
            for name in hits:
                other["files"][name]["overwritten_by"] = run
            write_text_atomic(path, json.dumps(other, indent=2, allow_nan=False) + "\n")
            changed.append(path)
    return changed


def read_manifest(path: str | Path) -> dict[str, Any]:
    """The manifest at `path` as a dict; ParameterError if it is not one."""
    try:
        data = json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise ParameterError(f"cannot read manifest {path}: {err}") from None
    if not isinstance(data, dict) or not isinstance(data.get("files"), dict):
        raise ParameterError(f"{path} is not a wpam_mj run manifest")
    return data


def check_files(path: str | Path) -> dict[str, str]:
    """{file name: "ok" | "changed" | "missing"} for every file the manifest lists.

    "ok" needs the SHA-256 the manifest recorded and, for a figure or video, the run id
    the file carries to be this manifest's: a file of another run is never "ok", even
    under a manifest written while that run was overwriting it.
    """
    manifest = read_manifest(path)
    folder = Path(path).parent
    status = {}
    for name, entry in manifest["files"].items():
        target = folder / name
        if not target.is_file():
            status[name] = "missing"
        else:
            same = _digest(target)["sha256"] == entry.get("sha256") and \
                embedded_run_id(target) in (None, manifest.get("run_id"))
            status[name] = "ok" if same else "changed"
    return status


def embedded_run_id(path: Path) -> str | None:
    """The run id a PNG (`png_metadata`) or video (`video_comment`) carries, else None."""
    suffix = path.suffix.lower()
    if suffix == ".png":
        return png_run_id(path)
    if suffix in (".mp4", ".gif"):
        found = re.search(rb"%s ([\w-]{1,64})" % RUN_ID_KEY.encode(), path.read_bytes())
        return found.group(1).decode() if found else None
    return None


def check_run_id(run: str) -> str:
    """A run id as `run_id` makes them (letters, digits, '_', '-'; at most 64)."""
    if not isinstance(run, str) or not re.fullmatch(r"[\w-]{1,64}", run, re.ASCII):
        raise ParameterError(f"run_id = {run!r} must be 1-64 letters, digits, '_' or '-'")
    return run


def png_metadata(run: str) -> dict[str, str]:
    """PNG text chunks recording the run id: ``fig.savefig(path, metadata=...)``."""
    return {RUN_ID_KEY: check_run_id(run)}


def video_comment(run: str) -> str:
    """The comment an MP4 or GIF of the run carries."""
    return f"{RUN_ID_KEY} {check_run_id(run)}"


def png_run_id(path: str | Path) -> str | None:
    """The run id recorded in a PNG written with `png_metadata`, or None."""
    from PIL import Image  # noqa: PLC0415 (only for reading figures)

    with Image.open(path) as image:
        return getattr(image, "text", {}).get(RUN_ID_KEY)


def _params_dict(params: Params) -> dict[str, Any]:
    return {"preset": params.preset, **params.as_dict()}


def _relative(out_dir: Path, path: Path) -> str:
    rel = os.path.relpath(path.resolve(), out_dir.resolve())
    if rel.startswith(".."):
        raise ParameterError(f"manifest file {path} is not inside the output folder {out_dir}")
    return Path(rel).as_posix()


def _digest(path: Path) -> dict[str, Any]:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return {"sha256": h.hexdigest(), "bytes": path.stat().st_size}


def _plain(obj: Any) -> Any:
    """JSON-ready copy: tuples -> lists, numpy scalars -> Python numbers, paths -> str."""
    if isinstance(obj, Mapping):
        return {str(k): _plain(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_plain(v) for v in obj]
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, Path):
        return str(obj)
    return obj
