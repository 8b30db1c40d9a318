"""The global search on a cheap stand-in for the paper's targets: seeded and
deterministic, journaled, resumable without rerunning, and its archive a feasibility map.
The paper's own targets take minutes per generation: scripts/global_search.py."""

from __future__ import annotations

import json

import numpy as np
import pytest

from wpam_mj.reproduction import findings_map
from wpam_mj.reproduction import search
from wpam_mj.physics.params import ParameterError, preset
from wpam_mj.experiments.protocol import Protocol


class _Task:
    cost = 1.0

    def __init__(self, value: float) -> None:
        self.value = value

    def run(self) -> float:
        _Task.runs += 1
        return self.value


_Task.runs = 0


class _Targets:
    """Two findings that conflict (a high and a low Kf) and the rest met by a low mu."""

    def __init__(self, protocol: Protocol) -> None:
        self.protocol = protocol

    def tasks(self, params):
        return [_Task(params.muscle.output_coeff), _Task(params.muscle.friction_coeff)]

    def score(self, params, results):
        kf, mu = results
        margins = dict.fromkeys(search.FINDINGS, 0.2 - mu)
        margins["table2_po_row"] = kf - 0.8
        margins["gain_spread"] = 0.7 - kf
        r = np.array([max(0.0, -m) for m in margins.values()])
        return r, margins, {"step_error_mm": {"pi": [0.1]}, "table2_po_row": [kf, mu, 0.06]}


def _search(tmp_path, **kw):
    return search.search(tmp_path, popsize=1, maxiter=2, jobs=1, progress=False,
                         targets=_Targets, **kw)


def test_search_is_seeded_journaled_and_resumes_without_rerunning(tmp_path):
    _Task.runs = 0
    first = _search(tmp_path / "a")
    runs = _Task.runs
    assert runs == 2 * first.evaluations
    lines = (tmp_path / "a" / "journal.jsonl").read_text().splitlines()
    assert len(lines) == first.evaluations and json.loads(lines[0])["margins"]
    again = _search(tmp_path / "b")
    assert again.best == first.best  # same seed, same search
    # an interrupted journal (half its lines, the last one cut) resumes to the same end
    cut = lines[:len(lines) // 2] + [lines[len(lines) // 2][:10]]
    (tmp_path / "b" / "journal.jsonl").write_text("\n".join(cut) + "\n")
    _Task.runs = 0
    resumed = _search(tmp_path / "b", resume=True)
    assert resumed.best == first.best
    assert _Task.runs == 2 * (first.evaluations - len(lines) // 2)
    with pytest.raises(ParameterError, match="no journal"):
        _search(tmp_path / "c", resume=True)


def test_the_archive_maps_which_findings_conflict(tmp_path):
    records = _search(tmp_path).records
    pm = findings_map.pair_margins(records)
    i, j = search.FINDINGS.index("table2_po_row"), search.FINDINGS.index("gain_spread")
    assert pm[i, i] > 0 and pm[j, j] > 0 and pm[i, j] < 0  # each alone, never together
    assert ("table2_po_row", "gain_spread", pm[i, j]) in findings_map.conflicts(pm)
    assert findings_map.best_compromise(records).cost == min(r.cost for r in records)
    assert findings_map.most_findings(records).held == max(r.held for r in records)
    assert "while F1" in findings_map.markdown(pm, records)
    assert findings_map.figure(pm, tmp_path / "map.png", "test").stat().st_size > 1000


def test_coordinates_round_trip_the_shipped_point():
    base = preset("wpam")
    point = search.point_of(search.coordinates_of(search.Point(base, Protocol())), base)
    assert point.params == base
    assert point.protocol.ramp_top == 0.0 and point.protocol.loop_method == "branches"
    assert point.protocol.ramp_time == pytest.approx(60.0)
