"""Concurrent commands: runs into one output folder never mix, and `check_files` catches a
file of another run; a refused or failed command leaves no folder it created."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from wpam_mj.infra import manifest
from wpam_mj.infra import outputs
from wpam_mj.visualisation import render
from wpam_mj.cli import main
from wpam_mj.physics.params import preset
from wpam_mj.errors import ParameterError
from wpam_mj.simulation.context import RunContext
from wpam_mj.simulation.results import SimResult

ROOT = Path(__file__).resolve().parents[1]
DTS = ("0.005", "0.0025", "0.002")  # the files are named alike (by load and control)


def _step(cwd: Path, out: str, dt: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "wpam_mj", "step", "--load", "100",
                             "--dt", dt, "--jobs", "1", "--out", out, "--json"],
                            cwd=cwd, env={**os.environ, "PYTHONPATH": str(ROOT)},
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def test_concurrent_runs_into_one_folder_each_list_their_own_files(tmp_path):
    """Three steps at once into `same`: each manifest holds the SHA-256 of the files its
    own run wrote (as a run alone writes them), and the last run's files are all "ok"."""
    procs = [_step(tmp_path, "same", dt) for dt in DTS]
    alone = [_step(tmp_path, f"alone{dt}", dt) for dt in DTS]
    runs = [json.loads(p.communicate(timeout=300)[0])["run_id"] for p in procs]
    for p in alone:
        p.communicate(timeout=300)
    assert all(p.returncode == 0 for p in procs + alone)
    statuses = []
    for dt, run in zip(DTS, runs):
        listed = manifest.read_manifest(tmp_path / "same" / f"manifest-{run}.json")["files"]
        own = manifest.read_manifest(tmp_path / f"alone{dt}" / f"manifest-{run}.json")
        assert {n: e["sha256"] for n, e in listed.items()} == \
            {n: e["sha256"] for n, e in own["files"].items()}, f"dt {dt} lists another run"
        statuses.append(manifest.check_files(tmp_path / "same" / f"manifest-{run}.json"))
    complete = [s for s in statuses if set(s.values()) == {"ok"}]
    assert len(complete) == 1, statuses  # the run that finished last
    for run, status in zip(runs, statuses):  # the others say which run rewrote their files
        listed = manifest.read_manifest(tmp_path / "same" / f"manifest-{run}.json")["files"]
        assert all((listed[n].get("overwritten_by") in runs) == (s == "changed")
                   for n, s in status.items()), (run, status)


def test_a_run_that_rewrites_another_runs_files_marks_its_manifest(tmp_path, capsys):
    """Before: the first run's manifest kept vouching for files the second had rewritten."""
    out = tmp_path / "same"
    ids = []
    for dt in ("0.005", "0.0025", "0.0025"):  # the third reruns the second: nothing to mark
        assert main(["step", "--load", "100", "--dt", dt, "--jobs", "1", "--json",
                     "--out", str(out)]) == 0
        captured = capsys.readouterr()
        ids.append(json.loads(captured.out)["run_id"])
        notes = [line for line in captured.err.splitlines() if "rewrote" in line]
        assert notes == ([f"note: this run rewrote files that manifest-{ids[0]}.json listed "
                          "(marked there as overwritten by this run)"] if len(ids) == 2 else [])
    first = manifest.read_manifest(out / f"manifest-{ids[0]}.json")["files"]
    assert {e.get("overwritten_by") for e in first.values()} == {ids[1]}
    assert set(manifest.check_files(out / f"manifest-{ids[0]}.json").values()) == {"changed"}
    assert set(manifest.check_files(out / f"manifest-{ids[1]}.json").values()) == {"ok"}


def test_a_second_claim_of_a_folder_waits_for_the_first(tmp_path):
    code = ("import sys, time\nfrom wpam_mj.infra import outputs\n"
            "outputs.claim(sys.argv[1]); print('held', flush=True); time.sleep(60)")
    holder = subprocess.Popen([sys.executable, "-c", code, str(tmp_path)],
                              env={**os.environ, "PYTHONPATH": str(ROOT)},
                              stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        waiter = subprocess.Popen([sys.executable, "-c", code, str(tmp_path)],
                                  env={**os.environ, "PYTHONPATH": str(ROOT)},
                                  stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        assert "waiting for another wpam command" in waiter.stderr.readline()
        holder.kill()  # its lock goes with it
        assert waiter.stdout.readline().strip() == "held"
        waiter.kill()
        waiter.communicate()
    finally:
        holder.kill()
        holder.communicate()


def test_one_command_may_claim_a_folder_twice(tmp_path):
    try:
        outputs.claim(tmp_path)
        outputs.claim(tmp_path / ".")  # e.g. fit's --out and --randomize-out side by side
    finally:
        outputs.release(failed=False)


def _video_result(n: int = 5) -> SimResult:
    z = np.zeros(n)
    return SimResult(time=np.arange(n) * 0.01, x=np.linspace(0, 0.02, n), velocity=z,
                     x_ref=z, pi=z, po=z, pi_cmd=z, po_cmd=z, tension=z, friction=z,
                     pi_reg=z, po_reg=z, context=RunContext(preset(), 1e-3, 100.0, "pi"))


@pytest.mark.parametrize("name", ["run.mp4", "run.gif", "still.png"])
def test_a_figure_or_video_of_another_run_is_never_ok(tmp_path, name):
    """The manifest's SHA-256 taken from another run's file (the race of item 2) is still
    caught: the file carries that other run's id."""
    params = preset()
    ours, theirs = (manifest.run_id("render", params, {"load_n": f}) for f in (1.0, 2.0))
    path = tmp_path / name
    if name == "still.png":
        render.still_frame(_video_result(), params, 0.0, path, size=(64, 48), run_id=theirs)
    else:
        render.render_video(_video_result(), params, path, fps=10, size=(64, 48), threads=1,
                            run_id=theirs)
    assert manifest.embedded_run_id(path) == theirs
    listed = manifest.write_manifest(tmp_path, ours, "render", params, [path])
    assert manifest.check_files(listed) == {name: "changed"}
    mine = manifest.write_manifest(tmp_path, theirs, "render", params, [path])
    assert manifest.check_files(mine) == {name: "ok"}


@pytest.mark.parametrize("argv", [
    ["synth", "--out", "new/deeper", "--sample-ms", "0"],
    ["step", "--out", "new/deeper", "--dt", "0.003"],
    ["fit", "--data", "nothing.csv", "--out", "new/deeper/p.toml"],
    ["study", "missing.toml", "--out", "new/deeper"],
], ids=["synth", "step", "fit", "study"])
def test_a_refused_command_leaves_no_folder(tmp_path, monkeypatch, capsys, argv):
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    assert capsys.readouterr().err.count("\n") == 1
    assert not (tmp_path / "new").exists()


def test_release_keeps_a_created_folder_that_holds_files(tmp_path):
    outputs.claim(tmp_path / "a" / "b")
    (tmp_path / "a" / "b" / "part.csv").write_text("x\n")
    outputs.release(failed=True)
    assert (tmp_path / "a" / "b" / "part.csv").exists()


def test_claim_names_the_folder_it_cannot_write(tmp_path):
    (tmp_path / "file").write_text("")
    with pytest.raises(ParameterError, match=r"--out .*file/sub: cannot write there"):
        outputs.claim(tmp_path / "file" / "sub")
    outputs.release(failed=True)


def test_a_folder_that_cannot_be_locked_is_still_written_with_a_note(tmp_path, monkeypatch,
                                                                      capsys):
    import errno  # noqa: PLC0415
    import fcntl  # noqa: PLC0415

    def no_locks(fd, op):
        raise OSError(errno.ENOLCK, os.strerror(errno.ENOLCK))

    monkeypatch.setattr(fcntl, "flock", no_locks)
    try:
        assert outputs.claim(tmp_path / "nfs") == tmp_path / "nfs"
    finally:
        outputs.release(failed=False)
    assert "cannot lock" in capsys.readouterr().err
