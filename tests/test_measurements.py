"""The measurement format: round trip, and one-line refusals naming line and column."""

import numpy as np
import pytest

from wpam_mj import preset
from wpam_mj.physics.geometry import BraidGeometry
from wpam_mj.fitting.measurements import Experiment, experiment_files, read_experiment
from wpam_mj.errors import ParameterError
from wpam_mj.units import MM, MPA

HEADER = "time_s,load_n,pi_mpa,po_mpa,x_mm"


def _rows(n=20):
    return [f"{0.01 * i:g},100,{0.1 + 0.001 * i:g},0.0,{0.5 * i:g}" for i in range(n)]


def _write(tmp_path, header=HEADER, rows=None, name="run.csv"):
    path = tmp_path / name
    path.write_text("\n".join(["# a comment", header, *(rows or _rows())]) + "\n")
    return path


def test_round_trip_keeps_si_values(tmp_path):
    t = np.arange(50) * 0.002
    exp = Experiment("ramp", 100.0, t, pi=np.linspace(0, 0.3, 50) * MPA,
                     po=np.full(50, 0.04 * MPA), x=np.linspace(0, 30, 50) * MM,
                     pi_cmd=np.linspace(0, 0.3, 50) * MPA, po_cmd=np.zeros(50),
                     x_ref=np.where(t < 0.05, np.nan, 0.01))
    back = read_experiment(exp.to_csv(tmp_path / "ramp.csv"), preset())
    assert back.load == 100.0 and back.has_commands
    for name in ("time", "pi", "po", "x", "pi_cmd", "po_cmd"):
        np.testing.assert_allclose(getattr(back, name), getattr(exp, name), rtol=1e-5,
                                   atol=1e-9, err_msg=name)
    assert np.array_equal(np.isnan(back.x_ref), np.isnan(exp.x_ref))


def _edit(rows, i, column, value):
    cells = rows[i].split(",")
    cells[HEADER.split(",").index(column)] = value
    rows[i] = ",".join(cells)
    return rows


x_limit_mm = BraidGeometry.from_params(preset().braid).max_contraction / MM


@pytest.mark.parametrize("header, rows, line, column, words", [
    ("time_s,load_n,pi_mpa,x_mm", None, 2, None, "missing column(s) po_mpa"),
    (HEADER, _edit(_rows(), 5, "time_s", "0.01"), 8, "time_s", "does not increase"),
    (HEADER, _edit(_rows(), 7, "x_mm", ""), 10, "x_mm", "empty or NaN"),
    (HEADER, _edit(_rows(), 7, "x_mm", "nan"), 10, "x_mm", "gap"),
    (HEADER, _edit(_rows(), 4, "pi_mpa", "abc"), 7, "pi_mpa", "not a number"),
    (HEADER, _edit(_rows(), 9, "pi_mpa", "250"), 12, "pi_mpa", "kPa"),
    (HEADER, _edit(_rows(), 9, "po_mpa", "0.7"), 12, "po_mpa", "above the regulator range"),
    (HEADER, _edit(_rows(), 9, "x_mm", f"{x_limit_mm + 5:g}"), 12, "x_mm",
     "beyond the braid's limit"),
    (HEADER, _edit(_rows(), 3, "load_n", "120"), 6, "load_n", "one load per file"),
])
def test_bad_files_are_refused_in_one_line(tmp_path, header, rows, line, column, words):
    path = _write(tmp_path, header, rows)
    with pytest.raises(ParameterError) as err:
        read_experiment(path, preset())
    msg = str(err.value)
    assert "\n" not in msg and words in msg
    assert f"line {line}" in msg and (column is None or f"column {column}" in msg)


def test_time_in_milliseconds_is_caught(tmp_path):
    rows = [f"{10 * i},100,0.1,0,1" for i in range(20)]
    with pytest.raises(ParameterError, match="is time in ms"):
        read_experiment(_write(tmp_path, rows=rows), preset())


def test_folders_expand_to_their_csv_files(tmp_path):
    b, a = _write(tmp_path, name="b.csv"), _write(tmp_path, name="a.csv")
    assert experiment_files([tmp_path]) == [a, b]  # sorted by name
    with pytest.raises(ParameterError, match="no such file"):
        experiment_files([tmp_path / "missing.csv"])
    with pytest.raises(ParameterError, match="twice"):
        experiment_files([a, tmp_path])
