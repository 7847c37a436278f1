"""A mission whose agents attach to different Zenoh routers linked as a mesh.

Three routers on free loopback ports, each linked to the two others (the triangle of
``broker_config/mesh_router_*.json5``), one agent process per router: every trade crosses the
mesh. An observer on one router checks the ownership invariant on every state it hears and
waits for completion; each agent exits 0 only once it saw the mission complete (completion
agreed). The second case kills one router mid-mission for good: its agent attaches to the next
router it lists and the mission ends as on one router.
"""

from __future__ import annotations

import json
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
import zenoh

from agent.cli import main
from agent.config.parse import load_scenario
from agent.net.router import free_tcp_port, start_router_process, stop_router_process
from agent.wire import keys
from tests.agent_helpers import ROOT
from tests.conftest import repo_env
from tests.test_agent_processes import HEXAGON, InTestObserver, _reap, spawn_agent, wait_all

__all__ = ["_reap"]  # the agent processes a failed test leaves are killed (by pid)

BROKER = ROOT / "broker_config"


def _endpoints(path: Path, key: str) -> list[str]:
    """``key``/endpoints of a Zenoh config file, read by Zenoh itself (a misspelt key, or a
    value of the wrong type, fails here as it would fail ``viscover router``)."""
    return list(json.loads(zenoh.Config.from_file(str(path)).get_json(f"{key}/endpoints")))


def test_example_mesh_configs_form_a_triangle() -> None:
    """Each example router listens on its own port and dials the two others (no router
    left out, none dialling itself) and retries for ever; the example agent lists all
    three, router 2 first."""
    ports = {i: _endpoints(BROKER / f"mesh_router_{i}.json5", "listen")[0].rsplit(":", 1)[1]
             for i in (1, 2, 3)}
    assert len(set(ports.values())) == 3
    for i in (1, 2, 3):
        path = BROKER / f"mesh_router_{i}.json5"
        cfg = zenoh.Config.from_file(str(path))
        assert json.loads(cfg.get_json("mode")) == "router"
        assert json.loads(cfg.get_json("connect/timeout_ms")) == -1
        dialled = {e.rsplit(":", 1)[1] for e in _endpoints(path, "connect")}
        assert dialled == {ports[j] for j in (1, 2, 3) if j != i}, i
    agent = [e.rsplit(":", 1)[1] for e in _endpoints(BROKER / "mesh_agent.json5", "connect")]
    assert agent == [ports[2], ports[1], ports[3]]


Mesh = list[tuple[subprocess.Popen[bytes], str]]


def start_mesh(n: int = 3) -> Mesh:
    """``n`` routers on free loopback ports, each dialling every other (a full mesh)."""
    ports = [free_tcp_port() for _ in range(n)]
    eps = [f"tcp/127.0.0.1:{p}" for p in ports]
    mesh: Mesh = []
    try:
        for i, port in enumerate(ports):
            mesh.append(start_router_process(port, connect=[e for e in eps if e != eps[i]]))
    except BaseException:
        for proc, _ep in mesh:
            stop_router_process(proc)
        raise
    return mesh


@pytest.fixture
def mesh() -> Iterator[Mesh]:
    """Three meshed routers, stopped after the test (a test may have stopped one)."""
    routers = start_mesh()
    yield routers
    for proc, _ep in routers:
        stop_router_process(proc)


def _said(outs: list[str]) -> dict[str, dict[str, object]]:
    return {doc["agent"]: doc for doc in (json.loads(line) for o in outs
                                           for line in o.splitlines() if line.startswith("{"))}


@pytest.mark.slow
@pytest.mark.serial
def test_three_router_mesh_mission(mesh: Mesh, tmp_path: Path) -> None:
    """A on router 1, B on router 2, C on router 3 (each knows only its own router): the
    mission completes with no violation, every landmark owned exactly once, every agent saw it
    complete, and trades went through the mesh (every trade is between two routers)."""
    sc = load_scenario(HEXAGON)
    eps = [ep for _p, ep in mesh]
    ob = InTestObserver(eps[0], sc, "hexagon_5_3")
    try:
        time.sleep(0.5)  # the routers' links up and the observer subscribed
        outs = wait_all([spawn_agent(a, HEXAGON, ep, tmp_path, timeout=60.0)
                         for a, ep in zip("ABC", eps, strict=True)], timeout=90.0)
        assert ob.wait(20.0)
        rep = ob.obs.snapshot()
        assert rep.violations == [] and rep.complete
        assert sorted(rep.owners) == sorted(sc.landmark_ids)  # each once: a map by landmark
        assert rep.coverage >= (rep.coverage_initial or 0.0) - 1e-9
        said = _said(outs)
        assert sorted(said) == ["A", "B", "C"]
        assert sum(int(str(d["ok"])) for d in said.values()) >= 2  # trades crossed the mesh
    finally:
        ob.close()


@pytest.mark.slow
@pytest.mark.serial
def test_router_lost_mid_mission_agent_moves_to_another(mesh: Mesh, tmp_path: Path) -> None:
    """Router 2 is stopped for good once every agent publishes: B, which lists router 2 first
    and the others after it, was on it (its liveliness token goes with the router, and only
    B's) and comes back through router 3; the mission completes on the two routers left, no
    violation, every landmark owned once, every agent exiting 0 after completion."""
    sc = load_scenario(HEXAGON)
    eps = [ep for _p, ep in mesh]
    order = {"A": [0, 1, 2], "B": [1, 2, 0], "C": [2, 0, 1]}
    ob = InTestObserver(eps[0], sc, "hexagon_5_3")
    tokens: list[tuple[str, bool]] = []  # (agent, up) of every token change
    watch = ob.tp.watch_liveliness(keys.all_agents("hexagon_5_3", "alive"),
                                   lambda k: tokens.append((k.rsplit("/", 1)[1], True)),
                                   lambda k: tokens.append((k.rsplit("/", 1)[1], False)))
    try:
        time.sleep(0.5)
        procs = []
        for a, idx in order.items():
            connect = [x for i in idx[1:] for x in ("--connect", eps[i])]
            procs.append(spawn_agent(a, HEXAGON, eps[idx[0]], tmp_path, *connect,
                                     timeout=60.0))
        deadline = time.monotonic() + 30.0
        while len(ob.obs.latest) < 3 and time.monotonic() < deadline:
            time.sleep(0.02)  # every agent is up and publishing: mid-mission
        assert len(ob.obs.latest) == 3 and not ob.obs.done.is_set()
        before = len(tokens)
        stop_router_process(mesh[1][0])
        deadline = time.monotonic() + 10.0
        while ("B", True) not in tokens[before + 1:] and time.monotonic() < deadline:
            time.sleep(0.02)
        moved = tokens[before:]
        # B left with router 2 and came back through another; A and C were not touched
        assert moved[:2] == [("B", False), ("B", True)], moved
        wait_all(procs, timeout=90.0)  # each exits 0 only once it saw the mission complete
        assert ob.wait(20.0)
        rep = ob.obs.snapshot()
        assert rep.violations == [] and rep.complete
        assert sorted(rep.owners) == sorted(sc.landmark_ids)
    finally:
        watch.undeclare()
        ob.close()


@pytest.mark.slow
def test_launch_three_routers_spreads_the_agents(tmp_path: Path) -> None:
    """``viscover launch --routers 3``: three meshed routers, A, B and C each first on its own
    (the two others after it), the mission complete with no violation, nothing left running
    (the three routers' ports closed)."""
    proc = subprocess.run(
        [sys.executable, "-m", "agent.cli", "launch", str(HEXAGON), "--routers", "3",
         "--no-record", "--timeout", "60", "--runs", str(tmp_path / "runs")],
        capture_output=True, text=True, env=repo_env(), cwd=tmp_path, timeout=150)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    (run,) = (tmp_path / "runs").iterdir()
    doc = json.loads((run / "launch.json").read_text())
    routers = [doc["router"], *doc["mesh"]]
    assert len(set(routers)) == 3 and doc["ended"] == "complete"
    for k, aid in enumerate("ABC"):
        cmd = doc["processes"][aid]["cmd"]
        connect = [cmd[i + 1] for i, x in enumerate(cmd) if x == "--connect"]
        assert connect == routers[k:] + routers[:k], (aid, connect)
        assert doc["processes"][aid]["exit_code"] == 0
    rep = json.loads((run / "observer.json").read_text())
    assert rep["complete"] and rep["violations"] == []
    assert sorted(rep["owners"]) == ["1", "2", "3", "4", "5", "6"]
    for ep in routers:
        host, port = ep.split("/", 1)[1].rsplit(":", 1)
        with pytest.raises(OSError), socket.create_connection((host, int(port)), timeout=1):
            pass


@pytest.mark.parametrize(("args", "message"), [
    (["--routers", "0"], "--routers 0: give 1 to 8 routers"),
    (["--routers", "3", "--router", "tcp/127.0.0.1:7447"],
     "--routers 3 starts the routers here: drop --router"),
])
def test_launch_routers_mistakes_are_one_line(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch,
        args: list[str], message: str) -> None:
    monkeypatch.chdir(tmp_path)
    assert main(["launch", str(HEXAGON), *args, "--runs", str(tmp_path / "runs")]) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err
    assert not (tmp_path / "runs").exists() or not any((tmp_path / "runs").iterdir())
