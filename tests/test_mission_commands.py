"""Mission commands over Zenoh (``viscover land`` / ``viscover stop``) under 30 % loss, the
one-id-per-mission rule, and hostile command payloads."""

from __future__ import annotations

import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import msgspec
import pytest

from agent.mission.operator import live_agents
from agent.net.router import client_config, start_router_process, stop_router_process
from agent.net.transport import ZenohTransport
from agent.wire import keys
from agent.wire.codec import RateLimitedLogger, RejectCounter
from agent.wire.commands import MissionCommand, codec_for_commands
from agent.wire.departure import DEPARTURE_CODEC, AgentDeparture
from tests.conftest import reap, repo_env, scenario_path, wait_until

HEX = str(scenario_path("hexagon_5_3"))


@pytest.fixture
def router() -> Iterator[str]:
    """A router of this test's own: the tests run the same mission and ids, and a router
    that heard A in an earlier test refuses a new A while that test's agents are still
    leaving (its fence record says the run is under way: agent.runners.recovery)."""
    proc, endpoint = start_router_process()
    yield endpoint
    assert stop_router_process(proc) in (0, -15)


def _agent(aid: str, endpoint: str, state: Path, *extra: str) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [sys.executable, "-m", "agent.cli", "agent", "--id", aid, "--scenario", HEX,
         "--connect", endpoint, "--state-dir", str(state / aid), "--rate-scale", "0.5",
         "--timeout", "90", *extra],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=repo_env())


def _viscover(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "agent.cli", *args], capture_output=True,
                          text=True, env=repo_env(), timeout=60)


def _all_live(endpoint: str, ids: set[str]) -> bool:
    tp = ZenohTransport(client_config([endpoint]), None, "probe")
    try:
        return wait_until(lambda: ids <= live_agents(tp, "hexagon_5_3", 0.3), 30.0)
    finally:
        tp.close()


def test_land_all_under_loss_every_agent_acknowledges_and_leaves(router: str,
                                                                 tmp_path: Path) -> None:
    procs = [_agent(a, router, tmp_path, "--drop", "0.3", "--fault-seed", str(i))
             for i, a in enumerate("ABC")]
    try:
        assert _all_live(router, {"A", "B", "C"})
        t0 = time.monotonic()
        res = _viscover("land", "--all", "--scenario", HEX, "--connect", router)
        if res.returncode != 0:
            errs = reap(procs)
            pytest.fail(res.stdout + res.stderr + "".join(
                f"--- agent {a} stderr:\n{errs[p.pid][-3000:]}"
                for a, p in zip("ABC", procs, strict=True)))
        assert sorted(line.split(":")[0] for line in res.stdout.splitlines()) == ["A", "B", "C"]
        assert all("land acknowledged after" in line for line in res.stdout.splitlines())
        for p in procs:
            _out, err = p.communicate(timeout=30)
            assert p.returncode == 0, err
            assert "leaving the mission: land ordered by operator" in err
        assert time.monotonic() - t0 < 30.0
    finally:
        reap(procs)


def test_stop_one_agent_leaves_the_others_running(router: str, tmp_path: Path) -> None:
    """B obeys, says why on stderr and on the mesh (its departure names the command and the
    landmarks it still holds); A, not addressed, runs on."""
    procs = {a: _agent(a, router, tmp_path) for a in "AB"}
    tp = ZenohTransport(client_config([router]), None, "probe")
    departures: list[AgentDeparture | None] = []  # None: a departure that did not decode
    tp.subscribe(keys.all_agents("hexagon_5_3", "departure"),
                 lambda k, p: departures.append(DEPARTURE_CODEC.decode(p, k)))
    try:
        if not _all_live(router, {"A", "B"}):
            errs = reap(procs.values())
            pytest.fail("".join(f"--- agent {a} stderr:\n{errs[p.pid][-3000:]}"
                                for a, p in procs.items()))
        res = _viscover("stop", "--id", "B", "--scenario", HEX, "--connect", router)
        assert res.returncode == 0 and res.stdout.startswith("B: stop acknowledged"), res.stderr
        _out, err = procs["B"].communicate(timeout=30)
        assert procs["B"].returncode == 0 and "stop ordered by operator" in err
        time.sleep(1.0)
        assert procs["A"].poll() is None  # A was not addressed
        assert departures, "B left without announcing its departure"
        d = departures[0]
        assert d is not None
        assert (d.sender, d.reason) == ("B", "operator_stop")
        assert d.detail.startswith("stop ordered by operator") and d.owned > 0
        assert {x.sender if x is not None else None for x in departures} == {"B"}
    finally:
        tp.close()
        reap(procs.values())


def test_a_second_agent_with_a_live_id_is_refused(router: str, tmp_path: Path) -> None:
    first = _agent("A", router, tmp_path / "one")
    second = None
    try:
        assert _all_live(router, {"A"})
        second = _agent("A", router, tmp_path / "two")
        _out, err = second.communicate(timeout=30)
        assert second.returncode == 2
        assert err == ("viscover: error: agent A is already running on mission hexagon_5_3 "
                       "(its liveliness token is present): stop it first, or start this one "
                       "with another --id\n")
        assert first.poll() is None
    finally:
        reap([first] if second is None else [first, second])


def test_land_names_unknown_agents_in_one_line(router: str) -> None:
    res = _viscover("land", "--id", "A,Z", "--scenario", HEX, "--connect", router)
    assert res.returncode == 2
    assert res.stderr == ("viscover: error: --id: Z not agents of "
                          f"{HEX} (agents: A, B, C)\n")


@pytest.mark.parametrize("bad", [
    {"sender": "x" * 1_000_000, "seq": 1, "command": "land"},
    {"sender": "op", "seq": 2**63, "command": "land"},
    {"sender": "op", "seq": -1, "command": "land"},
    {"sender": "op", "seq": 1, "command": "self_destruct"},
    {"sender": "op", "seq": 1, "command": "land", "targets": [f"D{i}" for i in range(300)]},
    {"sender": "op/../x", "seq": 1, "command": "stop"},
])
def test_hostile_commands_are_rejected_and_counted(bad: dict[str, object]) -> None:
    counter = RejectCounter()
    codec = codec_for_commands(counter, RateLimitedLogger())
    payload = msgspec.msgpack.encode({**bad, "schema": 1})
    assert codec.decode(payload, "viscover/m/command") is None
    assert counter.total == 1
    ok = msgspec.msgpack.encode(MissionCommand(seq=1, command="land", targets=["A"]))
    assert codec.decode(ok, "viscover/m/command") is not None
