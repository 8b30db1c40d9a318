"""A large measurement file under a memory limit: read into arrays with little more memory
than its numbers (`wpam fit` in a subprocess whose address space is capped a few tens of
MB above what it has after its imports), and where even that does not fit, one line."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from wpam_mj import preset
from wpam_mj.fitting.measurements import read_experiment
from wpam_mj.errors import ParameterError

ROOT = Path(__file__).resolve().parents[1]
ROWS = 200_000  # 200 s at 1 kHz, 11 MB: the cell-by-cell reader needed ~15 times that

# The command's lazy imports first, then RLIMIT_AS at the current size plus argv[1] MB.
LIMITED = """
import resource, sys
from wpam_mj.cli import main
from wpam_mj.fitting import estimation, measured_fit, measurements

with open("/proc/self/status") as fh:
    size = next(int(ln.split()[1]) * 1024 for ln in fh if ln.startswith("VmSize:"))
extra = int(sys.argv[1]) * 2**20
resource.setrlimit(resource.RLIMIT_AS, (size + extra, resource.RLIM_INFINITY))
sys.exit(main(sys.argv[2:]))
"""


@pytest.fixture(scope="module")
def big_csv(tmp_path_factory) -> Path:
    """A PI sine at 1 kHz whose last row names another load: read whole, then refused."""
    t = np.arange(ROWS) * 1e-3
    x = 25.0 + 10.0 * np.sin(2 * np.pi * 0.2 * t)
    pi = 0.2 + 0.05 * np.sin(2 * np.pi * 0.2 * t)
    load = np.full(ROWS, 100.0)
    load[-1] = 130.0
    path = tmp_path_factory.mktemp("big") / "big.csv"
    with path.open("w") as fh:
        fh.write("# a long run\ntime_s,load_n,pi_mpa,po_mpa,x_mm,x_ref_mm\n")
        np.savetxt(fh, np.column_stack([t, load, pi, np.full(ROWS, 0.02), x, x]),
                   fmt=["%.9g"] + ["%.6g"] * 5, delimiter=",")
    return path


def _fit_limited(path: Path, extra_mb: int, tmp_path: Path) -> tuple[int, str]:
    env = {**os.environ, "PYTHONPATH": str(ROOT), "MALLOC_ARENA_MAX": "2"}
    proc = subprocess.run([sys.executable, "-c", LIMITED, str(extra_mb), "fit", "--data",
                           str(path), "--out", str(tmp_path / "fit.toml"), "--jobs", "1"],
                          capture_output=True, text=True, env=env, cwd=tmp_path, timeout=120)
    return proc.returncode, proc.stderr.strip()


def test_a_large_file_is_read_within_a_small_memory_limit(big_csv, tmp_path):
    code, err = _fit_limited(big_csv, 60, tmp_path)
    assert code == 2 and err.count("\n") == 0, err
    assert f"line {ROWS + 2} column load_n" in err and "one load per file" in err, err


def test_a_file_beyond_the_memory_limit_is_refused_in_one_line(tmp_path, monkeypatch):
    path = tmp_path / "run.csv"
    path.write_text("time_s,load_n,pi_mpa,po_mpa,x_mm\n"
                    + "".join(f"{0.01 * i:g},100,0.1,0.0,1\n" for i in range(20)))

    def exhausted(*args, **kwargs):
        raise MemoryError
    monkeypatch.setattr(np, "loadtxt", exhausted)
    with pytest.raises(ParameterError, match="run.csv: 0 MB of data does not fit in the "
                       "memory this process may use; split the experiment into shorter"):
        read_experiment(path, preset())


def test_any_command_out_of_memory_ends_in_one_line(monkeypatch, capsys):
    from wpam_mj.cli import main, reproduction

    def exhausted(args):
        raise MemoryError
    monkeypatch.setattr(reproduction, "_cmd_reproduce", exhausted)
    assert main(["reproduce", "--out", "never"]) == 1
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "wpam reproduce ran out of the memory" in err, err


@pytest.mark.parametrize("edit, words", [
    (lambda rows: rows[:4] + ["0.05,100,0.1,0.0,1,2"] + rows[5:], "line 7: 6 values"),
    (lambda rows: rows[:6] + ["0.07,100,inf,0.0,1"] + rows[7:], "line 9 column pi_mpa: 'inf'"),
    (lambda rows: rows[:3] + ["", "# paused"] + rows[3:8] + ["0.1,100,0.1,0.0,1"] + rows[8:],
     "line 14 column time_s: time 0.08 s does not increase"),
    (lambda rows: rows[:9], "9 data rows; at least 10"),
])
def test_both_readers_name_the_line_at_fault(tmp_path, edit, words):
    """The array reader and the cell-by-cell one it falls back on count lines alike,
    comments and blank lines included."""
    rows = [f"{0.01 * i:g},100,0.1,0.0,{0.5 * i:g}" for i in range(20)]
    path = tmp_path / "run.csv"
    path.write_text("\n".join(["# a comment", "time_s,load_n,pi_mpa,po_mpa,x_mm",
                               *edit(rows)]) + "\n")
    with pytest.raises(ParameterError, match=words):
        read_experiment(path, preset())
