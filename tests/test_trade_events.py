"""The ``trade`` events of the mission watch (:mod:`agent.mission.trade_events`) over whole
in-memory missions with lost, duplicated, delayed and retried messages, and a responder
killed while in doubt: both sides of every trade report it once, and agree (the initiator's
``gained`` is the responder's ``given`` and vice versa), and their terms are the journals'
committed records.

Before the events came from the journaled terms, a responder whose state was published
between its *prepared* and *committed* records (the Commit lost or retried) reported
``gave []`` at the commit: its outgoing landmarks had already left its owned set."""

from __future__ import annotations

import dataclasses
from collections import defaultdict
from pathlib import Path
from typing import Any

import msgspec
import pytest

from agent.config.scenario import Scenario
from agent.mission.trade_events import trade_events
from agent.mission.watch import MissionWatch
from agent.net.faults import FaultConfig
from agent.protocol.records import CommitRec, CommittedRec, PreparedRec
from agent.runtime.shell.runtime import AgentConfig
from agent.storage.events import Trade, TradeGap
from agent.storage.journal import Journal
from agent.testing.memsim import MemoryMission
from agent.wire.peer import AgentState, Counters, TradeTerms, pack, unpack_trusted
from bench.quality.structures import make_scene
from tests.agent_helpers import thesis

#: the events of the trades a watch heard
Event = Trade | TradeGap
#: (agent, trade id) -> (role, partner, gained ids, given ids)
Terms = dict[tuple[str, str], tuple[str, str, list[int], list[int]]]

FAULTS = {
    "loss": FaultConfig(drop_default=0.3),
    "dup": FaultConfig(duplicate=0.3),
    "everything": FaultConfig(drop_default=0.3, duplicate=0.2, jitter_s=0.25),
}
SEEDS = range(6)


def ids(s: Any) -> list[int]:
    """The landmark ids of a packed set, ascending."""
    return sorted(unpack_trusted(s)[0].tolist())


def journal_terms(root: Path, agents: list[str]) -> Terms:
    """Every committed trade side in the agents' journals: the initiator's CommitRec, the
    responder's PreparedRec of a trade it journaled as committed."""
    out: Terms = {}
    for a in agents:
        j = Journal(root / a)
        try:
            prepared: dict[str, PreparedRec] = {}
            for rec in j.replay():
                if isinstance(rec, CommitRec):
                    out[(a, rec.trade_id)] = ("initiator", rec.partner, ids(rec.r_to_i),
                                              ids(rec.i_to_r))
                elif isinstance(rec, PreparedRec):
                    prepared[rec.trade_id] = rec
                elif isinstance(rec, CommittedRec) and rec.trade_id in prepared:
                    p = prepared[rec.trade_id]
                    out.setdefault((a, rec.trade_id), ("responder", p.partner, ids(p.i_to_r),
                                                       ids(p.r_to_i)))
        finally:
            j.close()
    return out


def run_watched(tmp_path: Path, sc: Scenario, faults: FaultConfig | None, seed: int,
                kill_in_doubt: bool = False) -> tuple[list[Event], Terms]:
    """A whole mission watched by a :class:`MissionWatch` on the same network (its own link
    without faults): the watch's trade events, and the journals' committed trade sides. With
    ``kill_in_doubt`` the first responder seen in doubt is killed and restarted 0.5 s later
    from its journal."""
    root = tmp_path / f"{sc.name}-{seed}"
    m = MemoryMission(sc, root, faults, seed=seed, autostart=False,
                      config=AgentConfig(mission="mem", seed=seed))
    watch = MissionWatch(m.net.transport("watch"), "mem", sc)
    events: list[Event] = []
    watch.listeners.append(lambda ev: events.append(ev) if isinstance(ev, (Trade, TradeGap))
                             else None)
    try:
        for a in sc.agents:
            m.start(a.id)
        killed: tuple[str, float] | None = None
        while m.net.now < 300.0 and not m.complete:
            m.step()
            if kill_in_doubt and killed is None:
                victim = next((a for a, rt in m.agents.items() if rt.core.machine.prepared), None)
                if victim is not None:
                    m.crash(victim)
                    killed = (victim, m.net.now)
            if killed is not None and killed[0] not in m.agents \
                    and m.net.now > killed[1] + 0.5:
                m.start(killed[0])
        assert m.complete, f"not complete after {m.net.now:.0f} s"
        assert not kill_in_doubt or killed is not None, "nobody was ever in doubt"
        m.run(m.net.now + 2.0, until=lambda _m: False)  # the last states reach the watch
    finally:
        m.close()
        watch.close()
    return events, journal_terms(root, [a.id for a in sc.agents])


def check_sides_agree(events: list[Event]) -> None:
    """Both sides of each trade report it once, and agree. The n-th trade between two agents
    is the same trade for both (the trades of a pair are sequential): this needs no trade
    id, so it holds for the events of any build."""
    trades = [e for e in events if isinstance(e, Trade)]
    assert len(trades) == len(events)  # no gap: every trade reported
    pairs: dict[tuple[frozenset[str], int], dict[str, Trade]] = defaultdict(dict)
    for e in trades:
        side = pairs[(frozenset((e.source, e.partner)), e.count)]
        assert e.source not in side, f"trade reported twice: {e.text}"
        side[e.source] = e
    for (pair, n), side in sorted(pairs.items(), key=lambda kv: (sorted(kv[0][0]), kv[0][1])):
        assert len(side) == 2, f"trade {n} of {sorted(pair)}: only {sorted(side)} reported it"
        a, b = side.values()
        assert (a.gained, a.given) == (b.given, b.gained), \
            f"the two sides disagree: {a.text!r} / {b.text!r}"


def check_journaled_terms(events: list[Event], truth: Terms) -> None:
    """Every event names its trade and role, and reports the journal's committed record of
    its side; every committed side is reported, and has a committed other side."""
    got = {(e.source, e.trade): (e.role, e.partner, e.gained, e.given)
           for e in events if isinstance(e, Trade)}
    assert len(got) == len(events)
    assert got == truth
    for (agent, tid), (role, partner, _g, _v) in truth.items():
        assert (role == "initiator") == tid.startswith(f"{agent}:")
        assert (partner, tid) in truth, f"{tid}: {partner} has no committed record"


def check_runs(runs: list[tuple[list[Event], Terms]]) -> None:
    """The property over several missions: first the sides' agreement in every mission,
    then the journals' terms."""
    for events, _truth in runs:
        check_sides_agree(events)
    for events, truth in runs:
        check_journaled_terms(events, truth)


@pytest.mark.parametrize("fault", [
    "dup", "everything",
    pytest.param("loss", marks=pytest.mark.long)])  # make test: [everything], its loss and more
@pytest.mark.parametrize("name", ["hexagon_5_3", "cube_6_2"])
def test_both_sides_of_every_trade_report_the_journaled_terms(
        tmp_path: Path, name: str, fault: str) -> None:
    sc = thesis(name)
    runs = [run_watched(tmp_path, sc, FAULTS[fault], seed) for seed in SEEDS]
    check_runs(runs)
    assert sum(len(truth) for _e, truth in runs) >= 2 * len(SEEDS)


@pytest.mark.parametrize("fault", [
    pytest.param("loss", marks=pytest.mark.long),  # make test: [everything], its loss and more
    "everything"])
def test_re_split_trades_of_the_coverage_moves_too(tmp_path: Path, fault: str) -> None:
    """``strategy = "potential"`` (the L-shaped building, 3 drones): the pair re-splits are
    trades too, with terms named by the initiator's proposal."""
    sc = dataclasses.replace(make_scene("lshape", "tuning", 1, 3, 1).scenario(),
                             strategy="potential", lost_after=0.0)
    runs = [run_watched(tmp_path, sc, FAULTS[fault], seed) for seed in (1, 2)]
    check_runs(runs)
    assert all(len(truth) >= 8 for _e, truth in runs)


def test_a_responder_killed_in_doubt_reports_its_trade_once_after_its_restart(
        tmp_path: Path) -> None:
    """The responder's trade commits in its next incarnation (rebuilt from its journal):
    it is reported once, with the terms the initiator reported."""
    sc = thesis("cube_6_2")
    check_runs([run_watched(tmp_path, sc, FAULTS["loss"], seed, kill_in_doubt=True)
                for seed in range(3)])


def terms(n: int, tid: str, partner: str, gained: dict[int, int],
          given: dict[int, int]) -> TradeTerms:
    """The terms of one committed trade as a state carries them."""
    return TradeTerms(n=n, trade_id=tid, partner=partner, role="responder", count=n,
                      gained=pack(gained), given=pack(given))


def state(seq: int, owned: dict[int, int], ok: int, trades_with: dict[str, int],
          trades: list[TradeTerms] | None = None) -> AgentState:
    """A state of agent B."""
    return AgentState(sender="B", incarnation=1, seq=seq, t=0.2 * seq, p=(0.0, 0.0, 0.0),
                      v=(1.0, 0.0, 0.0), phase="converged", owned=pack(owned), held=pack({}),
                      vision=0.5, counters=Counters(ok=ok), partners=[], pending=[],
                      trades_with=trades_with, trades=trades or [])


def test_events_come_from_the_terms_not_the_owned_sets_and_gaps_are_reported() -> None:
    """B prepared (gave 4 away, held) before its state 1; at state 2 the trade committed: the
    event says it gave 4. Two trades between states are two events; trades beyond what a
    state reports are one gap event; a state of a build without terms falls back on the
    owned sets."""
    prev = state(1, {1: 0}, 0, {})
    t1 = terms(1, "A:1:1", "A", {2: 0}, {4: 0})
    t2 = terms(2, "C:1:1", "C", {}, {1: 0})
    (ev,) = trade_events(prev, {1}, state(2, {1: 0, 2: 1}, 1, {"A": 1}, [t1]), {1, 2})
    assert isinstance(ev, Trade)
    assert (ev.trade, ev.partner, ev.gained, ev.given) == ("A:1:1", "A", [2], [4])
    evs = trade_events(prev, {1}, state(2, {2: 1}, 2, {"A": 1, "C": 1}, [t1, t2]), {2})
    assert [(e.trade, e.gained, e.given) for e in evs if isinstance(e, Trade)] == [
        ("A:1:1", [2], [4]), ("C:1:1", [], [1])] and len(evs) == 2
    evs = trade_events(prev, {1}, state(2, {2: 1}, 3, {"A": 1, "C": 2}, [t1, t2]), {2})
    assert [e.kind for e in evs] == ["trade", "trade", "trade_gap"]
    assert isinstance(evs[2], TradeGap) and evs[2].count == 1
    evs = trade_events(state(2, {1: 0}, 1, {"A": 1}, [t1]), {1},
                       state(3, {2: 1}, 2, {"A": 1, "C": 1}, [t1, t2]), {2})
    assert [e.trade for e in evs if isinstance(e, Trade)] == ["C:1:1"] and len(evs) == 1
    (old,) = trade_events(prev, {1}, state(2, {1: 0, 2: 1}, 1, {"A": 1}), {1, 2})
    assert isinstance(old, Trade) and (old.partner, old.gained, old.given) == ("A", [2], [])
    assert old.trade is None and "trade" not in msgspec.to_builtins(old)  # not written


def test_states_with_terms_and_without_decode_on_either_build() -> None:
    """The terms are a new field with a default: a state without them decodes (no terms),
    and a state with them decodes with a decoder that does not know them."""
    st = state(2, {2: 1}, 1, {"A": 1}, [terms(1, "A:1:1", "A", {2: 0}, {4: 0})])
    raw = msgspec.msgpack.encode(st)
    assert msgspec.msgpack.decode(raw, type=AgentState) == st
    old = msgspec.msgpack.decode(raw, type=dict)
    del old["trades"]
    assert msgspec.msgpack.decode(msgspec.msgpack.encode(old), type=AgentState).trades == []

    class OldState(msgspec.Struct, tag_field="kind", tag="state", kw_only=True):
        sender: str
        trades_with: dict[str, int]

    assert msgspec.msgpack.decode(raw, type=OldState).trades_with == {"A": 1}
