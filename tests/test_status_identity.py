"""The observer's one-process-per-id rule (:class:`agent.mission.observer.IdentityWatch`) and
``viscover status``'s view of a mission (:class:`agent.mission.watch.MissionWatch`), in
memory."""

from __future__ import annotations

import io
import random

import pytest

from agent.config.parse import load_scenario
from agent.mission.observer import IdentityWatch, Observer
from agent.mission.status import render_plain, render_rich
from agent.mission.watch import MissionWatch, state_events
from agent.net.memory import MemoryNetwork
from agent.storage.events import Event, Fault, Trade
from agent.wire import keys
from agent.wire.codec import Codec
from agent.wire.commands import COMMAND_CODEC, MissionCommand
from agent.wire.ground import STATUS_CODEC, MocapStatus
from agent.wire.peer import AgentState, Counters, Phase, Publication, pack
from tests.conftest import scenario_path

PUB: Codec[Publication] = Codec(Publication)


def state(sender: str, seq: int, t: float, owned: dict[int, int], *, inc: int = 1,
          phase: Phase = "optimising", ok: int = 0, trades_with: dict[str, int] | None = None,
          complete: bool = False, timeouts: int = 0, stage: int = 1,
          reverting: bool = False) -> AgentState:
    """An agent state as published (pose at the origin, looking along +x)."""
    return AgentState(sender=sender, incarnation=inc, seq=seq, t=t, p=(0.0, 0.0, 0.0),
                      v=(1.0, 0.0, 0.0), phase=phase,
                      owned=pack(owned), held=pack({}), vision=0.5,
                      counters=Counters(ok=ok, timeouts=timeouts), partners=[], pending=[],
                      trades_with=trades_with or {}, complete=complete, stage=stage,
                      reverting=reverting)


def test_two_processes_of_one_incarnation_are_told_apart() -> None:
    """Same incarnation, one far ahead in sequence numbers: reported once, after 2 s."""
    w = IdentityWatch()
    found = []
    for k in range(40):
        now = 0.1 * k
        found += w.add("A", 1, 1000 + k, 100.0 + 0.2 * k, now)
        found += w.add("A", 1, 1 + k, 5.0 + 0.2 * k, now + 0.05)
    assert len(found) == 1 and "agent A: two processes claim this id" in found[0]


def test_two_processes_started_together_are_told_apart() -> None:
    """Sequence numbers in lockstep: the mission times differ, so the streams do."""
    w = IdentityWatch()
    found = [v for k in range(40) for v in (w.add("A", 1, k, 10.0 + 0.2 * k, 0.1 * k),
                                            w.add("A", 1, k, 3.0 + 0.2 * k, 0.1 * k))]
    assert sum(len(v) for v in found) == 1


def test_different_incarnations_overlapping_are_reported() -> None:
    w = IdentityWatch()
    found = [v for k in range(40) for v in (w.add("B", 1, k, 0.2 * k, 0.1 * k),
                                            w.add("B", 2, k, 0.2 * k, 0.1 * k + 0.01))]
    assert sum(len(v) for v in found) == 1


def test_a_restart_a_straggler_duplicates_and_reordering_are_not_reported() -> None:
    """One process whose states arrive duplicated and up to 3 places out of order, then a
    restart (new incarnation) with a late state of the old one: no violation."""
    rng = random.Random(1)
    w = IdentityWatch()
    seqs = list(range(1, 200))
    for i in range(0, len(seqs) - 3, 3):
        chunk = seqs[i:i + 3]
        rng.shuffle(chunk)
        seqs[i:i + 3] = chunk
    found = []
    for k, s in enumerate(seqs):
        found += w.add("C", 1, s, 0.5 * s, 0.1 * k)
        if k % 7 == 0:
            found += w.add("C", 1, s, 0.5 * s, 0.1 * k + 0.01)
    now = 0.1 * len(seqs)
    for k in range(40):
        found += w.add("C", 2, 1 + k, 0.2 * k, now + 0.1 * k)
        if k == 2:
            found += w.add("C", 1, 199, 99.5, now + 0.25)
    assert found == []


def test_the_observer_reports_two_processes_claiming_one_id() -> None:
    """Two publishers of A's states on one mission: a violation in the observer's report."""
    sc = load_scenario(str(scenario_path("hexagon_5_3")))
    net = MemoryNetwork()
    clock = [0.0]
    obs = Observer(net.transport("obs"), "m", ["A", "B", "C"], list(sc.landmark_ids),
                   now=lambda: clock[0])
    one, two = net.transport("A1"), net.transport("A2")
    for k in range(30):
        clock[0] = 0.2 * k
        one.publish(keys.state_key("m", "A"), PUB.encode(state("A", 500 + k, 50 + k, {3: 0})))
        two.publish(keys.state_key("m", "A"), PUB.encode(state("A", 1 + k, 2 + k, {6: 0})))
    rep = obs.snapshot()
    assert [v for v in rep.violations if "two processes claim" in v] == [
        "agent A: two processes claim this id (incarnations 1 and 1 both publishing for "
        "2.2 s)"]


def test_state_events_phase_trade_fault_and_completion() -> None:
    a0 = state("A", 1, 0.0, {3: 0, 6: 0})
    a1 = state("A", 2, 1.0, {3: 0, 2: 1}, phase="converged", ok=1, trades_with={"B": 1},
               timeouts=2, complete=True)
    evs = state_events(a0, {3, 6}, a1, {3, 2})
    kinds = [e.kind for e in evs]
    assert kinds == ["phase", "trade", "fault", "complete"]
    trade, fault = evs[1], evs[2]
    assert isinstance(trade, Trade) and isinstance(fault, Fault)
    assert (trade.partner, trade.gained, trade.given) == ("B", [2], [6])
    assert fault.level == "warning" and fault.what == "timeouts"
    assert state_events(a1, {3, 2}, state("A", 3, 2.0, {3: 0, 2: 1}, inc=2),
                        {3, 2})[0].kind == "restart"


@pytest.fixture
def watched() -> tuple[MissionWatch, MemoryNetwork, list[Event]]:
    """A mission watch of hexagon_5_3 on an in-memory network, collecting its events."""
    sc = load_scenario(str(scenario_path("hexagon_5_3")))
    net = MemoryNetwork()
    watch = MissionWatch(net.transport("status"), "m", sc)
    events: list[Event] = []
    watch.listeners.append(events.append)
    return watch, net, events


def test_the_status_view_of_a_mission(
        watched: tuple[MissionWatch, MemoryNetwork, list[Event]]) -> None:
    watch, net, events = watched
    tp = net.transport("agents")
    tok = tp.declare_liveliness(keys.alive_key("m", "A"))
    for aid, owned in (("A", {3: 0, 6: 0}), ("B", {2: 0, 4: 0}), ("C", {1: 0, 5: 0})):
        tp.publish(keys.state_key("m", aid), PUB.encode(state(aid, 1, 0.0, owned)))
    tp.publish(keys.state_key("m", "A"), PUB.encode(
        state("A", 2, 1.0, {3: 0, 6: 0}, phase="converged", timeouts=1)))
    tp.publish(keys.state_key("m", "B"), PUB.encode(
        state("B", 2, 1.0, {2: 0, 4: 0}, phase="converged", stage=3, reverting=True)))
    tp.publish(keys.mocap_status_key("m", "B"), STATUS_CODEC.encode(
        MocapStatus(drone="B", state="stale", age=0.6, t=1.0)))
    cmd = COMMAND_CODEC.encode(MissionCommand(sender="op", seq=7, command="land"))
    tp.publish(keys.command_key("m"), cmd)
    tp.publish(keys.command_key("m"), cmd)  # repeated until acknowledged: one event
    tp.publish(keys.state_key("m", "C"), b"\x00garbage")
    tok.undeclare()
    view = watch.view()
    rows = {r.id: r for r in view.rows}
    assert (rows["A"].phase, rows["A"].owned, rows["A"].trades) == ("converged", 2, "0 / 0")
    assert (rows["A"].fault, rows["A"].link[:4]) == ("left the mission", "left")
    assert [e.text for e in events if e.kind == "fault"] == ["A: 1 more timeouts (1 in all)"]
    assert (rows["B"].mocap, rows["B"].fault) == ("stale", "mocap stale")
    assert rows["B"].phase == "converged, stage 3, reverting"  # strategy "potential"
    assert view.seen + view.not_seen == 6 and view.unowned == 0 and view.rejected == 1
    kinds = [e.kind for e in events]
    assert kinds.count("command") == 1 and {"join", "leave", "mocap", "fault"} <= set(kinds)
    text = render_plain(view)
    assert text.splitlines()[0].split()[:3] == ["drone", "phase", "landmarks"]
    assert "landmarks seen by their owner" in text and "rejected payloads 1" in text
    from rich.console import Console

    out = io.StringIO()
    Console(file=out, width=160, color_system=None).print(render_rich(view))
    assert "converged" in out.getvalue() and "viscover mission m" in out.getvalue()
    watch.close()


def test_the_watch_emits_a_violation_for_two_processes_of_one_id(
        watched: tuple[MissionWatch, MemoryNetwork, list[Event]]) -> None:
    """The older process's states are not the newest, yet its violation is an event."""
    watch, net, events = watched
    one, two = net.transport("A1"), net.transport("A2")
    clock = [0.0]
    watch.observer._now = lambda: clock[0]
    for k in range(40):
        clock[0] = 0.1 * k
        one.publish(keys.state_key("m", "A"), PUB.encode(state("A", 900 + k, 90 + k, {3: 0})))
        two.publish(keys.state_key("m", "A"), PUB.encode(state("A", 1 + k, 1 + k, {6: 0})))
    (v,) = [e for e in events if e.kind == "violation"]
    assert v.source == "A" and "two processes claim this id" in v.text
    assert watch.view().rows[0].fault.startswith("two processes claim this id")
