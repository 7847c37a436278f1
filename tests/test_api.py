"""The Python API (viscover.api): a kinematic mission launched through it on a real router,
its states iterated until complete, its run folder read; a mission attached to from a second
session and landed through it; a mission rehearsed in memory under faults; its mistakes
raised as one-line UsageErrors."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from agent.errors import UsageError
from tests.conftest import scenario_path
from viscover.api import Mission, Run, simulate

pytestmark = pytest.mark.slow

HEXAGON = str(scenario_path("hexagon_5_3"))


def test_a_launched_mission_is_watched_until_complete_and_its_run_read(
        tmp_path: Path, router: str) -> None:
    with Mission.launch(HEXAGON, runs=tmp_path / "runs", router=router, timeout=90) as m:
        views = list(m.states(period=0.2, timeout=90))
        assert m.wait(60) == 0
        run = m.run
    last = views[-1]
    assert last.complete and last.violations == []
    assert [r.id for r in last.rows] == ["A", "B", "C"]
    assert sum(r.owned for r in last.rows) == 6 and all(r.done for r in last.rows)
    assert any(not v.complete for v in views)  # watched while it ran
    assert any(line.startswith("launch: complete") for line in m.output)
    assert run is not None and run.path.parent == tmp_path / "runs"
    doc = run.launch()
    assert doc is not None and doc["exit_status"] == 0 and doc["router"] == router
    seen = run.observer()
    assert seen is not None and seen["complete"] and sorted(seen["owners"]) == list("123456")


def test_a_mission_landed_through_the_api_ends_by_the_operator(
        tmp_path: Path, router: str) -> None:
    with Mission.launch(HEXAGON, runs=tmp_path / "runs", router=router, rate_scale=0.5,
                        timeout=90) as m:
        for view in m.states(period=0.2, timeout=60):
            if all(r.phase != "-" for r in view.rows):  # every drone heard
                break
        with Mission.attach(HEXAGON, connect=router) as operator:  # as from another machine
            assert operator.live() == {"A", "B", "C"} and operator.run is None
            acks = operator.land()
        assert sorted(acks) == ["A", "B", "C"] and all(t is not None for t in acks.values())
        assert m.wait(60) == 0
        kinds = {type(e).__name__ for e in m.events()}
    assert {"Command", "Ack"} <= kinds
    assert m.run is not None
    doc = m.run.launch()
    assert doc is not None and doc["ended"] == "ended by the operator (land --all)"


def test_a_rehearsal_in_memory_reports_its_invariants(tmp_path: Path) -> None:
    sc = tmp_path / "hexagon.toml"
    sc.write_text(re.sub(r"^duration = .*$", "duration = 200.0\nlost_after = 5.0",
                         scenario_path("hexagon_5_3").read_text(), count=1, flags=re.M))
    sim = simulate(sc, tmp_path / "out", drop=0.3, lose=["C@5"], fault_seed=2)
    assert sim.status == 0 and sim.complete
    assert sim.outcome is not None and sim.outcome.ok and sim.outcome.lost == {"C": 5.0}
    doc = Run(tmp_path / "out").rehearsal()
    assert doc is not None and doc["violations"] == [] and set(doc["observer"]["fenced"]) == {"C"}
    assert Run(tmp_path / "out").result()["complete"]


def test_mistakes_are_usage_errors(tmp_path: Path) -> None:
    with pytest.raises(UsageError, match=r"^--drop 2: must be a probability in \[0, 1\]$"):
        simulate(HEXAGON, drop=2.0)
    with pytest.raises(UsageError, match=r"^--lose Z: not a drone of hexagon_5_3"):
        simulate(HEXAGON, lose=["Z@1"])
    with pytest.raises(UsageError, match=r"^router: "):
        Mission.launch(HEXAGON, runs=tmp_path, router="127.0.0.1:7447")
