"""Signed trades across a receiver's restart and across skewed clocks (issue "No single peer,
disk or file can lose a landmark", items 4 and 5): a request recorded before drone B
restarted is refused by the new process; a drone whose wall clock is a minute off still
trades."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

import msgspec
import pytest

from agent.net.security import TeamDir, drone_name, load_signing
from agent.net.security import client_config as secure_config
from agent.net.transport import ZenohTransport
from agent.wire import keys
from agent.wire.codec import Codec
from agent.wire.peer import AgentState, Decision, Publication, Reply, Request, StatusQuery
from agent.wire.signed import TradeSeal
from tests.conftest import reap, repo_env, scenario_path, wait_until
from tests.test_security_mesh import M as SEC
from tests.test_security_mesh import close_agent, signed_agent

REQ: Codec[Request] = Codec(Request)
REP: Codec[Reply] = Codec(Reply)
PUB: Codec[Publication] = Codec(Publication)
HEX = scenario_path("hexagon_5_3")  # drones A, B, C
M = "hexagon_5_3"


def spawn_b(team: TeamDir, endpoint: str, state: Path) -> subprocess.Popen[str]:
    """Drone B as its own process on the secured profile, journaling in ``state``."""
    return subprocess.Popen(
        [sys.executable, "-m", "agent.cli", "agent", "--id", "B", "--scenario", str(HEX),
         "--connect", endpoint, "--tls-dir", str(team.path), "--state-dir", str(state),
         "--rate-scale", "10", "--timeout", "120"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=repo_env())


def answered(tp: ZenohTransport, seal: TradeSeal, data: bytes, nonce: bytes) -> bool:
    """Whether B answers request ``data`` with a reply signed for it (a Decision)."""
    raw = tp.request(keys.trade_key(M, "B"), data, 1.0)
    inner = None if raw is None else seal.open_reply(raw, "B", nonce)
    return isinstance(inner, bytes) and isinstance(REP.decode(inner), Decision)


def ask(tp: ZenohTransport, seal: TradeSeal) -> bytes | None:
    """A fresh signed StatusQuery from A that B answered (its bytes), or None."""
    data, nonce = seal.seal_request(REQ.encode(StatusQuery(sender="A", trade_id="B:1:1")), "B")
    return data if answered(tp, seal, data, nonce) else None


@pytest.mark.serial
def test_a_request_replayed_after_the_receiver_restarts_is_refused(
        team: TeamDir, secured_router: str, tmp_path: Path) -> None:
    """A genuine request B accepted, replayed once B restarted from its journal (and before
    anyone asked the new process anything newer), is not answered."""
    seal = TradeSeal(load_signing(team, "A"), M)
    tp = ZenohTransport(secure_config(team, [secured_router], drone_name("A")), None, "A")
    incarnations: set[int] = set()

    def on_state(key: str, payload: bytes) -> None:
        msg = PUB.decode(payload, key)
        if isinstance(msg, AgentState):
            incarnations.add(msg.incarnation)

    tp.subscribe(keys.state_key(M, "B"), on_state)
    procs = [spawn_b(team, secured_router, tmp_path / "B")]
    try:
        got: list[bytes] = []

        def record() -> bool:
            """Ask B; keep the request if it was answered."""
            r = ask(tp, seal)
            got.extend([r] if r is not None else [])
            return bool(got)

        assert wait_until(record, 30.0, 0.1), "B never answered"
        procs[0].send_signal(signal.SIGKILL)  # B accepted got[0]; it is killed ...
        procs[0].wait(10)
        procs.append(spawn_b(team, secured_router, tmp_path / "B"))  # ... and restarts
        assert wait_until(lambda: 2 in incarnations, 30.0), "B did not come back"
        time.sleep(0.2)
        # The recording, replayed to the new process, is not answered.
        assert not answered(tp, seal, got[0], nonce_of(got[0]))
        assert ask(tp, seal) is not None  # a fresh request still is
    finally:
        tp.close()
        reap(procs)


def nonce_of(envelope: bytes) -> bytes:
    """The signature of a sealed request (what its reply is bound to)."""
    return bytes(msgspec.msgpack.decode(envelope)[-1])


def test_a_drone_a_minute_off_still_trades(team: TeamDir, secured_router: str,
                                           tmp_path: Path) -> None:
    """A's wall clock runs 60 s ahead of B's: its signed requests are still accepted (no
    rejection on either side) and a whole trade goes through."""
    b = signed_agent(team, secured_router, "B", tmp_path)
    a = signed_agent(team, secured_router, "A", tmp_path)
    try:
        a.seal = TradeSeal(load_signing(team, "A"), SEC,
                                  clock_ns=lambda: time.time_ns() + 60 * 10**9)
        assert wait_until(lambda: "B" in a.core.members.live, 5.0)
        a.core.shared.partners.reset()
        a.core.client.maybe_offer(0.0)
        for _ in range(3):  # a first contact may cost a try (learning B's incarnation)
            a.drive(a.core.client.attempt_offer(0.0))
            a.drive(a.core.client.service_pending(0.0))
        assert a.core.machine.ok == 1 and b.core.machine.ok == 1 and not a.core.machine.pending_ids
        assert a.core.rejects.total == 0 and b.core.rejects.total == 0
    finally:
        close_agent(a)
        close_agent(b)
