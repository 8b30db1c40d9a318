"""Studies: a process pool gives the serial results bit for bit; result structures."""

import dataclasses
import json

import numpy as np
import pytest

from wpam_mj import paper
from wpam_mj.experiments import figures
from wpam_mj.experiments import paper_studies
from wpam_mj.experiments.analysis import loop_area
from wpam_mj.physics.params import preset
from wpam_mj.errors import ParameterError
from wpam_mj.units import MPA
from wpam_mj.simulation.execution import execute


@pytest.fixture(scope="module")
def params():
    return preset("wpam")


def _same_result(a, b):
    arrays_a, arrays_b = a.arrays(), b.arrays()
    assert arrays_a.keys() == arrays_b.keys()
    for name in arrays_a:
        assert np.array_equal(arrays_a[name], arrays_b[name], equal_nan=True), name


@pytest.fixture(scope="module")
def table2_pair(params):
    """Table 2 at one load, serial and with two worker processes."""
    return [paper_studies.table2(params, loads=(100.0,), jobs=jobs) for jobs in (1, 2)]


def test_table2_pool_equals_serial(table2_pair):
    serial, pooled = table2_pair
    assert serial.as_json() == pooled.as_json()
    for a, b in zip(serial.open_loops + serial.po_loops, pooled.open_loops + pooled.po_loops):
        assert a.area == b.area
        _same_result(a.result, b.result)
    for a, b in zip(serial.feedback_runs, pooled.feedback_runs):
        for name in ("x_mean", "pi_mean", "po_mean"):
            assert np.array_equal(getattr(a, name), getattr(b, name)), name
        _same_result(a.result, b.result)


def test_sweep_pool_equals_serial(params):
    runs = [paper_studies.sweep(params, (100.0,), (1.0,), ("pi", "pid"), jobs=jobs)
            for jobs in (1, 2)]
    assert runs[0].points == runs[1].points  # exact float equality
    assert runs[0].series.keys() == runs[1].series.keys() == {(100.0, 1.0, "pi")}
    _same_result(runs[0].series[(100.0, 1.0, "pi")], runs[1].series[(100.0, 1.0, "pi")])


def test_table2_json_structure(table2_pair):
    t2 = table2_pair[0]
    doc = json.loads(json.dumps(t2.as_json()))  # plain JSON types only
    assert set(doc) == {"open_po", "feedback", "load_moved", "paper"}
    assert doc["load_moved"] == {"100": True}
    assert set(doc["open_po"]) == set(doc["feedback"]) == {"100"}
    assert doc["open_po"]["100"] > 0.0 and doc["feedback"]["100"] >= 0.0
    assert doc["paper"]["open_po"] == {"100": 0.1899}  # paper Table 2
    assert doc["paper"]["feedback"] == {"100": 0.0019}
    # normalized = area / open-loop (Po = 0) area of the same load
    assert doc["open_po"]["100"] == t2.po_loops[0].area / t2.open_loops[0].area


def test_feedback_area_uses_plateau_means(table2_pair):
    run = table2_pair[0].feedback_runs[0]
    n = len(paper.STEP_LEVELS_MM)
    assert run.x_mean.shape == run.pi_mean.shape == run.target.shape == (n,)
    assert int(np.argmax(run.pi_mean)) == n // 2  # up branch to 50 mm, then down
    assert run.area == loop_area(run.pi_mean, run.x_mean, method="branches")


def test_worker_errors_reach_the_caller(params):
    bad = paper_studies.StaticTask(params, -1.0, 0.0, 1e-3)  # skips the up-front validation
    good = paper_studies.StaticTask(params, 100.0, 0.0, 1e-3)
    with pytest.raises(ParameterError, match="load"):
        execute([good, bad], 2)


@dataclasses.dataclass(frozen=True)
class _Square:
    """A cheap task that is no simulation: value**2, or ValueError for a negative value."""

    value: int

    @property
    def cost(self) -> float:
        return float(self.value % 3)  # a cost order unlike the task order

    def run(self) -> int:
        if self.value < 0:
            raise ValueError(f"negative value {self.value}")
        return self.value ** 2


@pytest.mark.parametrize("jobs", [1, 2])
def test_tasks_that_are_no_simulations_keep_their_order(jobs):
    assert execute([_Square(v) for v in range(7)], jobs) == [v * v for v in range(7)]


@pytest.mark.parametrize("jobs", [1, 2])
def test_a_fault_of_a_task_reaches_the_caller(jobs):
    with pytest.raises(ValueError, match="negative value -4"):
        execute([_Square(v) for v in (1, 2, -4, 3)], jobs)


def test_inputs_are_checked_before_running(params):
    with pytest.raises(ParameterError, match="freq"):
        paper_studies.sweep(params, (100.0,), (0.5, 0.0), ("pi",))
    with pytest.raises(ParameterError, match="control"):
        paper_studies.sweep(params, (100.0,), (0.5,), ("pi", "bangbang"))
    with pytest.raises(ParameterError, match="po_down"):
        paper_studies.static_study(params, (100.0,), 0.7 * MPA)
    with pytest.raises(ParameterError, match="jobs"):
        execute([], 0)


def test_figure_run_key():
    assert paper_studies.figure_run_key(paper.LOADS_N, paper.SWEEP_FREQS_HZ,
                                  ("pi", "pid")) == (150.0, 0.5, "pi")
    assert paper_studies.figure_run_key((50.0, 80.0), (0.2, 1.0), ("pid",)) == (80.0, 0.2, "pid")


def test_figures_from_a_small_study(table2_pair, tmp_path):
    t2 = table2_pair[0]
    for name, fig in {"static.png": figures.static_figure(t2.open_loops + t2.po_loops),
                      "step.png": figures.step_figure([r.result for r in t2.feedback_runs]),
                      "fig16.png": figures.closed_loop_static_figure(t2.feedback_runs),
                      "table2.png": figures.table2_figure(t2)}.items():
        path = figures.save_figure(fig, tmp_path / name)
        assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n", name
    for obj in (t2, t2.open_loops[0], t2.feedback_runs[0]):
        assert obj.plot().axes, type(obj).__name__
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
        ["static.png", "step.png", "fig16.png", "table2.png"])  # no temporary files left
