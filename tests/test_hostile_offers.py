"""Issue 33, pure: every offer is checked the same way, whatever move claims its terms. Three
agent cores of a random ``potential`` scene run to completion over the model network
(:mod:`agent.testing.core_net`); then N0 is stepped by hand with what a drone holding N1's
certificate and signing key could send it:

* a re-split leg taking all of N0's landmarks, from a pose N1 is not at: refused
  (``pose_mismatch``; before issue 33 a re-split skipped the pose check and was prepared);
* a re-split leg, or an ordinary offer, from N1's own pose that hands N0 landmarks N2 owns
  (at N2's versions, or one higher): Busy, nothing prepared (before: prepared, the landmarks
  doubled);
* a pose published under N1's certificate just before the offer: a run that young is not
  trusted (Busy) and once the real N1 speaks again its pose is contested (refused).

Also the parts on their own: the published-ledger check, pose runs, the seal's bounded replay
memory, and the observer's doubled-ownership watch (any versions; the open profile does not
report a forged state as doubled).
"""

from __future__ import annotations

import dataclasses
import math

import msgspec
import numpy as np
import pytest

from agent.core.coverage_moves import Goal
from agent.mission.observer import DoubleWatch, Observer
from agent.net.contract import Declared
from agent.protocol.regroup import leg_terms
from agent.runtime.core.agent_core import AgentCore
from agent.runtime.core.events import Ask, AskHedged, Query, Sample
from agent.runtime.core.shared import AgentConfig, vec3
from agent.runtime.ends.membership import PoseRuns
from agent.runtime.ends.trade_server import ledger_mismatch
from agent.testing.core_net import LOSSLESS, CoreNet, Fate
from agent.wire import keys
from agent.wire.codec import Codec
from agent.wire.peer import (
    Accept,
    AgentState,
    Busy,
    Counters,
    FenceProof,
    Offer,
    Pose,
    Publication,
    Refused,
    Request,
    pack,
    pack_arrays,
    unpack,
)
from agent.wire.peer import Reply as ReplyMsg
from agent.wire.record import RECORD_CODEC, FenceRecord
from tests.agent_helpers import fixed_motion, random_scene

REQ: Codec[Request] = Codec(Request)
REP: Codec[ReplyMsg] = Codec(ReplyMsg)
PUB: Codec[Publication] = Codec(Publication)


def completed_team() -> CoreNet:
    """Three cores of a random scene (strategy ``potential``: re-split legs are accepted from
    stage 2 on), run to completion."""
    sc = dataclasses.replace(random_scene(3, 9, 2), lost_after=0.0, strategy="potential")
    net = CoreNet(sc, AgentConfig(mission="m", seed=2), motion=fixed_motion(2, max_ticks=1))
    end = net.clock.now() + 200.0
    while net.clock.now() < end and not all(c.completion.complete
                                            for c in net.cores.values()):
        for aid in ("N0", "N1", "N2"):
            net.tick(aid, LOSSLESS)
        net.clock.advance(net.sc.params.dt)
    assert all(c.completion.complete for c in net.cores.values())
    # a few more periods: every state and pose heard, every pose run older than a period
    for _ in range(40):
        for aid in ("N0", "N1", "N2"):
            net.tick(aid, LOSSLESS)
        net.clock.advance(net.sc.params.dt)
    return net


def owned(core: AgentCore) -> tuple[np.ndarray, np.ndarray]:
    ids, vers = core.machine.owned_arrays()
    return ids.copy(), vers.copy()


def ask(net: CoreNet, to: str, req: Request) -> ReplyMsg:
    core = net.cores[to]
    got = net.step(to, Query(REQ.encode(req), keys.trade_key("m", to), net.clock.now()),
                   LOSSLESS)
    assert got is not None
    reply = REP.decode(got)
    assert reply is not None
    assert core is net.cores[to]
    return reply


@pytest.fixture(scope="module")
def team() -> CoreNet:
    return completed_team()


def leg(net: CoreNet, p: tuple[float, float, float], v: tuple[float, float, float],
        tid: str, give: tuple[np.ndarray, np.ndarray] | None = None,
        take_all: bool = True) -> Offer:
    """An offer as N1 of a re-split leg with N0: take all of N0's set (``take_all``) and give
    ``give`` (ids, versions; offered as N1's own with N1's published set)."""
    n0 = net.cores["N0"]
    n1 = net.cores["N1"]
    r_ids, r_vers = owned(n0)
    i_ids, i_vers = owned(n1)
    if give is not None:
        i_ids, i_vers = np.concatenate([i_ids, give[0]]), np.concatenate([i_vers, give[1]])
    new_peer = r_ids[:0] if take_all else r_ids
    if give is not None:
        new_peer = np.concatenate([new_peer, give[0]])
    terms = leg_terms(new_peer, Goal(np.zeros(3), np.array([1.0, 0.0, 0.0]), 0.0),
                      i_ids, i_vers, r_ids, r_vers)
    assert terms is not None
    return Offer(sender="N1", trade_id=tid, p=p, v=v, owned=pack_arrays(i_ids, i_vers),
                 regroup=terms)


def test_a_resplit_leg_from_a_made_up_pose_is_refused(team: CoreNet) -> None:
    n0 = team.cores["N0"]
    assert n0.shared.stage >= 2 and n0.shared.phase == "converged"
    before = owned(n0)
    assert before[0].size
    p1, v1, _ = n0.members.poses["N1"]
    far = vec3(np.asarray(p1) + np.array([3.0, 0.0, 0.0]))
    reply = ask(team, "N0", leg(team, far, vec3(v1), "N1:1:9001"))
    assert isinstance(reply, Refused) and reply.reason == "pose_mismatch", reply
    assert np.array_equal(owned(n0)[0], before[0]) and not n0.machine.prepared
    assert n0.rejects.by_reason["pose_mismatch"] >= 1


def test_a_resplit_leg_handing_over_a_peers_landmarks_is_not_taken(team: CoreNet) -> None:
    n0, n2 = team.cores["N0"], team.cores["N2"]
    p1, v1, _ = n0.members.poses["N1"]
    theirs = owned(n2)
    assert theirs[0].size
    for k, vers in enumerate((theirs[1], theirs[1] + 1)):  # N2's versions, or one higher
        reply = ask(team, "N0", leg(team, vec3(p1), vec3(v1), f"N1:1:{9100 + k}",
                                    give=(theirs[0], vers), take_all=False))
        assert isinstance(reply, Busy), reply
        assert not n0.machine.prepared
    assert n0.shared.counters.unconfirmed.get("unpublished", 0) >= 2
    # an ordinary offer (Algorithm 7) with N2's landmarks in N1's set: the same
    i_ids, i_vers = owned(team.cores["N1"])
    offer = Offer(sender="N1", trade_id="N1:1:9200", p=vec3(p1), v=vec3(v1),
                  owned=pack_arrays(np.concatenate([i_ids, theirs[0]]),
                                    np.concatenate([i_vers, theirs[1]])))
    assert isinstance(ask(team, "N0", offer), Busy)
    assert not np.isin(theirs[0], owned(n0)[0]).any()


def test_an_honest_leg_from_the_published_pose_and_ledger_is_judged(team: CoreNet) -> None:
    """The checks let an honest re-split leg through (here: N1 takes one of N0's landmarks
    and the leg is prepared), then the test aborts it by committing nothing."""
    n0 = team.cores["N0"]
    p1, v1, _ = n0.members.poses["N1"]
    r_ids, r_vers = owned(n0)
    i_ids, i_vers = owned(team.cores["N1"])
    terms = leg_terms(r_ids[1:], Goal(np.zeros(3), np.array([1.0, 0.0, 0.0]), 0.0),
                      i_ids, i_vers, r_ids, r_vers)
    assert terms is not None
    offer = Offer(sender="N1", trade_id="N1:1:9300", p=vec3(p1), v=vec3(v1),
                  owned=pack_arrays(i_ids, i_vers), regroup=terms)
    assert isinstance(ask(team, "N0", offer), Accept)


def test_a_pose_published_under_the_certificate_just_before_the_offer() -> None:
    net = completed_team()
    n0 = net.cores["N0"]
    p1, v1, _ = n0.members.poses["N1"]
    run = n0.members.runs.runs["N1"]
    far = vec3(np.asarray(p1) + np.array([3.0, 0.0, 0.0]))
    forged = Pose(sender="N1", seq=run.seq + 1000, t=0.0, p=far, v=vec3(v1))
    net.step("N0", Sample("pose", keys.pose_key("m", "N1"), PUB.encode(forged),
                          net.clock.now()), LOSSLESS)
    r_ids = owned(n0)[0]
    i_ids, i_vers = owned(net.cores["N1"])
    offer = Offer(sender="N1", trade_id="N1:1:9400", p=far, v=vec3(v1),
                  owned=pack_arrays(i_ids, i_vers))
    assert isinstance(ask(net, "N0", offer), Busy)  # a run this young: ask again
    for _ in range(30):  # the real N1 speaks again: two publishers on its pose key
        net.clock.advance(net.sc.params.dt)
        net.tick("N1", LOSSLESS)
        if n0.members.runs.contested("N1", net.clock.now()):
            break
    assert n0.members.runs.contested("N1", net.clock.now())
    offer = msgspec.structs.replace(offer, trade_id="N1:1:9401")
    reply = ask(net, "N0", offer)
    assert isinstance(reply, Refused) and reply.reason == "pose_mismatch", reply
    assert np.array_equal(owned(n0)[0], r_ids) and not n0.machine.prepared


# -- the parts -------------------------------------------------------------------------------
def state(aid: str, lms: dict[int, int], seq: int = 1, inc: int = 1) -> AgentState:
    return AgentState(sender=aid, incarnation=inc, seq=seq, t=0.0, p=(0.0, 0.0, 0.0),
                      v=(1.0, 0.0, 0.0), phase="converged", owned=pack(lms), held=pack({}),
                      vision=0.0, counters=Counters(), partners=[], pending=[],
                      trades_with={})


def test_the_published_ledger_check() -> None:
    states = {"A": (state("A", {1: 0, 2: 3}), 0.0), "B": (state("B", {5: 1}), 0.0)}
    a = np.array([2, 1]), np.array([3, 0])
    assert ledger_mismatch("A", *a, states, set()) is None
    assert ledger_mismatch("A", np.array([2]), np.array([4]), states, set()) == "unpublished"
    assert ledger_mismatch("C", *a, states, set()) == "unpublished"
    states["A"] = (state("A", {1: 0, 2: 3, 5: 2}), 0.0)  # B's 5 in A's forged ledger
    assert ledger_mismatch("A", np.array([5]), np.array([2]), states, set()) == "claimed"
    assert ledger_mismatch("A", np.array([5]), np.array([2]), states, {"B"}) is None


def test_pose_runs_see_a_second_publisher() -> None:
    runs = PoseRuns(0.5, 2.0)
    runs.heard("C", np.zeros(3), 10, 0.0)
    runs.heard("C", np.array([0.1, 0.0, 0.0]), 11, 0.5)
    assert runs.age("C", 1.0) == math.inf and not runs.contested("C", 1.0)  # the first run
    runs.heard("C", np.array([5.0, 0.0, 0.0]), 900, 1.0)  # a thief: a new run, not yet seen
    assert runs.age("C", 1.0) == 0.0 and not runs.contested("C", 1.0)
    runs.heard("C", np.array([0.1, 0.0, 0.0]), 12, 1.1)  # the real drone again
    assert runs.contested("C", 1.1) and not runs.contested("C", 3.2)
    runs.heard("C", np.array([0.2, 0.0, 0.0]), None, 1.2)  # a state: no sequence to compare
    assert runs.contests == 1


def test_the_seal_replay_memory_is_bounded_and_still_refuses_replays() -> None:
    from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey

    from agent.wire.signed import TOKENS_PER_SENDER, SigningKeys, TradeSeal

    ka, kb = Ed25519PrivateKey.generate(), Ed25519PrivateKey.generate()
    team = {"A": ka.public_key(), "B": kb.public_key()}
    clock = iter(range(1, 10**6))
    b = TradeSeal(SigningKeys("B", kb, team), "m", lambda: next(clock))
    first = TradeSeal(SigningKeys("A", ka, team), "m", lambda: next(clock))
    first.know("B", b.boot)
    old, _ = first.seal_request(b"x", "B")
    assert not hasattr(b.open_request(old), "reason")
    for _ in range(100):  # a flood of new processes of A (A's key needed)
        s = TradeSeal(SigningKeys("A", ka, team), "m", lambda: next(clock))
        s.know("B", b.boot)
        got = b.open_request(s.seal_request(b"x", "B")[0])
        assert not hasattr(got, "reason")
    assert b.memory_size() <= TOKENS_PER_SENDER and b.evictions == 101 - TOKENS_PER_SENDER
    replay = b.open_request(old)  # its process was evicted: the floor still refuses it
    assert getattr(replay, "reason", None) == "replay"
    s = TradeSeal(SigningKeys("A", ka, team), "m", lambda: next(clock))
    s.know("B", b.boot)
    fresh = b.open_request(s.seal_request(b"y", "B")[0])
    assert not hasattr(fresh, "reason") and getattr(fresh, "evicted", 0) == 1


def test_doubled_ownership_at_any_versions_lasting_is_a_violation() -> None:
    w = DoubleWatch(5.0)
    claims: dict[str, tuple[dict[int, int], dict[int, int]]] = {
        "A": ({1: 3, 2: 0}, {}), "B": ({1: 4}, {})}
    assert w.update(claims, 0.0) == []
    assert w.update(claims, 4.0) == []
    got = w.update(claims, 5.5)
    assert len(got) == 1 and "A v3, B v4" in got[0] and "doubled" in got[0]
    assert w.update(claims, 9.0) == []  # once


class _NoTransport:
    def subscribe(self, keyexpr: str, callback: object) -> Declared:
        class H:
            def undeclare(self) -> None:
                pass
        return H()


def test_the_open_profile_observer_does_not_report_a_forged_state_as_doubled() -> None:
    t = [0.0]
    ob = Observer(_NoTransport(), "m", ["A", "B"], [1, 2, 3],  # type: ignore[arg-type]
                  now=lambda: t[0])
    ob._on_state(keys.state_key("m", "A"), PUB.encode(state("A", {1: 0, 2: 0})))
    ob._on_state(keys.state_key("m", "B"), PUB.encode(state("B", {3: 0})))
    # one forged state of B, a huge incarnation, claiming A's landmarks at A's versions
    ob._on_state(keys.state_key("m", "B"),
                 PUB.encode(state("B", {1: 0, 2: 0, 3: 0}, seq=1, inc=1_000_000)))
    for k in range(2, 60):  # the genuine streams go on; the forger said nothing more
        t[0] = k * 0.2
        ob._on_state(keys.state_key("m", "A"), PUB.encode(state("A", {1: 0, 2: 0}, seq=k)))
        ob._on_state(keys.state_key("m", "B"), PUB.encode(state("B", {3: 0}, seq=k)))
    rep = ob.snapshot()
    assert rep.violations == [], rep.violations
    assert rep.conflicting  # reported as suspicious
    # a doubling that lasts in the latest states is one, at any versions
    for k in range(60, 100):
        t[0] = k * 0.2
        ob._on_state(keys.state_key("m", "A"), PUB.encode(state("A", {1: 0, 2: 0}, seq=k)))
        ob._on_state(keys.state_key("m", "B"), PUB.encode(state("B", {1: 1, 3: 0}, seq=k)))
    assert any("landmark 1: owned by A v0, B v1" in v for v in ob.snapshot().violations)


def test_unpack_roundtrip_of_the_helpers() -> None:
    got = unpack(pack({4: 2}))
    assert got is not None and got[0].tolist() == [4] and got[1].tolist() == [2]


# -- comebacks -------------------------------------------------------------------------------
class _RecordNet(CoreNet):
    """A model network whose router answers the fence record ``record``."""

    record: FenceRecord | None = None

    def ask(self, ask: Ask | AskHedged, fate: Fate) -> bytes | None:
        if keys.kind_of(ask.key) == "fences" and self.record is not None:
            return RECORD_CODEC.encode(self.record)
        return super().ask(ask, fate)


def _proof_fencing_n2() -> FenceProof:
    """The proof of a team whose N2 vanished at once: N0 and N1 fence it, adopt, complete."""
    sc = dataclasses.replace(random_scene(3, 9, 3), lost_after=1.0)
    net = CoreNet(sc, AgentConfig(mission="m", seed=3), motion=fixed_motion(3, max_ticks=1))
    net.go_away("N2")
    end = net.clock.now() + 120.0
    while net.clock.now() < end and not all(c.completion.complete
                                            for c in net.cores.values()):
        for aid in ("N0", "N1"):
            net.tick(aid, LOSSLESS)
        net.clock.advance(net.sc.params.dt)
    proofs = [p for p in net.cores["N0"].shared.machine.fence_proofs if "N2" in p.fenced]
    assert proofs, "N2 was not fenced"
    return proofs[-1]


@pytest.mark.parametrize("team_live", [False, True])
def test_a_comeback_on_a_new_journal_after_its_team_finished_is_told_it_was_fenced(
        team_live: bool) -> None:
    """N2 killed before its journal's first write, started again on a new journal after its
    team fenced it, adopted its landmarks and finished: its first life hears the router's
    record, which proves the fence, with no team member live; within ``final_word_s`` it
    takes the proof and leaves holding nothing (before issue 33 a first life ignored the
    record's proofs and kept the adopted landmarks). With a member live (a new run's team, or
    the old one whose states carry the proof) it waits for nothing and goes on."""
    proof = _proof_fencing_n2()
    sc = dataclasses.replace(random_scene(3, 9, 3), lost_after=1.0)
    cfg = AgentConfig(mission="m", seed=3, final_word_s=3.0)
    net = _RecordNet(sc, cfg, motion=fixed_motion(3, max_ticks=1))
    net.record = FenceRecord(mission="m", proofs=[proof], complete=["N0", "N1"],
                             alive_for={"N2": 0.5, **({"N0": 9.0} if team_live else {})},
                             silent_for={} if team_live else {"N0": 20.0, "N1": 20.0})
    net.go_away("N0")
    net.go_away("N1")
    n2 = net.cores["N2"]
    assert n2.shared.machine.incarnation == 1 and owned(n2)[0].size  # the scenario's set
    end = net.clock.now() + 6.0
    while net.clock.now() < end and "N2" in net.cores:
        net.tick("N2", LOSSLESS)
        net.clock.advance(net.sc.params.dt)
    fenced_out = n2.shared.machine.fenced_out is not None
    assert fenced_out != team_live
    if not team_live:
        assert owned(n2)[0].size == 0 and "N2" in net.left


def test_reject_counters_stay_bounded_under_keys_of_the_senders_choosing() -> None:
    from agent.net.rejects import MAX_KEYS, OTHER_KEYS, LockedRejectCounter

    c = LockedRejectCounter()
    for k in range(MAX_KEYS + 500):
        c.add("impossible", f"viscover/m/state/X{k}")
    assert len(c.by_key) == MAX_KEYS + 1 and c.by_key[OTHER_KEYS] == 500 and c.folded == 500
    assert c.total == MAX_KEYS + 500
