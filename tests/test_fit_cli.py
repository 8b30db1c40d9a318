"""`wpam synth` and `wpam fit` end to end (small), their one-line refusals, and the
domain-randomisation ranges they export for the environment."""

import numpy as np
import pytest

from wpam_mj.simulation import plugin
from wpam_mj.cli import main
from wpam_mj.environments.dm_env_task import make_env
from wpam_mj.physics.params import apply_overrides, preset
from wpam_mj.errors import load_toml
from wpam_mj.fitting.randomize import ParameterRanges


def _run(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture(scope="module")
def synthetic(tmp_path_factory):
    out = tmp_path_factory.mktemp("synth")
    assert main(["synth", "--loads", "50", "--out", str(out), "--noise-mm", "0.05",
                 "--noise-kpa", "1", "--sample-ms", "5", "--jobs", "1"]) == 0
    return out


def test_synth_writes_the_format_fit_reads(synthetic):
    assert sorted(p.name for p in synthetic.glob("*.csv")) == ["static_50N.csv", "step_50N.csv"]
    assert [p.name for p in (synthetic / "holdout").glob("*.csv")] == ["sine_50N.csv"]
    header = (synthetic / "step_50N.csv").read_text().splitlines()[1]
    assert header == "time_s,load_n,pi_mpa,po_mpa,x_mm,pi_cmd_mpa,po_cmd_mpa,x_ref_mm"


def test_fit_writes_config_figures_and_ranges(synthetic, tmp_path, capsys):
    out = tmp_path / "fit" / "params.toml"
    ranges = tmp_path / "ranges.toml"
    lines = (synthetic / "static_50N.csv").read_text().splitlines()
    rising = tmp_path / "static_50N.csv"  # the first 40 s (the load lifts off at ~33 s)
    rising.write_text("\n".join(lines[:2 + 8000]) + "\n")
    code, stdout, err = _run(capsys, "fit", "--data", rising,
                             "--holdout", synthetic / "holdout", "--free",
                             "muscle.friction_coeff", "--max-evals", "3", "--jobs", "1",
                             "--out", out, "--randomize-out", ranges)
    assert code == 0, err
    assert "muscle.friction_coeff" in stdout and "held out" in stdout
    fitted = apply_overrides(preset(), load_toml(out))  # a --config file of the fit
    shipped = preset()
    assert fitted.replace(muscle={"friction_coeff": shipped.muscle.friction_coeff}) == shipped
    assert {p.name for p in out.parent.glob("*.png")} == {"static_50N.png", "sine_50N.png"}
    lo, hi = ParameterRanges.load(ranges, preset()).ranges["muscle.friction_coeff"]
    assert lo < fitted.muscle.friction_coeff < hi


def _one_line(code, err):
    assert code == 2, err
    assert len(err.strip().splitlines()) == 1 and err.startswith("wpam: error: "), err


@pytest.mark.parametrize("edit, words", [
    (lambda rows: [rows[0].replace("x_mm", "x_m")] + rows[1:], "missing column"),
    (lambda rows: rows[:5] + [rows[5] + ",7"] + rows[6:], "6 values"),
])
def test_fit_refuses_bad_files_in_one_line(tmp_path, capsys, edit, words):
    rows = ["time_s,load_n,pi_mpa,po_mpa,x_mm"] + [f"{0.01 * i:g},100,0.1,0,{i}"
                                                   for i in range(20)]
    path = tmp_path / "bad.csv"
    path.write_text("\n".join(edit(rows)) + "\n")
    code, _, err = _run(capsys, "fit", "--data", path, "--out", tmp_path / "p.toml")
    _one_line(code, err)
    assert words in err and "bad.csv line" in err


def test_fit_refuses_impossible_data_and_unknown_names(synthetic, tmp_path, capsys):
    rows = ["time_s,load_n,pi_mpa,po_mpa,x_mm"] + [f"{0.01 * i:g},100,0.6,0,1"
                                                   for i in range(20)]
    path = tmp_path / "high.csv"
    path.write_text("\n".join(rows) + "\n")
    code, _, err = _run(capsys, "fit", "--data", path)
    _one_line(code, err)
    assert "above the regulator range" in err
    code, _, err = _run(capsys, "fit", "--data", synthetic, "--free", "muscle.nothing")
    _one_line(code, err)
    assert "valid names" in err


def test_env_draws_parameters_from_the_ranges_each_episode(tmp_path):
    ranges = ParameterRanges({"muscle.friction_coeff": (0.1, 0.3),
                              "pneumatics.outer_conductance": (2e-9, 4e-9)})
    path = tmp_path / "ranges.toml"
    path.write_text(ranges.toml())
    drawn = []
    for _ in range(2):  # same seed, same draws
        env = make_env(seed=3, time_limit=0.05, randomize=path)
        seen = []
        for _ in range(3):
            env.reset()
            p = env.physics.params
            seen.append((p.muscle.friction_coeff, p.pneumatics.outer_conductance))
            config = plugin.config_of(env.physics.model.ptr, 0)  # what the muscle was given
            assert float(config["pneumatics.outer_conductance"]) == p.pneumatics.outer_conductance
        drawn.append(seen)
    assert drawn[0] == drawn[1]
    mu = np.array(drawn[0])[:, 0]
    assert np.all((mu >= 0.1) & (mu <= 0.3)) and len(set(mu)) == 3
    plain = make_env(seed=3, time_limit=0.05)
    plain.reset()
    assert plain.physics.params == preset()


def test_fit_refuses_a_free_list_naming_no_parameter(synthetic, tmp_path, capsys):
    """Before: `--free ,` fitted the default set, silently."""
    code, _, err = _run(capsys, "fit", "--data", synthetic, "--free", ",", "--out",
                        tmp_path / "p.toml")
    _one_line(code, err)
    assert "--free: ',' names no parameter" in err


@pytest.mark.parametrize("bounds, words", [
    ("muscle.friction_const=40.01:2000000", "muscle.friction_const=40.01:2000000: "
     "muscle.friction_const = 2000000.0 N is outside the allowed range [0, 500] N"),
    ("muscle.friction_coeff=-1:0.3", "muscle.friction_coeff=-1:0.3: muscle.friction_coeff "
     "= -1.0 is outside the allowed range [0, 1]"),
])
def test_fit_names_the_bound_given_and_the_allowed_range(synthetic, tmp_path, capsys, bounds,
                                                         words):
    """Before: 40.01:2000000 failed naming the search's start, 1000020.005; -1:0.3 ran."""
    name = bounds.partition("=")[0]
    code, _, err = _run(capsys, "fit", "--data", synthetic, "--free", name, "--bounds",
                        bounds, "--out", tmp_path / "p.toml")
    _one_line(code, err)
    assert f"--bounds {words}" in err


def test_fit_names_a_file_too_short_to_replay_and_why(tmp_path, capsys):
    """Before: "the simulation fails at the start values; check the start parameters and
    the data" (neither the file nor the cause)."""
    rows = ["time_s,load_n,pi_mpa,po_mpa,x_mm"] + [f"{0.0001 * i:g},100,0.1,0,1"
                                                   for i in range(12)]
    path = tmp_path / "brief.csv"
    path.write_text("\n".join(rows) + "\n")
    code, _, err = _run(capsys, "fit", "--data", path, "--free", "muscle.friction_coeff",
                        "--out", tmp_path / "p.toml")
    _one_line(code, err)
    assert f"{path}: its record spans 0.0011 s, less than one step of its replay" in err
