"""Hardening, library side: bad input is one ParameterError line naming the
value and its range; outputs a script can trust; nothing meaningless runs silently."""

from __future__ import annotations

import dataclasses
import json
import math
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest
from dm_control.rl.control import PhysicsError

import wpam_mj
from wpam_mj.infra import manifest
from wpam_mj.visualisation import render
from wpam_mj.cli import main
from wpam_mj.display import fmt
from wpam_mj.environments.dm_env_task import SEED_RANGE, make_env
from wpam_mj.experiments.drives import SineSpec, step_run
from wpam_mj.physics.geometry import BraidGeometry
from wpam_mj.simulation.context import RunContext, check_dt
from wpam_mj.physics.params import Braid, apply_overrides, preset
from wpam_mj.errors import MAX_TOML_BYTES, ParameterError, load_toml
from wpam_mj.units import MM, MPA
from wpam_mj.physics.pneumatics import chamber_volumes, outer_bag_volume
from wpam_mj.simulation.results import SimResult
from wpam_mj.infra.files import write_atomic
from wpam_mj.simulation.simulate import Drive, SimulationDiverged, simulate

ROOT = Path(__file__).resolve().parent.parent
PARAMS = preset()


def _one_line_error(capsys, *argv: str) -> str:
    """Run the CLI; it must exit 2 with exactly one line on stderr. Returns that line."""
    code = main(list(argv))
    err = capsys.readouterr().err
    assert code == 2, err
    assert err.count("\n") == 1 and err.startswith("wpam: error: "), err
    return err


def _sim_result(n: int = 50, **changes) -> SimResult:
    t = np.arange(n) * 0.01
    series = dict(time=t, x=np.linspace(0, 0.02, n), velocity=np.zeros(n),
                  x_ref=np.full(n, np.nan), pi=np.full(n, 0.2 * MPA), po=np.zeros(n),
                  pi_cmd=np.full(n, 0.2 * MPA), po_cmd=np.zeros(n), tension=np.full(n, 100.0),
                  friction=np.full(n, 5.0), pi_reg=np.full(n, 0.2 * MPA), po_reg=np.zeros(n),
                  context=RunContext(PARAMS, 1e-3, 100.0))
    series.update(changes)
    return SimResult(**series)


# ------------------------------------------------------------------ 11, 17: --config files

def test_config_with_invalid_utf8_is_one_line(tmp_path, capsys) -> None:
    path = tmp_path / "latin1.toml"
    path.write_bytes(b"[muscle]\n# Reibung f\xfcr den Sack\ndamping = 600.0\n")
    with pytest.raises(ParameterError, match=r"not UTF-8 text: byte 0xfc on line 2"):
        load_toml(path)
    assert "not UTF-8" in _one_line_error(capsys, "step", "--config", str(path))


def test_config_larger_than_the_bound_is_refused(tmp_path) -> None:
    path = tmp_path / "huge.toml"
    path.write_text("# padding\n" * (MAX_TOML_BYTES // 10 + 1))  # valid TOML, > 1 MB
    with pytest.raises(ParameterError, match="larger than the allowed 1 MB"):
        load_toml(path)


@pytest.mark.skipif(not Path("/dev/zero").exists(), reason="no /dev/zero")
def test_config_dev_zero_is_refused_without_reading_it() -> None:
    """An endless file: refused as a device before any read (before: memory grew)."""
    code = ("from wpam_mj.physics.params import load_toml, ParameterError\n"
            "try:\n    load_toml('/dev/zero')\nexcept ParameterError as e:\n    print(e)")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=60, env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert "is a device, not a regular file" in proc.stdout, proc.stderr


@pytest.mark.parametrize("section, field, toml_value", [
    ("muscle", "damping", '"600.0"'),
    ("muscle", "friction_coeff", "true"),
    ("braid", "braid_angle", "false"),
    ("pneumatics", "p_max", "[0.5e6]"),
    ("controller", "kp", "{ value = 0.1 }"),
    ("pneumatics", "time_constant", "2026-01-01"),
])
def test_config_value_of_the_wrong_type_names_field_and_type(tmp_path, capsys, section, field,
                                                             toml_value) -> None:
    path = tmp_path / "typed.toml"
    path.write_text(f"[{section}]\n{field} = {toml_value}\n")
    with pytest.raises(ParameterError, match=rf"^{section}\.{field} = .* is a \w+; expected a "
                                             r"number in [\[(]"):
        apply_overrides(PARAMS, load_toml(path))
    assert f"{section}.{field}" in _one_line_error(capsys, "step", "--config", str(path))


def test_numbers_of_every_numeric_type_are_still_accepted() -> None:
    p = PARAMS.replace(muscle={"damping": np.float32(600.0)}, controller={"kp": 1})
    assert p.muscle.damping == 600.0 and p.controller.kp == 1.0


# ------------------------------------------------------------------ 14: geometry at load time

def _locking_limit(braid: Braid) -> float:
    return math.asin(math.sqrt(2 / 3) * braid.natural_diameter / braid.max_diameter)


@pytest.mark.parametrize("overrides, names", [
    ({"braid": {"outer_bag_length": 0.30}}, "braid.outer_bag_length"),  # bag shorter than muscle
    ({"braid": {"outer_bag_diameter": 0.040}}, "braid.outer_bag_diameter"),  # < max diameter
    ({"braid": {"max_diameter": 0.020}}, "braid.max_diameter"),  # below natural diameter
    ({"braid": {"braid_angle": 0.6}}, "braid.braid_angle"),  # locks before the bag is full
    ({"braid": {"max_diameter": 0.1, "outer_bag_diameter": 0.12}},
     "braid.braid_angle"),  # the same through a larger max diameter
    ({"muscle": {"axial_area": 0.04}}, "muscle.axial_area"),  # outer chamber volume <= 0
    ({"braid": {"outer_bag_diameter": 0.043, "outer_bag_length": 0.35},
      "muscle": {"axial_area": 0.0015}}, "muscle.axial_area"),  # beyond a tight bag's section
])
def test_every_geometry_constraint_is_checked_at_construction(overrides, names) -> None:
    with pytest.raises(ParameterError, match=names.replace(".", r"\.")):
        PARAMS.replace(**overrides)


def test_short_outer_bag_is_a_parameter_error_from_the_cli(tmp_path, capsys) -> None:
    path = tmp_path / "bag.toml"
    path.write_text("[braid]\nouter_bag_length = 0.2\n")
    assert "braid.outer_bag_length" in _one_line_error(capsys, "step", "--config", str(path))


@pytest.mark.parametrize("natural_d, max_d", [(0.022, 0.042), (0.01, 0.05), (0.03, 0.035)])
def test_locking_bound_is_exact(natural_d, max_d) -> None:
    """Just inside the bound the effective area is still positive at the hard stop (the
    braid works over its whole stroke); just outside it the angle is refused."""
    base = Braid(natural_diameter=natural_d, max_diameter=max_d, braid_angle=0.1,
                 outer_bag_diameter=2 * max_d)
    limit = _locking_limit(base)
    if limit > math.radians(5):
        inside = dataclasses.replace(base, braid_angle=limit * (1 - 1e-6))
        geom = BraidGeometry.from_params(inside)
        assert geom.area(geom.max_contraction) > 0.0
        assert geom.diameter(geom.max_contraction) == pytest.approx(max_d, rel=1e-9)
    with pytest.raises(ParameterError, match="locking angle"):
        dataclasses.replace(base, braid_angle=limit * (1 + 1e-6))


def test_axial_area_bound_is_the_bag_section() -> None:
    b = PARAMS.braid
    section = math.pi * b.outer_bag_diameter ** 2 / 4
    PARAMS.replace(muscle={"axial_area": section * (1 - 1e-6)})
    with pytest.raises(ParameterError, match=r"muscle\.axial_area .* cross-section"):
        PARAMS.replace(muscle={"axial_area": section * (1 + 1e-6)})


@pytest.mark.parametrize("natural_d, max_d", [(0.022, 0.042), (0.01, 0.05), (0.03, 0.035)])
def test_accepted_parameters_keep_the_outer_chamber_open(natural_d, max_d) -> None:
    """V_o(x) = V_bag + V_tube - V(x) - A_ax x stays positive over the whole stroke at the
    tightest accepted corner: a bag just wider than the braid's maximum diameter and as long
    as the muscle, no tube, A_ax at the bag's cross-section, the braid just short of
    locking. (The bag's section bounds A_ax, V(x) = pi D(x)^2 (L0 - x) / 4 with D <= D_max,
    so V_o > pi d_bag^2 (L_bag - L0) / 4 >= 0: the separate free-volume check in
    `Params` can no longer be reached from a parameter file.)"""
    base = Braid(natural_diameter=natural_d, max_diameter=max_d, braid_angle=0.1,
                 outer_bag_diameter=max_d * (1 + 1e-6), outer_bag_length=0.35)
    braid = dataclasses.replace(base, braid_angle=_locking_limit(base) * (1 - 1e-6))
    section = math.pi * braid.outer_bag_diameter ** 2 / 4
    params = PARAMS.replace(braid=dataclasses.asdict(braid),
                            muscle={"axial_area": section * (1 - 1e-9)},
                            pneumatics={"tube_volume": 0.0})
    geom = BraidGeometry.from_params(params.braid)
    x = np.linspace(0.0, geom.max_contraction, 201)
    _, v_outer = chamber_volumes(geom.volume(x), x, params.muscle.axial_area,
                                 outer_bag_volume(braid.outer_bag_length,
                                                  braid.outer_bag_diameter), 0.0)
    assert v_outer.min() > 0.0


# ------------------------------------------------------------------ 20: calibration, durations

def test_missing_calibration_file_given_explicitly_is_an_error(tmp_path) -> None:
    with pytest.raises(ParameterError, match="missing.toml"):
        preset("wpam", calibration=tmp_path / "missing.toml")
    assert preset("wpam", calibration=None) == wpam_mj.Params()  # built-in values


@pytest.mark.parametrize("make", [
    lambda: step_run(PARAMS, 100.0, "pi", hold=0.0),
    lambda: step_run(PARAMS, 100.0, "pi", hold=-5.0),
    lambda: step_run(PARAMS, 100.0, "pi", levels_mm=()),
    lambda: SineSpec(0.5, cycles=0),
    lambda: SineSpec(0.5, settle_cycles=-1),
    lambda: SineSpec(0.5, cycles=2.5),
    lambda: simulate(PARAMS, 100.0, Drive(np.zeros(0), np.zeros(0), np.zeros(0))),
], ids=["hold0", "hold-5", "no-levels", "cycles0", "settle-1", "cycles2.5", "empty-drive"])
def test_zero_or_negative_durations_are_refused(make) -> None:
    with pytest.raises(ParameterError):
        make()


def test_result_series_must_share_one_length() -> None:
    with pytest.raises(ParameterError, match=r"SimResult\.x has shape \(3,\)"):
        _sim_result(x=np.zeros(3))


# ------------------------------------------------------------------ 13: env after divergence

def test_env_refuses_to_step_after_a_divergence_until_reset(monkeypatch) -> None:
    """A divergence reported by the physics step (stood in for: a chamber too fast for dt
    is now refused when the rig is built) ends stepping until reset()."""
    from wpam_mj.simulation import live  # noqa: PLC0415

    real_step = live.LiveRig.step

    def failing(self, data, nstep=1):
        raise SimulationDiverged("chamber pressure Pi = -1 Pa (stand-in)")

    env = make_env(PARAMS, action="both", dt=0.005, seed=0, load=100.0)
    env.reset()
    monkeypatch.setattr(live.LiveRig, "step", failing)
    with pytest.raises(PhysicsError, match="chamber pressure"):
        env.step([0.5 * MPA, 0.0])
    monkeypatch.setattr(live.LiveRig, "step", real_step)
    for _ in range(3):  # before: later steps returned with meaningless pressures
        with pytest.raises(PhysicsError, match=r"call reset\(\)"):
            env.step([0.0, 0.0])
    timestep = env.reset()
    assert timestep.first()
    env.step([0.1 * MPA, 0.0])  # a new episode steps


@pytest.mark.parametrize("seed", [-1, SEED_RANGE[1] + 1, 1.5, "0", True, [1, 2]])
def test_bad_seeds_are_parameter_errors(seed) -> None:
    with pytest.raises(ParameterError, match="seed = "):
        make_env(PARAMS, seed=seed)


@pytest.mark.parametrize("seed", [None, 0, SEED_RANGE[1], np.uint32(7)])
def test_good_seeds_are_accepted(seed) -> None:
    make_env(PARAMS, seed=seed)


# ------------------------------------------------------------------ 16, 20: stated ranges

@pytest.mark.parametrize("dt", [0.003, 0.0007, 0.004])
def test_dt_inside_the_range_but_not_dividing_the_record_period_names_both(dt) -> None:
    with pytest.raises(ParameterError, match=r"--dt = .* must divide the 0\.01 s recording "
                                             r"period.*\[1e-05, 0\.005\] s"):
        check_dt(dt, divides=0.01, name="--dt")


@pytest.mark.parametrize("dt", [0.005, 0.0025, 0.002, 0.001, 0.0005, 1e-5])
def test_dt_dividing_the_record_period_is_accepted(dt) -> None:
    assert check_dt(dt, divides=0.01) == dt
    assert step_run(PARAMS, 100.0, "open", levels_mm=(0,), hold=0.05, dt=dt).time[-1] > 0



@pytest.mark.parametrize("suffix", [".mp4", ".gif"])
def test_fps_range_stated_is_the_range_applied(suffix) -> None:
    lo, hi = render.FPS_RANGE[suffix]
    assert render.check_fps(lo, suffix) == lo and render.check_fps(hi, suffix) == hi
    for bad in (0.0, lo - 1e-9, hi + 1e-6, math.nan, "fast"):
        with pytest.raises(ParameterError, match=rf"fps = .*(\[{lo:g}, {hi:g}\]|not a number)"):
            render.check_fps(bad, suffix)


@pytest.mark.parametrize("call", [
    lambda out: render.render_video(None, PARAMS, out / "a.mp4"),
    lambda out: render.render_video(_sim_result(), None, out / "a.mp4"),
    lambda out: render.render_video(_sim_result(x=np.full(50, np.nan)), PARAMS, out / "a.mp4"),
    lambda out: render.render_video(_sim_result(time=np.zeros(50)), PARAMS, out / "a.mp4"),
    lambda out: render.render_video(_sim_result(), PARAMS, None),
    lambda out: render.render_video(_sim_result(), PARAMS, out / "a.avi"),
    lambda out: render.render_video(_sim_result(), PARAMS, out / "a.mp4", fps=0),
    lambda out: render.render_video(_sim_result(), PARAMS, out / "a.gif", fps=60),
    lambda out: render.render_video(_sim_result(), PARAMS, out / "a.mp4", size=(641, 480)),
    lambda out: render.render_video(_sim_result(), PARAMS, out / "a.mp4", size="640x480"),
    lambda out: render.render_video(_sim_result(), PARAMS, out / "a.mp4", camera=None),
    lambda out: render.render_video(_sim_result(), PARAMS, out / "a.mp4", shadows="yes"),
    lambda out: render.render_video(_sim_result(), PARAMS, out / "a.mp4", threads=0),
    lambda out: render.render_video(_sim_result(context=RunContext(PARAMS, 1e-3, 0.0)), PARAMS,
                                    out / "a.mp4"),  # no result carries a refused load
    lambda out: render.render_frames(_sim_result(pi=np.full(50, np.inf)), PARAMS),
    lambda out: render.still_frame(_sim_result(), PARAMS, 0.1, None),
    lambda out: render.still_frame(_sim_result(), PARAMS, math.nan, out / "a.png"),
])
def test_bad_render_inputs_are_parameter_errors(call, tmp_path) -> None:
    with pytest.raises(ParameterError):
        call(tmp_path)
    assert not list(tmp_path.iterdir()), "nothing is written for refused input"


# ------------------------------------------------------------------ 8, 18: CSV and manifests

def test_csv_loads_with_plain_genfromtxt_and_pandas(tmp_path) -> None:
    result = _sim_result(x_ref=np.where(np.arange(50) < 10, np.nan, 0.02))
    path = result.to_csv(tmp_path / "run.csv")
    table = np.genfromtxt(path, delimiter=",", names=True)
    assert len(table) == 50 and table.dtype.names[:3] == ("time_s", "x_mm", "x_ref_mm")
    np.testing.assert_allclose(table["x_mm"], result.x / MM, rtol=1e-5)
    pandas = pytest.importorskip("pandas")
    frame = pandas.read_csv(path)
    assert list(frame.columns) == list(table.dtype.names)
    np.testing.assert_allclose(frame["pi_mpa"], result.pi / MPA, rtol=1e-5)
    assert frame["x_ref_mm"].isna().sum() == 10


def test_csv_cells_of_numpy_scalars_read_back_as_numbers() -> None:
    # robustness.csv once wrote a margin as 'np.float64(0.15)': numpy 2's repr
    from wpam_mj.infra.files import csv_text
    text = csv_text([{"a": np.float64(0.1), "b": np.float32(2.5), "c": np.bool_(True),
                      "d": 0.1, "e": 3}])
    assert text.splitlines()[1] == "0.1,2.5,true,0.1,3"
    assert float(text.splitlines()[1].split(",")[0]) == 0.1


def _figure_png(path: Path, run: str) -> Path:
    from matplotlib.figure import Figure

    from wpam_mj.experiments.figures import save_figure
    fig = Figure(figsize=(1, 1))
    fig.add_subplot().plot([0, 1])
    return save_figure(fig, path, run_id=run)


def test_manifest_records_the_run_and_every_file(tmp_path) -> None:
    settings = {"load_n": 100.0, "control": "pi", "dt_s": 1e-3}
    run = manifest.run_id("step", PARAMS, settings)
    assert run == manifest.run_id("step", PARAMS, dict(settings))  # reruns: same id
    assert run != manifest.run_id("step", PARAMS.replace(muscle={"damping": 100.0}), settings)
    assert run != manifest.run_id("step", PARAMS, {**settings, "load_n": 150.0})
    result = _sim_result()
    csv_path = result.to_csv(tmp_path / "out" / "step.csv")
    png = _figure_png(tmp_path / "out" / "step.png", run)
    path = manifest.write_manifest(tmp_path / "out", run, "step", PARAMS,
                                   {csv_path: result.metadata(), png: {}}, settings=settings,
                                   argv=["wpam", "step", "--load", "100"])
    data = json.loads(path.read_text())
    assert path.name == f"manifest-{run}.json" and data["run_id"] == run
    assert data["command"] == "step" and data["wpam_mj_version"] == wpam_mj.__version__
    assert data["params"]["muscle"]["damping"] == PARAMS.muscle.damping
    assert data["files"]["step.csv"]["load_n"] == 100.0
    assert data["files"]["step.csv"]["samples"] == 50
    assert manifest.png_run_id(png) == run
    assert manifest.check_files(path) == {"step.csv": "ok", "step.png": "ok"}
    csv_path.write_text(csv_path.read_text().replace("0.2", "0.3"))
    assert manifest.check_files(path)["step.csv"] == "changed"


def test_two_runs_into_one_folder_can_be_told_apart(tmp_path) -> None:
    """Item 18: the CSV of one run beside the PNG of another is detected."""
    runs = {}
    for damping in (600.0, 100.0):
        params = PARAMS.replace(muscle={"damping": damping})
        run = manifest.run_id("step", params, {})
        result = _sim_result(x=np.linspace(0, damping * 1e-5, 50))
        files = [result.to_csv(tmp_path / "step.csv"), _figure_png(tmp_path / "step.png", run)]
        runs[run] = manifest.write_manifest(tmp_path, run, "step", params, files)
    (first, first_path), (second, second_path) = runs.items()
    _sim_result(x=np.linspace(0, 600.0 * 1e-5, 50)).to_csv(tmp_path / "step.csv")  # race
    assert manifest.check_files(first_path) == {"step.csv": "ok", "step.png": "changed"}
    assert manifest.check_files(second_path) == {"step.csv": "changed", "step.png": "ok"}
    assert manifest.png_run_id(tmp_path / "step.png") == second


@pytest.mark.parametrize("name", ["run.mp4", "run.gif", "still.png"])
def test_videos_and_stills_record_the_run_id(name, tmp_path) -> None:
    run = manifest.run_id("render", PARAMS, {"load_n": 100.0})
    path = tmp_path / name
    if name == "still.png":
        render.still_frame(_sim_result(n=5), PARAMS, 0.0, path, size=(64, 48), run_id=run)
        assert manifest.png_run_id(path) == run
    else:
        render.render_video(_sim_result(n=5), PARAMS, path, fps=10, size=(64, 48),
                            threads=1, run_id=run)
        assert manifest.video_comment(run).encode() in path.read_bytes()


@pytest.mark.parametrize("run", ["", "a b", "x" * 65, None, "id;rm"])
def test_bad_run_ids_are_refused(run) -> None:
    with pytest.raises(ParameterError, match="run_id"):
        manifest.png_metadata(run)


def test_manifest_refuses_files_outside_its_folder(tmp_path) -> None:
    outside = _sim_result().to_csv(tmp_path / "elsewhere.csv")
    with pytest.raises(ParameterError, match="not inside the output folder"):
        manifest.write_manifest(tmp_path / "out", "x", "step", PARAMS, [outside])


# ------------------------------------------------------------------ 12: killed writers

_KILLED_WRITER = textwrap.dedent("""
    import os, signal, sys
    from wpam_mj.infra.files import write_atomic
    def write(p):
        p.write_bytes(b"partial")
        os.kill(os.getpid(), signal.SIGKILL)
    write_atomic(sys.argv[1], write)
""")


def test_killed_writer_leaves_no_file_under_the_final_name_and_is_cleaned(tmp_path) -> None:
    target = tmp_path / "video.mp4"
    proc = subprocess.run([sys.executable, "-c", _KILLED_WRITER, str(target)],
                          env={**os.environ, "PYTHONPATH": str(ROOT)}, timeout=60)
    assert proc.returncode == -signal.SIGKILL
    assert not target.exists()
    (stale,) = tmp_path.glob(".video.mp4.*")
    live = tmp_path / f".video.mp4.wpam{os.getpid()}-concurrent.mp4"  # a live writer's
    live.write_bytes(b"in progress")
    write_atomic(target, lambda p: p.write_bytes(b"whole"))
    assert target.read_bytes() == b"whole"
    assert not stale.exists(), "the dead writer's temporary file is removed"
    assert live.exists(), "a running writer's temporary file is left alone"


def test_killed_render_leaves_no_partial_video(tmp_path) -> None:
    """SIGKILL during a render: ffmpeg may finish writing, but only under the hidden
    temporary name, which the next render of the same file removes."""
    pytest.importorskip("imageio_ffmpeg")
    target = tmp_path / "run.mp4"
    code = textwrap.dedent(f"""
        import numpy as np, wpam_mj
        from wpam_mj.visualisation.render import render_video
        from wpam_mj.simulation.context import RunContext
        from wpam_mj.simulation.results import SimResult
        n = 6000
        z = np.zeros(n)
        r = SimResult(time=np.arange(n) * 0.01, x=0.02 * (1 - np.cos(np.arange(n) / 50)),
                      velocity=z, x_ref=z, pi=z, po=z, pi_cmd=z, po_cmd=z, tension=z,
                      friction=z, pi_reg=z, po_reg=z,
                      context=RunContext(wpam_mj.preset(), 1e-3, 100.0, "pi"))
        render_video(r, wpam_mj.preset(), {str(target)!r}, fps=30, size=(64, 48), threads=1)
    """)
    proc = subprocess.Popen([sys.executable, "-c", code],
                            env={**os.environ, "PYTHONPATH": str(ROOT)})
    try:
        deadline = time.monotonic() + 60
        while not list(tmp_path.glob(".run.mp4.*")) and time.monotonic() < deadline:
            if proc.poll() is not None:
                pytest.fail(f"render exited early with {proc.returncode}")
            time.sleep(0.05)
        time.sleep(0.3)  # some frames in flight
    finally:
        proc.kill()
        proc.wait()
    if not list(tmp_path.glob(".run.mp4.*")):
        pytest.skip("render finished before it could be killed")
    time.sleep(0.5)  # an orphaned ffmpeg finishing its file
    assert not target.exists(), "a killed render left a file under the final name"
    render.render_video(_sim_result(n=10), PARAMS, target, fps=10, size=(64, 48), threads=1)
    assert target.stat().st_size > 0
    assert not list(tmp_path.glob(".run.mp4.*")), "stale temporary video not removed"


# ------------------------------------------------------------------ 10: display numbers

@pytest.mark.parametrize("value, spec, text", [
    (-3e-6, ".4f", "0.0000"),  # "Po -0.0000" before
    (-3e-6, ">10.4f", "    0.0000"),
    (-0.0, "6.3f", " 0.000"),
    (-4e-4, "+.1%", "+0.0%"),
    (-0.00049, ".3f", "0.000"),
    (-0.0005001, ".3f", "-0.001"),
    (-1e-5, "g", "-1e-05"),
    (-1e-5, ".2e", "-1.00e-05"),
    (-math.inf, ".3f", "-inf"),
])
def test_numbers_never_print_as_minus_zero(value, spec, text) -> None:
    assert fmt(value, spec) == text
