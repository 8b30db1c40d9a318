"""The command line says what it does: options README promises, help that lists only what
the command accepts and carries what an installed package has (no docs/ paths)."""

from __future__ import annotations

from pathlib import Path

import pytest

from wpam_mj.cli import main

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "po_cap_vs_load.toml"


def run(capsys, *argv) -> tuple[int, str, str]:
    try:
        code = main([str(a) for a in argv])
    except SystemExit as done:  # --help
        code = done.code
    out, err = capsys.readouterr()
    return code, out, err


@pytest.mark.parametrize("option", [["--preset", "rlam"], ["--dt", "5e-4"],
                                    ["--config", "x.toml"]])
def test_study_refuses_model_options_in_one_line_saying_where_they_go(capsys, option,
                                                                       tmp_path) -> None:
    code, _, err = run(capsys, "study", EXAMPLE, "--out", tmp_path, *option)
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert err.startswith(f"wpam: error: {option[0]}: a study file sets its own preset")


def test_view_help_lists_only_the_controllers_it_accepts(capsys) -> None:
    code, out, _ = run(capsys, "view", "--help")
    assert code == 0 and "{open,pi,pid}" in out and "pi_ff" not in out


def test_fit_help_carries_the_measurement_format_not_a_docs_path(capsys) -> None:
    code, out, _ = run(capsys, "fit", "--help")
    assert code == 0 and "docs/" not in out
    for column in ("time_s", "load_n", "pi_mpa", "po_mpa", "x_mm", "x_ref_mm"):
        assert column in out
