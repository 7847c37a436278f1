"""The open profile is unauthenticated by design, but a single unverified message must not
hold the mission up for ever (issue 21, item 9), with real agent processes on a real router:

* one forged state of agent A with incarnation 1,000,000: the agents and the observer take
  A's genuine states again once they speak after the forgery went quiet; the mission
  completes and the observer reports no violation;
* a fake ``alive/N3`` liveliness token for a drone that never speaks: it counts as gone after
  ``silent_s`` (said in one line), the team fences N3 and adopts its landmarks, and the
  mission completes with every landmark owned once (the agents' code on virtual time in make
  test; the processes, held ``silent_s`` = 10 s of real time, in make test-long).
"""

from __future__ import annotations

import subprocess
import time
from pathlib import Path

import msgspec
import pytest

from agent.config.parse import load_scenario
from agent.net.router import client_config
from agent.net.transport import ZenohTransport
from agent.testing.memsim import MemoryMission
from agent.wire import keys
from agent.wire.codec import Codec
from agent.wire.peer import AgentState, Publication
from agent.wire.streams import LatestStates
from tests.agent_helpers import random_scene_toml
from tests.conftest import reap, wait_until
from tests.test_adoption_memory import assert_every_landmark_owned_once
from tests.test_agent_processes import HEXAGON, InTestObserver, RouterBox, router_box, spawn_agent

__all__ = ["router_box"]

PUB: Codec[Publication] = Codec(Publication)


def test_latest_states_bound_a_forged_stream() -> None:
    s = LatestStates(quiet_s=2.0)
    assert s.offer("A", 1, 1, 0.0) and s.offer("A", 1, 2, 0.2)
    assert s.offer("A", 1_000_000, 1, 0.3)  # the forgery is newest for now
    assert not s.offer("A", 1, 3, 0.4)  # the genuine stream, while the forgery is fresh
    assert not s.offer("A", 1, 4, 2.4)  # quiet for 2.1 s: a candidate ...
    assert s.offer("A", 1, 5, 2.6)  # ... that spoke twice: it takes over
    assert not s.offer("A", 1, 4, 5.0)  # one late duplicate of an old state changes nothing
    assert not s.offer("A", 1, 3, 8.0) and s.offer("A", 1, 6, 8.1)
    assert s.offer("A", 2, 1, 8.2)  # a genuine restart (a new incarnation) is taken at once


@pytest.mark.serial
def test_a_forged_state_with_a_huge_incarnation_stalls_nothing(
        router_box: RouterBox, tmp_path: Path) -> None:
    sc = load_scenario(HEXAGON)
    ep = router_box["endpoint"]
    ob = InTestObserver(ep, sc, "hexagon_5_3")
    forger = ZenohTransport(client_config(ep), None, "forger")
    procs: list[subprocess.Popen[str]] = []
    try:
        procs = [spawn_agent(a, HEXAGON, ep, tmp_path, "--delay", "0.02", timeout=60.0)
                 for a in "ABC"]
        assert wait_until(lambda: len(ob.obs.latest) == 3, 30.0)
        genuine = ob.obs.latest["A"]
        assert isinstance(genuine, AgentState)
        forged = msgspec.structs.replace(genuine, incarnation=1_000_000)
        forger.publish(keys.state_key("hexagon_5_3", "A"), PUB.encode(forged))
        for p in procs:
            _out, err = p.communicate(timeout=90)
            assert p.returncode == 0, err[-2000:]  # each saw the mission complete
        assert ob.wait(10.0)
        rep = ob.obs.snapshot()
        assert rep.complete and rep.violations == [], rep.violations
        assert sorted(rep.owners) == sorted(sc.landmark_ids)
    finally:
        reap(procs)
        forger.close()
        ob.close()


def test_a_fake_liveliness_token_holds_an_in_memory_mission_for_a_bounded_time(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    """The agents' code on virtual time (the next test: processes): a token ``alive/N3`` for
    a drone that never speaks counts as gone after ``silent_s``, said in one line by every
    agent; the team fences N3, adopts its landmarks and completes, every landmark owned once,
    ``silent_s`` + ``lost_after`` + the adoption's rounds after the start."""
    scene = tmp_path / "scene.toml"
    scene.write_text("lost_after = 20.0\n" + random_scene_toml(4, 12, 2, dims=2))
    sc = load_scenario(scene)
    mm = MemoryMission(sc, tmp_path / "state", autostart=False)
    try:
        mm.net.transport("faker").declare_liveliness(keys.alive_key(mm.cfg.mission, "N3"))
        for a in sc.agents[:3]:  # N3 itself never starts
            mm.start(a.id)
        assert mm.run(sc.duration), f"not complete at {mm.net.now:.0f} s"
        assert mm.violations == [] and mm.final_violations() == []
        assert mm.fenced == {"N3"}
        assert_every_landmark_owned_once(mm)
        assert mm.net.now < mm.cfg.silent_s + sc.lost_after + 10.0, mm.net.now
    finally:
        mm.close()
    said = [r.getMessage() for r in caplog.records
            if "N3 holds a liveliness token but published nothing" in r.getMessage()]
    assert sorted(m.split(":")[0] for m in said) == ["agent N0", "agent N1", "agent N2"]


@pytest.mark.serial
@pytest.mark.long  # make test: the in-memory test above, the agents' code on virtual time
def test_a_fake_liveliness_token_holds_the_mission_for_a_bounded_time(
        router_box: RouterBox, tmp_path: Path) -> None:
    scene = tmp_path / "scene.toml"
    scene.write_text("lost_after = 20.0\n" + random_scene_toml(4, 12, 2, dims=2))
    sc = load_scenario(scene)
    ep = router_box["endpoint"]
    ob = InTestObserver(ep, sc, sc.name)
    faker = ZenohTransport(client_config(ep), None, "faker")
    procs: list[subprocess.Popen[str]] = []
    try:
        faker.declare_liveliness(keys.alive_key(sc.name, "N3"))  # N3 itself never starts
        time.sleep(0.2)
        t0 = time.monotonic()
        procs = [spawn_agent(a.id, scene, ep, tmp_path, timeout=60.0) for a in sc.agents[:3]]
        errs = []
        for p in procs:
            _out, err = p.communicate(timeout=90)
            assert p.returncode == 0, err[-2000:]
            errs.append(err)
        took = time.monotonic() - t0
        said = [line for e in errs for line in e.splitlines()
                if "N3 holds a liveliness token but published nothing" in line]
        assert said, errs[0][-2000:]
        assert ob.wait(10.0)
        rep = ob.obs.snapshot()
        assert rep.complete and rep.violations == [] and set(rep.fenced) == {"N3"}
        assert sorted(rep.owners) == sorted(sc.landmark_ids)
        assert took < 60.0
    finally:
        reap(procs)
        faker.close()
        ob.close()
