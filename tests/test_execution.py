"""The execution layer (`wpam_mj.simulation.execution`): the same outcomes, bit for bit,
run one task at a time, on batch threads here, on local processes or on a Dask cluster."""

from __future__ import annotations

import dataclasses
import sys

import numpy as np
import pytest

from wpam_mj.cli import main
from wpam_mj.experiments.paper_studies import SineTask, StepTask
from wpam_mj.fitting import estimation
from wpam_mj.infra.pool import Cluster, Workers, open_workers
from wpam_mj.physics.params import preset
from wpam_mj.errors import ParameterError
from wpam_mj.simulation import execution
from wpam_mj.simulation.execution import result_bytes
from wpam_mj.simulation.simulate import SimulationDiverged, simulate_run

P = preset("wpam")
DT = 5e-3
# runs of three lengths (batches of one and of two runs), a refused load, a kept series
TASKS = [StepTask(P, 60.0, "pi", DT), SineTask(P, 100.0, "pi", 2.0, DT, True),
         StepTask(P, 1900.0, "pi", DT), StepTask(P, 140.0, "open", DT),
         SineTask(P, 150.0, "pid", 1.0, DT, False)]


def _serial(tasks) -> list:
    out = []
    for t in tasks:
        try:
            out.append(t.run())
        except execution.FAILURES as err:
            out.append(str(err))
    return out


@pytest.fixture(scope="module")
def cluster():
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as c:
        yield c


class _Plain:
    """A task that is not a simulation: it runs as it is (on the pool, if any)."""

    cost = 1.0

    def __init__(self, value: float) -> None:
        self.value = value

    def run(self) -> float:
        if self.value < 0:
            raise ArithmeticError("negative")
        return self.value


def test_batch_threads_and_local_processes_give_the_serial_results_bit_for_bit():
    serial = result_bytes(_serial(TASKS))
    assert result_bytes(execution.execute(TASKS, None, failed=str)) == serial
    with open_workers(2) as workers:  # two cores: batch threads here, plain tasks on the pool
        assert result_bytes(execution.execute(TASKS, workers, failed=str)) == serial
        assert execution.execute([_Plain(2.0), *TASKS[:1], _Plain(-1.0)], workers,
                                 failed=None)[::2] == [2.0, None]


def test_a_local_run_and_a_two_worker_dask_cluster_agree_bit_for_bit(cluster):
    with open_workers(Cluster(cluster.scheduler_address)) as workers:
        assert workers.slots == 2 and workers.where.startswith("Dask")
        remote = execution.execute(TASKS, workers, failed=str)
        bare = execution.execute(TASKS, workers.executor, failed=str)  # a bare executor
    local = execution.execute(TASKS, None, failed=str)
    assert (result_bytes(remote) == result_bytes(bare) == result_bytes(local)
            == result_bytes(_serial(TASKS)))
    assert "cannot lift" in remote[2]


def test_failures_in_task_order_values_or_raised():
    out = execution.execute(TASKS, None, failed=None)
    assert out[2] is None and all(o is not None for i, o in enumerate(out) if i != 2)
    with pytest.raises(ParameterError, match="cannot lift"):
        execution.execute(TASKS, None)
    with pytest.raises(KeyError):  # a fault, not a failed run: always raised
        execution.execute([_Fault()], None, failed=None)


class _Fault(execution.SimulationTask):
    cost = 1.0

    def runs(self):
        return []

    def reduce(self, results):
        return {}["missing"]


def test_runs_of_any_length_on_threads_equal_one_at_a_time():
    runs = [r for t in (TASKS[0], TASKS[1], TASKS[3], TASKS[4]) for r in t.runs()]
    one = [simulate_run(r) for r in runs]
    for nthread in (1, 2, 3):
        got = execution._simulate_runs(runs, nthread)
        for a, b in zip(got, one):
            assert not isinstance(a, SimulationDiverged)
            for name, arr in b.arrays().items():
                np.testing.assert_array_equal(getattr(a, name), arr, err_msg=name)


@dataclasses.dataclass(frozen=True)
class _Steps:
    """A residual model of one PI staircase: the plateau means' errors [mm]."""

    load: float = 100.0

    def tasks(self, params):
        return [StepTask(params, self.load, "pi", DT)]

    def residuals(self, params, results):
        return (results[0].x_mean - results[0].target) * 1e3


def test_fits_evaluate_the_same_residuals_here_and_on_dask(cluster):
    trials = [P, P.replace(muscle={"friction_coeff": 0.2})]
    here = estimation.evaluate(_Steps(), trials)
    with open_workers(Cluster(cluster.scheduler_address)) as workers:
        remote = estimation.evaluate(_Steps(), trials, workers.executor)
        assert estimation.evaluate(_Steps(1900.0), trials, workers.executor) == [None, None]
    serial = [np.asarray(_Steps().residuals(p, [t.run() for t in _Steps().tasks(p)]))
              for p in trials]
    assert result_bytes(here) == result_bytes(remote) == result_bytes(serial)


def test_workers_that_are_not_workers_are_refused_in_one_line():
    with pytest.raises(ParameterError, match=r"jobs = 'two' must be an integer >= 1"):
        execution.execute(TASKS, "two")


def test_local_workers_are_the_cores_here_whoever_opened_them():
    with open_workers(2) as workers:
        assert (workers.slots, workers.remote) == (2, False)
        with open_workers(workers.executor) as again:  # a caller's pool: the same cores
            assert (again.slots, again.remote, again.executor) == (2, False, workers.executor)
    assert open_workers(None).__enter__() == Workers(None, 1, "this process")


def test_runs_tasks_and_batches_in_one_call_give_their_own_results():
    run = TASKS[0].runs()[0]
    batch = execution.Batch(TASKS[:2], lambda res: ("both", res))
    out = execution.execute([run, batch, TASKS[3]], 2)
    assert result_bytes(out) == result_bytes([simulate_run(run), ("both", _serial(TASKS[:2])),
                                              TASKS[3].run()])


def test_each_job_is_handed_over_as_it_is_done_in_the_order_given():
    seen = []
    out = execution.execute(TASKS, None, failed=execution.Failed,
                            each=lambda k, r: seen.append(k))
    assert seen == list(range(len(TASKS)))
    assert isinstance(out[2], execution.Failed) and "cannot lift" in str(out[2].error)


@pytest.mark.parametrize("command", [["search", "--maxiter", "0", "--popsize", "1"],
                                     ["calibrate", "--max-steps", "1"]])
def test_search_and_calibrate_take_a_scheduler(tmp_path, monkeypatch, capsys, command):
    """--scheduler reaches the workers both commands open (here: Dask not installed,
    refused in one line before anything runs)."""
    monkeypatch.setitem(sys.modules, "distributed", None)  # import fails
    out = tmp_path / ("o" if command[0] == "search" else "c.toml")
    assert main([*command, "--scheduler", "tcp://127.0.0.1:1", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert err == ("wpam: error: Dask scheduler tcp://127.0.0.1:1: Dask distributed is not "
                   'installed; pip install ".[cluster]"'), err


# ---- a cluster that fails: bounded time, one line, a resumable job (issue 37, item 7)


class _Nap:
    """A task that is not a simulation and takes a moment."""

    cost = 1.0

    def run(self) -> float:
        import time  # noqa: PLC0415

        time.sleep(0.5)
        return 1.0


@pytest.fixture
def quick_loss(monkeypatch):
    """A cluster is given up after 1 s instead of 10 s."""
    from wpam_mj.infra import pool  # noqa: PLC0415

    monkeypatch.setattr(pool, "LOST_AFTER_S", 1.0)
    monkeypatch.setattr(execution, "LOST_AFTER_S", 1.0)
    monkeypatch.setattr(execution, "LOST_POLL_S", 0.2)


def _bare_scheduler():
    distributed = pytest.importorskip("distributed")
    return distributed.LocalCluster(n_workers=0, processes=False, dashboard_address=None)


def test_a_cluster_without_workers_ends_the_job_in_one_line(quick_loss, capfd):
    """Before: the scheduler waited for a worker forever, and so did the command."""
    import time  # noqa: PLC0415
    from wpam_mj.infra.pool import WorkersLost  # noqa: PLC0415

    with _bare_scheduler() as cluster, open_workers(Cluster(cluster.scheduler_address)) as w:
        start = time.monotonic()
        with pytest.raises(WorkersLost, match=r"every worker is gone") as lost:
            execution.execute([_Nap()], w)
        assert time.monotonic() - start < 10.0
    assert "\n" not in str(lost.value) and "run the command again" in str(lost.value)
    assert capfd.readouterr().err == ""  # no traceback from Dask's loggers


def test_a_scheduler_that_dies_ends_the_job_in_one_line(quick_loss, capfd):
    import threading  # noqa: PLC0415
    import time  # noqa: PLC0415
    from wpam_mj.infra.pool import WorkersLost  # noqa: PLC0415

    cluster = _bare_scheduler()
    with open_workers(Cluster(cluster.scheduler_address)) as w:
        threading.Timer(0.5, cluster.close).start()
        start = time.monotonic()
        with pytest.raises(WorkersLost, match=r"the scheduler is gone"):
            execution.execute([_Nap()], w)
        assert time.monotonic() - start < 10.0
    assert capfd.readouterr().err == ""


def test_a_scheduler_address_that_is_not_dask_is_refused_in_one_line(tmp_path, capsys):
    """Before: a 64-line traceback ending 'Unable to allocate 3.01 EiB'; and the
    half-made Client left for a later garbage collection, whose __del__ then stalled the
    next in-process cluster's IO loop start past distributed's 10 s."""
    distributed = pytest.importorskip("distributed")
    import gc  # noqa: PLC0415
    import socket  # noqa: PLC0415
    import threading  # noqa: PLC0415

    server = socket.create_server(("127.0.0.1", 0))

    def answer() -> None:  # an HTTP server's answer to whatever it is sent
        while True:
            try:
                conn, _ = server.accept()
            except OSError:
                return
            conn.sendall(b"HTTP/1.1 400 Bad Request\r\nContent-Length: 0\r\n\r\n" * 64)
            conn.close()

    threading.Thread(target=answer, daemon=True).start()
    address = f"tcp://127.0.0.1:{server.getsockname()[1]}"
    try:
        assert main(["search", "--maxiter", "0", "--popsize", "1", "--scheduler", address,
                     "--out", str(tmp_path / "o")]) == 2
    finally:
        server.close()
    assert not [c for c in gc.get_objects() if isinstance(c, distributed.Client)]
    err = capsys.readouterr().err.strip()
    assert err == (f"wpam: error: Dask scheduler {address}: the service there does not "
                   "answer as a Dask scheduler"), err


def test_a_study_whose_cluster_is_gone_says_so_in_one_line_and_resumes_here(
        quick_loss, tmp_path, capsys):
    spec = tmp_path / "s.toml"
    spec.write_text('experiment = "step"\ndt = 5e-3\n[fixed]\nduration = 33.0\n'
                    '[vary]\nmethod = "list"\n[vary.values]\nload = [60, 100]\n')
    out = tmp_path / "study"
    with _bare_scheduler() as cluster:
        code = main(["study", str(spec), "--scheduler", cluster.scheduler_address,
                     "--out", str(out), "--no-progress"])
    err = capsys.readouterr().err.strip()
    assert code == 1 and err.count("\n") == 0 and "every worker is gone" in err, err
    assert main(["study", str(spec), "--out", str(out), "--resume", "--jobs", "1",
                 "--no-progress"]) == 0
    assert (out / "study.csv").read_text().count("\n") == 3  # header and both runs
