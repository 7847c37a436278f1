"""The observer's check that no landmark is lost between ledgers
(:class:`agent.mission.observer.LandmarkWatch`): in flight is fine, gone for good is a
violation, held by a fenced agent is orphaned (not a violation) until adopted."""

from __future__ import annotations

import io

import msgspec
import pytest

from agent.mission.invariants import LandmarkWatch, VersionHistory
from agent.mission.observer import Observer, print_report
from agent.net.memory import MemoryNetwork
from agent.protocol.fence_proof import make_proof
from agent.wire import keys
from agent.wire.peer import AgentState
from tests.test_status_identity import PUB, state

#: A and B (two of three) voted in A's round 1 to fence C out (open profile: unsigned).
PROOF = make_proof(1, "A", ["C"], {"A": b"", "B": b""})


def claims(*agents: dict[int, int]) -> list[tuple[dict[int, int], dict[int, int]]]:
    return [(owned, {}) for owned in agents]


def test_a_landmark_in_flight_is_not_lost() -> None:
    h, w = VersionHistory(), LandmarkWatch([1, 2, 3], lost_s=5.0)
    h.add("A", {1: 0, 2: 0}, {})
    h.add("B", {3: 0}, {})
    assert w.update(claims({1: 0, 2: 0}, {3: 0}), 0.0, h) == []
    # A gave 2 to B; A's state arrives first, B's (with 2 at version 1) 4 s later.
    assert w.update(claims({1: 0}, {3: 0}), 1.0, h) == []
    assert w.update(claims({1: 0}, {3: 0}), 4.9, h) == []
    h.add("B", {3: 0, 2: 1}, {})
    assert w.update(claims({1: 0}, {2: 1, 3: 0}), 5.0, h) == []
    assert w.since == {}


def test_a_landmark_that_arrives_nowhere_is_reported_once() -> None:
    h, w = VersionHistory(), LandmarkWatch([1, 2], lost_s=5.0)
    h.add("A", {1: 0, 2: 3}, {})
    w.update(claims({1: 0, 2: 3}), 0.0, h)
    assert w.update(claims({1: 0}), 1.0, h) == []
    found = w.update(claims({1: 0}), 6.5, h)
    assert found == ["landmark 2: in no agent's ledger for 5.5 s (last claimed at version 3 "
                     "by A): lost"]
    assert w.update(claims({1: 0}), 9.0, h) == []


def test_landmarks_of_a_fenced_agent_are_orphaned_until_adopted() -> None:
    h, w = VersionHistory(), LandmarkWatch([1, 2, 3], lost_s=5.0)
    h.add("A", {1: 0}, {})
    h.add("F", {2: 0, 3: 4}, {})
    w.update(claims({1: 0}, {2: 0, 3: 4}), 0.0, h)
    w.fenced_touched |= h.forget("F")
    assert w.update(claims({1: 0}), 1.0, h) == []
    assert w.update(claims({1: 0}), 30.0, h) == []
    assert w.orphaned(30.0) == {2: 29.0, 3: 29.0}
    h.add("A", {1: 0, 2: 1, 3: 1}, {})  # adopted (F's versions are void)
    assert w.update(claims({1: 0, 2: 1, 3: 1}), 31.0, h) == []
    assert w.orphaned(31.0) == {}


@pytest.mark.parametrize("c_tells_first", [False, True])
def test_the_observer_says_who_adopted_what_whoever_tells_it_of_the_fence(
        c_tells_first: bool) -> None:
    """C owned 1 and 2 and was fenced out; A and B adopted them at higher versions. The
    observer learns the fence from a survivor's state, or first from C itself (back, it
    learned the fence and dropped its ledger: ``fenced_out``); either way C's claims are void
    and ``adopted`` names the adopters."""
    net = MemoryNetwork()
    obs = Observer(net.transport("obs"), "m", ["A", "B", "C"], [1, 2, 3])
    tp = net.transport("agents")

    def send(st: AgentState, **kw: object) -> None:
        tp.publish(keys.state_key("m", st.sender),
                   PUB.encode(msgspec.structs.replace(st, **kw)))

    send(state("A", 1, 0.0, {3: 0}))
    send(state("B", 1, 0.0, {}))
    send(state("C", 1, 0.0, {1: 0, 2: 0}))
    if c_tells_first:
        send(state("C", 1, 0.0, {}, inc=2), fenced_out=True, fence_epoch=1,
             fence_proofs=[PROOF])
    send(state("A", 2, 1.0, {3: 0, 1: 1}), fenced=["C"], fence_epoch=1, fence_proofs=[PROOF])
    send(state("B", 2, 1.0, {2: 1}), fenced=["C"], fence_epoch=1, fence_proofs=[PROOF])
    rep = obs.snapshot()
    assert list(rep.fenced) == ["C"] and rep.fenced["C"]["epoch"] == 1
    assert rep.adopted == {"1": "A", "2": "B"} and rep.orphaned == {}
    assert rep.violations == []
    out = io.StringIO()
    print_report(rep, out)
    assert "landmarks adopted 2 (A 1, B 1), orphaned 0" in out.getvalue()
    obs.close()


def test_an_agent_fenced_before_it_was_ever_heard_is_adopted_from_its_initial_set() -> None:
    """C died before its first state: the observer takes its scenario set (version 0) for
    the ledger the team adopted."""
    net = MemoryNetwork()
    obs = Observer(net.transport("obs"), "m", ["A", "B", "C"], [1, 2, 3],
                   initial={"A": [3], "B": [], "C": [1, 2]})
    tp = net.transport("agents")
    tp.publish(keys.state_key("m", "A"), PUB.encode(msgspec.structs.replace(
        state("A", 2, 1.0, {3: 0, 1: 1, 2: 1}), fenced=["C"], fence_epoch=1,
        fence_proofs=[PROOF])))
    rep = obs.snapshot()
    assert rep.adopted == {"1": "A", "2": "A"} and rep.violations == []
    obs.close()
