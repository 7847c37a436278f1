"""Real agent processes over a real Zenoh router on a free loopback port.

Agents run ``python -m agent.cli agent`` (``viscover agent``) with a faster-than-real-time mission
clock; an observer (process or in-test) checks the ownership invariant on every state it
receives and waits for global termination.
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import TypedDict

import numpy as np
import pytest

from agent.config.parse import load_scenario
from agent.config.scenario import Scenario
from agent.core.vision import per_landmark
from agent.mission.observer import Observer
from agent.net.router import client_config, start_router_process, stop_router_process
from agent.net.transport import ZenohTransport
from agent.wire import keys
from agent.wire.codec import Codec
from agent.wire.peer import AgentState, Publication
from tests.agent_helpers import ROOT, random_scene_toml
from tests.conftest import repo_env

pytestmark = [pytest.mark.slow, pytest.mark.serial]

HEXAGON = ROOT / "scenarios" / "hexagon_5_3.toml"
RATE = "10"


_SPAWNED: list[subprocess.Popen[str]] = []


@pytest.fixture(autouse=True)
def _reap() -> Iterator[None]:
    """Kill (by pid) any agent process a failed test left behind."""
    yield
    while _SPAWNED:
        p = _SPAWNED.pop()
        if p.poll() is None:
            p.kill()
        p.communicate()


def spawn_agent(aid: str, scenario: Path, endpoint: str, state: Path, *extra: str,
                timeout: float = 90.0) -> subprocess.Popen[str]:
    cmd = [sys.executable, "-m", "agent.cli", "agent", "--id", aid,
           "--scenario", str(scenario), "--connect", endpoint, "--state-dir", str(state / aid),
           "--rate-scale", RATE, "--request-timeout", "0.15", "--exit-on-complete",
           "--timeout", str(timeout), *extra]
    p = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                         env=repo_env())
    _SPAWNED.append(p)
    return p


def wait_all(procs: list[subprocess.Popen[str]], timeout: float = 120.0) -> list[str]:
    outs = []
    for p in procs:
        try:
            out, err = p.communicate(timeout=timeout)
        except subprocess.TimeoutExpired:
            p.kill()
            out, err = p.communicate()
        assert p.returncode == 0, f"agent exited {p.returncode}: {err[-3000:]}"
        outs.append(out)
    return outs


class RouterBox(TypedDict):
    """A restartable router: its process (a test may replace it) and endpoint."""

    proc: subprocess.Popen[bytes]
    endpoint: str


@pytest.fixture
def router_box() -> Iterator[RouterBox]:
    """A router per test, restartable (the box holds its process and endpoint)."""
    proc, endpoint = start_router_process()
    box: RouterBox = {"proc": proc, "endpoint": endpoint}
    yield box
    stop_router_process(box["proc"])


class InTestObserver:
    """An :class:`Observer` on its own Zenoh session inside the test process."""

    def __init__(self, endpoint: str, scenario: Scenario, mission: str) -> None:
        self.tp = ZenohTransport(client_config(endpoint), None, "test-observer")
        self.obs = Observer(self.tp, mission, [a.id for a in scenario.agents],
                            list(scenario.landmark_ids), initial=scenario.initial_sets())

    def wait(self, timeout: float) -> bool:
        return self.obs.done.wait(timeout)

    def close(self) -> None:
        self.obs.close()
        self.tp.close()


def test_hexagon_loss_free_observer_process(router_box: RouterBox, tmp_path: Path) -> None:
    """3 agents, 0 % loss, observer process: no violation, termination, the coverage score
    never below its start (Proposition 4 across processes), and every agent's own account of
    what it does not see matches its final pose. Which local optimum asynchronous agents
    reach depends on timing (landmark 6 sometimes stays unseen with A); the deterministic
    comparison with the kinematic simulator is in tests/test_protocol_memory.py."""
    ep = router_box["endpoint"]
    out_json = tmp_path / "obs.json"
    obs = subprocess.Popen(
        [sys.executable, "-m", "agent.cli", "observe", "--scenario",
         str(HEXAGON), "--connect", ep, "--until-complete", "--timeout", "90", "--json-out",
         str(out_json)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=repo_env())
    time.sleep(0.5)  # let the observer subscribe before the first states
    outs = wait_all([spawn_agent(a, HEXAGON, ep, tmp_path) for a in "ABC"])
    try:
        out, err = obs.communicate(timeout=120)
    finally:
        if obs.poll() is None:
            obs.kill()
            obs.communicate()
    assert obs.returncode == 0, out + err
    rep = json.loads(out_json.read_text())
    assert rep["complete"] and rep["violations"] == []
    assert rep["coverage"] >= rep["coverage_initial"] - 1e-9
    said = {doc["agent"]: doc for doc in (json.loads(line) for o in outs
                                           for line in o.splitlines() if line.startswith("{"))}
    assert sorted(said) == ["A", "B", "C"]
    sc = load_scenario(HEXAGON)
    for j, lid in enumerate(sc.landmark_ids):
        owner = rep["owners"][str(lid)]
        a = rep["agents"][owner]
        seen = per_landmark(np.array(a["p"]), np.array(a["v"]), sc.q[j:j + 1],
                            sc.u[j:j + 1], sc.d_opt)[0] > 0
        assert seen == (lid not in said[owner]["unseen"]), (lid, owner, said[owner])


@pytest.mark.parametrize(("drop", "seed"), [
    pytest.param("0.1", 1, marks=pytest.mark.long),  # make test: [0.3-0], more loss
    ("0.3", 0),
    # make test: [0.3-0] over processes, and 50 % loss in memory in
    # test_protocol_memory.py::test_thesis_scenarios_under_loss[1-hexagon_5_3-0.5]
    pytest.param("0.5", 1, marks=pytest.mark.long)])
def test_hexagon_lossy(router_box: RouterBox, tmp_path: Path, drop: str, seed: int) -> None:
    """3 agents, 10/30/50 % loss of every message kind (more seeds: the in-memory protocol
    tests and ``make bench``; make test runs 30 %, make test-long the others)."""
    sc = load_scenario(HEXAGON)
    ob = InTestObserver(router_box["endpoint"], sc, "hexagon_5_3")
    try:
        wait_all([spawn_agent(a, HEXAGON, router_box["endpoint"], tmp_path, "--drop", drop,
                              "--fault-seed", str(100 * seed + i),
                              "--fault-log", str(tmp_path / f"{a}.jsonl"))
                  for i, a in enumerate("ABC")])
        assert ob.wait(20.0)
        rep = ob.obs.snapshot()
        assert rep.violations == [] and rep.complete
        assert rep.coverage >= (rep.coverage_initial or 0.0)
        assert (tmp_path / "A.jsonl").stat().st_size > 0  # faults were injected and logged
    finally:
        ob.close()


@pytest.mark.parametrize(("drop", "seed"), [
    pytest.param("0.0", 0, marks=pytest.mark.long),  # make test: [0.3-1], the same but lossy
    ("0.3", 1)])
def test_eight_agents_lossy(router_box: RouterBox, tmp_path: Path, drop: str, seed: int
                            ) -> None:
    """8 agent processes on a 12-landmark scene, 0 and 30 % loss of every message kind (50 %
    with 8 processes is mostly timeouts and takes a minute: ``bench.bench_net``'s swarm rows
    and the in-memory protocol tests cover heavier loss)."""
    path = tmp_path / "eight.toml"
    path.write_text(random_scene_toml(8, 12, 4, dims=2))
    sc = load_scenario(path)
    heavy = float(drop) >= 0.5
    extra = ("--request-timeout", "0.06") if heavy else ()
    ob = InTestObserver(router_box["endpoint"], sc, sc.name)
    try:
        wait_all([spawn_agent(a.id, path, router_box["endpoint"], tmp_path, "--drop", drop,
                              "--fault-seed", str(100 * seed + i), *extra,
                              timeout=240.0 if heavy else 90.0)
                  for i, a in enumerate(sc.agents)], timeout=300 if heavy else 150)
        assert ob.wait(20.0)
        rep = ob.obs.snapshot()
        assert rep.violations == [] and rep.complete
    finally:
        ob.close()


def test_sigkill_mid_trade_and_restart(router_box: RouterBox, tmp_path: Path) -> None:
    """SIGKILL the first agent seen in a trade (messages are slowed so trades last; an
    initiator's offer runs on its tick thread, so it is mostly seen as a responder), restart
    it with the same id and state directory: nothing lost or duplicated, mission completes."""
    sc = load_scenario(HEXAGON)
    ep = router_box["endpoint"]
    ob = InTestObserver(ep, sc, "hexagon_5_3")
    victim: list[str] = []
    mid_trade = threading.Event()
    codec: Codec[Publication] = Codec(Publication)
    seen: list[str] = []

    def on_state(key: str, payload: bytes) -> None:
        st = codec.decode(payload, key)
        if not isinstance(st, AgentState):
            return
        seen.append(f"{st.sender}:{st.phase}:{st.pending}")
        if (st.pending or st.phase in ("trading", "in_doubt")) and not victim:
            victim.append(st.sender)
            mid_trade.set()

    sub = ob.tp.subscribe(keys.all_agents("hexagon_5_3", "state"), on_state)
    try:
        slow = ("--delay", "0.04")  # query + reply 0.08 s < the 0.15 s request timeout
        procs = {a: spawn_agent(a, HEXAGON, ep, tmp_path, *slow) for a in "ABC"}
        assert mid_trade.wait(60.0), seen[-30:]
        v = victim[0]
        procs[v].send_signal(signal.SIGKILL)
        procs[v].wait()
        time.sleep(0.3)
        procs[v] = spawn_agent(v, HEXAGON, ep, tmp_path)
        wait_all(list(procs.values()))
        assert ob.wait(20.0)
        rep = ob.obs.snapshot()
        assert rep.violations == [] and rep.complete
        assert sorted(rep.owners) == sorted(sc.landmark_ids)
        with (tmp_path / v / "journal.bin").open("rb"):
            pass
    finally:
        sub.undeclare()
        ob.close()


def test_router_killed_and_restarted(router_box: RouterBox, tmp_path: Path) -> None:
    sc = load_scenario(HEXAGON)
    ep = router_box["endpoint"]
    port = int(ep.rsplit(":", 1)[1])
    ob = InTestObserver(ep, sc, "hexagon_5_3")
    try:
        procs = [spawn_agent(a, HEXAGON, ep, tmp_path) for a in "ABC"]
        deadline = time.monotonic() + 30.0
        while len(ob.obs.latest) < 3 and time.monotonic() < deadline:
            time.sleep(0.02)  # every agent is up and publishing: mid-mission
        assert len(ob.obs.latest) == 3 and not ob.obs.done.is_set()
        stop_router_process(router_box["proc"])
        time.sleep(1.0)
        router_box["proc"], _ = start_router_process(port)
        wait_all(procs)  # each agent exits 0 only once it saw the mission complete
        assert ob.wait(20.0)
        rep = ob.obs.snapshot()
        assert rep.violations == [] and rep.complete
    finally:
        ob.close()


def test_two_linked_routers_trade_as_one(router_box: RouterBox, tmp_path: Path) -> None:
    """A and B on router 1, C on router 2 linked to router 1: one mission across the link
    (C's trades with A and B go through both routers): complete, no violation, every
    landmark owned once, the coverage score not below its start. (The final partition is
    the simulator's in most runs; which local optimum asynchronous agents reach depends on
    timing, see test_hexagon_loss_free_observer_process.)"""
    sc = load_scenario(HEXAGON)
    proc2, ep2 = start_router_process(connect=[router_box["endpoint"]])
    ob = InTestObserver(ep2, sc, "hexagon_5_3")
    try:
        time.sleep(0.3)
        procs = [spawn_agent("A", HEXAGON, router_box["endpoint"], tmp_path),
                 spawn_agent("B", HEXAGON, router_box["endpoint"], tmp_path),
                 spawn_agent("C", HEXAGON, ep2, tmp_path)]
        outs = wait_all(procs)
        assert ob.wait(20.0)
        rep = ob.obs.snapshot()
        assert rep.violations == [] and rep.complete
        assert sorted(rep.owners) == sorted(sc.landmark_ids)
        assert rep.coverage >= (rep.coverage_initial or 0.0) - 1e-9
        c = next(json.loads(x) for x in outs[2].splitlines() if x.startswith("{"))
        assert c["agent"] == "C" and c["ok"] >= 1  # C traded across the link
    finally:
        ob.close()
        stop_router_process(proc2)
