"""The static ramps' protocol readings (wpam_mj.experiments.protocol) and their command options."""

from __future__ import annotations

import numpy as np
import pytest

from wpam_mj import cli
from wpam_mj.cli.runs import protocol_of
from wpam_mj.physics.params import preset
from wpam_mj.errors import ParameterError
from wpam_mj.units import MPA
from wpam_mj.experiments.protocol import (SHIPPED, Protocol, ProtocolStaticTask,
                                          open_loop_tasks, static_drive, table2_batch)
from wpam_mj.simulation.execution import execute
from wpam_mj.experiments.paper_studies import StaticTask


def test_the_default_protocol_runs_the_ramps_of_the_static_study():
    params = preset("wpam")
    ours = ProtocolStaticTask(params, 100.0, 0.04 * MPA, 1e-3, Protocol(ramp_time=5.0)).run()
    theirs = StaticTask(params, 100.0, 0.04 * MPA, 1e-3, ramp_time=5.0).run()
    assert ours.area == theirs.area
    assert np.array_equal(ours.result.x, theirs.result.x)


def test_a_common_top_and_a_hold_shape_the_commands():
    params = preset("wpam")
    pr = Protocol(ramp_top=0.2 * MPA, ramp_time=10.0, top_hold=2.0)
    d = static_drive(params, 150.0, 0.04 * MPA, pr, 1e-3)
    t = np.arange(len(d.pi_cmd)) * 1e-3
    assert t[-1] == pytest.approx(1 + 10 + 2 + 10 + 1)
    held = (t >= 11.0) & (t <= 13.0)
    assert np.allclose(d.pi_cmd[held], 0.2 * MPA)  # the same top for every load
    assert np.all(d.po_cmd[t > 11.0] == 0.04 * MPA) and np.all(d.po_cmd[t <= 11.0] == 0.0)
    assert pr.top(params, 50.0) == pr.top(params, 150.0) == 0.2 * MPA
    per_load = Protocol()
    assert per_load.top(params, 50.0) < per_load.top(params, 150.0)
    assert SHIPPED.top(params, 50.0) == SHIPPED.top(params, 150.0)  # one ramp for all loads


@pytest.mark.parametrize("kwargs, match", [
    (dict(ramp_top=-0.1), "ramp_top"), (dict(ramp_time=0.5), "ramp_time"),
    (dict(top_hold=-1.0), "top_hold"), (dict(loop_method="area"), "loop_method")])
def test_bad_readings_are_refused(kwargs, match):
    with pytest.raises(ParameterError, match=match):
        Protocol(**kwargs)


def test_every_reading_is_a_command_option():
    args = cli.build_parser().parse_args(
        ["reproduce", "--ramp-top", "0.19", "--ramp-time", "90", "--top-hold", "1.5",
         "--loop-area", "shoelace", "--po-feedforward", "0.01",
         "--feedforward-friction", "0.9", "--gain-reading", "volts-10"])
    params, protocol = protocol_of(args, preset("wpam"))
    assert protocol == Protocol(0.19 * MPA, 90.0, 1.5, "shoelace")
    c = params.controller
    assert (c.po_feedforward, c.feedforward_friction, c.command_scale) == (0.01 * MPA, 0.9,
                                                                          0.05)
    default = cli.build_parser().parse_args(["reproduce"])
    assert protocol_of(default, preset("wpam")) == (preset("wpam"), SHIPPED)
    per_load = cli.build_parser().parse_args(["reproduce", "--ramp-top", "per-load"])
    assert protocol_of(per_load, preset("wpam"))[1].ramp_top == 0.0


def test_table2_from_open_loops_already_run_is_table2():
    """The open loop does not use the controller, so Table 2 from ramps run before (the
    controller model's calibration runs them) is the Table 2 that runs them itself."""
    params, loads = preset("wpam"), (100.0,)
    ramps = execute(open_loop_tasks(params, SHIPPED, loads, dt=2e-3), 2)
    given, ran = execute([table2_batch(params, SHIPPED, loads=loads, dt=2e-3, open_loops=ramps),
                          table2_batch(params, SHIPPED, loads=loads, dt=2e-3)], 2)
    assert given.open_po == ran.open_po and given.feedback == ran.feedback
    with pytest.raises(ParameterError, match="1 open loops given; Table 2 needs 2"):
        table2_batch(params, SHIPPED, loads=loads, open_loops=ramps[:1])
