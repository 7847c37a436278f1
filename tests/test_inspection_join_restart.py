"""Inspection missions with a changing team: a drone joining a running mission takes part of
the remaining work (in memory, at 0 and 30 % loss), and a real agent process killed with
SIGKILL and restarted from its journal keeps its captures while the mission completes.

What must hold: every capturable landmark is captured; one owner per landmark; a joiner,
starting with no landmark, captures some; a restarted agent's journal keeps its pre-kill
captures; every journaled capture holds when re-checked from its logged pose
(bench.inspection.recheck)."""

from __future__ import annotations

import json
import shutil
import signal
import time
from pathlib import Path

import numpy as np
import pytest

from agent.config.parse import load_scenario
from agent.net.faults import FaultConfig
from agent.protocol.records import CaptureRec
from agent.storage.journal import Journal
from agent.testing.memsim import MemoryMission
from agent.world.structure import resolve_structure
from agent.world.tables import mission_tables
from bench.inspection.recheck import journal_captures, recheck_records
from tests.conftest import flown_tables, scenario_path
from tests.test_agent_processes import RouterBox, router_box, spawn_agent, wait_all
from tests.test_inspection_agents import LOSSY, _run, _scenario

__all__ = ["router_box"]


@pytest.mark.parametrize("faults", [
    pytest.param(None, id="lossless", marks=pytest.mark.long),  # make test: [30% loss], harder
    pytest.param(LOSSY, id="30% loss")])
def test_a_drone_joining_an_inspection_takes_remaining_work(tmp_path: Path,
                                                            faults: FaultConfig | None) -> None:
    """L-shaped building, three drones; at 5 s (about half the landmarks captured) J, not in
    the scenario, joins at (5, -5, 5) m with nothing: admitted by a majority (no vision
    re-split: an inspection's agents do not trade by vision), it takes a share of a busy
    peer's remaining set (the inspection's take-work re-split) and captures landmarks."""
    sc = _scenario("l_building")
    ids = np.asarray(sc.landmark_ids)
    mm = MemoryMission(sc, tmp_path, faults=faults, seed=4)
    try:
        table = flown_tables(mm)[0]
        _run(mm, 5.0)
        before = {lid for rt in mm.agents.values() for lid in rt.core.machine.captured}
        assert 0 < len(before) < int(table.capturable.sum())
        j = mm.join("J", [5.0, -5.0, 5.0], [1.0, 0.0, 0.0])
        _run(mm, 300.0)
        assert mm.complete and mm.final_violations() == [] and mm.violations == []
        assert "J" in j.core.machine.members
        assert all("J" in rt.core.machine.members for rt in mm.agents.values())
        mine = set(j.core.machine.captured)
        assert mine, "the joiner captured nothing"
        assert not (mine & before)  # it captured only remaining work
        ins = j.core.planning.inspecting
        assert ins is not None and ins.complete
        owners = [lid for rt in mm.agents.values() for lid in rt.core.machine.owned]
        assert sorted(owners) == sorted(ids.tolist())  # one owner per landmark
    finally:
        mm.close()
    recs = journal_captures(tmp_path, [*(a.id for a in sc.agents), "J"])
    assert {lid for r in recs for lid in r.ids} == set(ids[table.capturable].tolist())
    assert recheck_records(sc, recs) == 0


def _captures_now(state: Path, tmp: Path) -> list[CaptureRec]:
    """The CaptureRec of a running agent's journal (read from a copy: the agent holds the
    journal's lock)."""
    src = state / "journal.bin"
    if not src.exists():
        return []
    if tmp.exists():
        shutil.rmtree(tmp)
    tmp.mkdir(parents=True)
    shutil.copyfile(src, tmp / "journal.bin")
    j = Journal(tmp)
    try:
        return [r for r in j.replay() if isinstance(r, CaptureRec)]
    finally:
        j.close()


@pytest.mark.slow
@pytest.mark.serial
@pytest.mark.long  # make test checks it faster: the journal kept in memory, the process seam in
# test_inspection_agents.py::test_a_restarted_agent_keeps_its_captures_and_the_mission_completes
# test_agent_processes.py::test_sigkill_mid_trade_and_restart
def test_sigkill_and_restart_of_an_inspecting_agent_process(router_box: RouterBox,
                                                            tmp_path: Path) -> None:
    """Wind-turbine inspection, three kinematic agent processes on a router: B is killed with
    SIGKILL once its journal holds two captures and restarted with the same state directory
    0.3 s later; the mission completes with every capturable landmark captured, B's journal
    keeps its pre-kill captures, and every capture holds when re-checked."""
    path = scenario_path("inspect_wind_turbine")
    sc = resolve_structure(load_scenario(path))
    table, _ = mission_tables(sc)
    ep = router_box["endpoint"]
    state = tmp_path / "state"
    procs = {a.id: spawn_agent(a.id, path, ep, state, timeout=120.0) for a in sc.agents}
    pre: list[CaptureRec] = []
    deadline = time.monotonic() + 60.0
    while len(pre) < 2 and time.monotonic() < deadline and procs["B"].poll() is None:
        time.sleep(0.05)
        pre = _captures_now(state / "B", tmp_path / "peek")
    assert len(pre) >= 2, "B journaled no capture in time"
    procs["B"].send_signal(signal.SIGKILL)
    procs["B"].wait()
    assert procs["B"].returncode == -signal.SIGKILL
    time.sleep(0.3)
    procs["B"] = spawn_agent("B", path, ep, state, timeout=120.0)
    outs = wait_all(list(procs.values()), timeout=150)
    capturable = int(table.capturable.sum())
    for out in outs:  # each agent's result line
        line = json.loads(next(x for x in out.splitlines() if x.startswith("{")))
        assert line["captured"] == line["capturable"] == capturable
    after = journal_captures(state, ["B"])
    assert {(r.t, tuple(r.ids)) for r in pre} <= {(r.t, tuple(r.ids)) for r in after}
    recs = journal_captures(state, [a.id for a in sc.agents])
    assert {lid for r in recs for lid in r.ids} == \
        set(np.asarray(sc.landmark_ids)[table.capturable].tolist())
    assert recheck_records(sc, recs) == 0
