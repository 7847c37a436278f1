"""A drone that comes back after its team finished and left (issue 21, item 3): it hears the
team's final word from the router (the fence record it keeps, agent.net.keeper), learns that
it was fenced out and leaves holding nothing, instead of reporting the mission complete with
landmarks the team adopted. Without the record it does not report complete (bounded wait,
one line saying what it waits for). Real processes on a real router; the observer checks
every state."""

from __future__ import annotations

import dataclasses
import json
import signal
import subprocess
import time
from pathlib import Path

import pytest

from agent.config.parse import load_scenario
from agent.net.keeper import FenceKeeper
from agent.net.router import client_config
from agent.net.transport import ZenohTransport
from agent.runtime.shell.runtime import AgentConfig
from agent.testing.memsim import MemoryMission
from agent.wire import keys
from agent.wire.peer import FenceProof
from agent.wire.record import RECORD_CODEC
from tests.agent_helpers import fixed_motion, random_scene, random_scene_toml
from tests.conftest import reap, wait_until
from tests.test_adoption_processes import spawn
from tests.test_agent_processes import InTestObserver, RouterBox, router_box

__all__ = ["router_box"]

LOST_AFTER = 20.0  #: [mission s] = 2 s at rate scale 10


@pytest.mark.serial
def test_a_drone_back_after_its_team_left_learns_its_fence_from_the_router(
        router_box: RouterBox, tmp_path: Path) -> None:
    scene = tmp_path / "scene.toml"
    scene.write_text(f"lost_after = {LOST_AFTER}\n" + random_scene_toml(4, 16, 3, dims=2))
    sc = load_scenario(scene)
    ep = router_box["endpoint"]
    ob = InTestObserver(ep, sc, sc.name)
    procs: list[subprocess.Popen[str]] = []
    try:
        survivors = [spawn(a.id, scene, ep, tmp_path, "--exit-on-complete")
                     for a in sc.agents[:3]]
        victim = spawn("N3", scene, ep, tmp_path)
        procs = [*survivors, victim]
        deadline = time.monotonic() + 60.0
        while time.monotonic() < deadline:  # every agent publishing: mid-mission
            if len(ob.obs.latest) == 4 and not ob.obs.done.is_set():
                break
            time.sleep(0.01)
        victim.send_signal(signal.SIGKILL)
        victim.wait()
        for p in survivors:  # the team fences N3, adopts its landmarks, completes and leaves
            _out, err = p.communicate(timeout=90)
            assert p.returncode == 0, err[-2000:]
        rep = ob.obs.snapshot()
        assert rep.complete and rep.violations == [] and set(rep.fenced) == {"N3"}
        assert sorted(rep.owners) == sorted(sc.landmark_ids)
        assert set(rep.owners.values()) <= {"N0", "N1", "N2"}
        # Nobody is left but the router: N3 comes back from its journal.
        back = spawn("N3", scene, ep, tmp_path, "--exit-on-complete", "--timeout", "40")
        procs.append(back)
        out, err = back.communicate(timeout=60)
        assert back.returncode == 0, err[-2000:]
        assert "the team declared it lost" in err and "told by fence-record" in err, err[-2000:]
        assert '"complete": true' not in out, out
        time.sleep(0.3)
        rep = ob.obs.snapshot()
        assert rep.violations == []
        assert set(rep.owners.values()) <= {"N0", "N1", "N2"}
    finally:
        for p in procs:
            if p.poll() is None:
                p.send_signal(signal.SIGTERM)
        reap(procs)
        ob.close()


def test_the_router_keeps_the_fence_record_of_a_mission(router_box: RouterBox) -> None:
    """The record a router answers: empty for a mission it never heard, the incarnation of
    an agent once two of its states were heard (one forged message is not enough)."""
    tp = ZenohTransport(client_config(router_box["endpoint"]), None, "t")
    try:
        key = keys.fences_key("rec")
        raw = None
        deadline = time.monotonic() + 5.0
        while raw is None and time.monotonic() < deadline:
            raw = tp.request(key, b"", 0.5)
        assert raw is not None
        rec = RECORD_CODEC.decode(raw)
        assert rec is not None and (rec.mission, rec.proofs, rec.seen) == ("rec", [], {})
    finally:
        tp.close()


def test_completion_waits_for_the_final_word_and_gives_up_in_time(tmp_path: Path) -> None:
    """In memory no router keeps a record: with the final word required, the agents never
    report complete, and each gives up after its bound with one line saying why."""
    sc = random_scene(3, 9, 4)
    cfg = dataclasses.replace(AgentConfig(mission="mem"), final_word_s=20.0)
    m = MemoryMission(sc, tmp_path, motion=fixed_motion(4), config=cfg)
    try:
        assert not m.run(60.0)
        for rt in m.agents.values():
            fw = rt.core.adoption.final_word
            assert not rt.complete and fw.asks > 0 and fw.gave_up is not None
            assert "no fence record from the router" in fw.gave_up
            assert "the team's final word" in rt.completion_blocker(m.net.now)
    finally:
        m.close()
    m = MemoryMission(sc, tmp_path / "off", motion=fixed_motion(4))  # not required: completes
    try:
        assert m.run(60.0)
    finally:
        m.close()


class _Session:
    """What :class:`FenceKeeper` declares on a router's session, doing nothing."""

    def declare_subscriber(self, *_a: object, **_k: object) -> object:
        return self

    declare_queryable = declare_subscriber

    def liveliness(self) -> object:
        return self

    def undeclare(self) -> None:
        pass


def _state(aid: str, inc: int, seq: int, complete: bool = False,
           proofs: list[FenceProof] | None = None) -> bytes:
    from agent.wire.codec import Codec
    from agent.wire.peer import AgentState, Counters, Publication, pack
    pub: Codec[Publication] = Codec(Publication)
    return pub.encode(AgentState(
        sender=aid, incarnation=inc, seq=seq, t=0.0, p=(0.0, 0.0, 0.0), v=(1.0, 0.0, 0.0),
        phase="optimising", owned=pack({}), held=pack({}), vision=0.0, counters=Counters(),
        partners=[], pending=[], trades_with={}, complete=complete,
        fence_proofs=proofs or []))


def test_a_router_record_from_one_state_lists_nobody() -> None:
    """A keeper hears one forged state of N9 (huge incarnation): N9 is not *seen*; two
    states of one stream are."""
    k = FenceKeeper(_Session())
    try:
        k.add_state(keys.state_key("m", "N9"), _state("N9", 1_000_000, 1))
        k.add_state(keys.state_key("m", "N1"), _state("N1", 2, 1))
        assert k.record("m").seen == {}
        k.add_state(keys.state_key("m", "N1"), _state("N1", 2, 2))
        k.add_state(keys.state_key("m", "N1"), _state("N9", 2, 3))  # another sender's key
        assert k.record("m").seen == {"N1": 2}
        assert json.loads(json.dumps(k.record("m").complete)) == []
    finally:
        k.close()


def _life(k: FenceKeeper, aid: str, inc: int) -> None:
    """``aid`` comes up and publishes two states of incarnation ``inc``."""
    k.token(keys.alive_key("m", aid), True)
    for seq in (1, 2):
        k.add_state(keys.state_key("m", aid), _state(aid, inc, seq))


def test_a_fresh_journal_is_refused_only_while_its_old_run_is_under_way() -> None:
    """The router's clock tells a run under way from a new run on the same router: A and B
    flew; A's journal is lost. While B's life overlapped A's (mid-run), or B resumed a
    journal, A fresh is refused; once both left and the team starts again fresh, in any
    order, nobody is (the race that failed CI: B fresh and live first, then A fresh)."""
    from agent.runners.recovery import under_way

    t = [0.0]
    k = FenceKeeper(_Session(), now=lambda: t[0])
    try:
        _life(k, "A", 1)
        _life(k, "B", 1)
        t[0] = 10.0
        k.token(keys.alive_key("m", "A"), False)  # A dies mid-run, its journal lost
        t[0] = 12.0
        rec = k.record("m")
        assert rec.seen == {"A": 1, "B": 1}
        assert rec.alive_for == {"B": 12.0} and rec.silent_for == {"A": 2.0}
        assert under_way(rec, "A", {"B"}) == {"B"}
        t[0] = 20.0
        k.token(keys.alive_key("m", "B"), False)  # the run ends
        t[0] = 100.0
        _life(k, "B", 1)  # a new run: B fresh, up first
        t[0] = 101.0
        rec = k.record("m")
        assert rec.alive_for == {"B": 1.0} and rec.silent_for == {"A": 91.0}
        assert rec.resumed == [] and under_way(rec, "A", {"B"}) == set()
        k.token(keys.alive_key("m", "B"), False)
        t[0] = 110.0
        _life(k, "B", 2)  # B resumed its journal of the old run
        assert k.record("m").resumed == ["B"]
        assert under_way(k.record("m"), "A", {"B"}) == {"B"}
        # a token the keeper has not heard yet counts as just up; A still live counts all
        assert under_way(rec, "A", {"C"}) == set()
        k.token(keys.alive_key("m", "A"), True)
        assert under_way(k.record("m"), "A", {"C"}) == {"C"}
    finally:
        k.close()


def test_a_token_withdrawn_and_announced_again_at_once_keeps_its_life() -> None:
    """When a session closes the router may withdraw the tokens it learned through it and
    announce them again (0.27 s later on a loaded machine, which failed the flying-agent
    fresh-journal test once): B's token going and coming back within ``BLIP_S`` keeps its
    age, so A's fresh journal is still refused; a token back later is a new life."""
    from agent.net.keeper import BLIP_S
    from agent.runners.recovery import under_way

    t = [0.0]
    k = FenceKeeper(_Session(), now=lambda: t[0])
    try:
        _life(k, "A", 1)
        _life(k, "B", 1)
        t[0] = 10.0
        k.token(keys.alive_key("m", "A"), False)  # A dies mid-run, its journal lost
        k.token(keys.alive_key("m", "B"), False)  # the router withdraws B's token ...
        t[0] = 10.27
        k.token(keys.alive_key("m", "B"), True)  # ... and announces it again
        t[0] = 12.0
        rec = k.record("m")
        assert rec.alive_for == {"B": 12.0} and under_way(rec, "A", {"B"}) == {"B"}
        k.token(keys.alive_key("m", "B"), False)  # B leaves for good
        t[0] = 12.0 + BLIP_S + 0.5
        _life(k, "B", 1)  # and a new run starts: its life starts now
        rec = k.record("m")
        assert rec.alive_for == {"B": 0.0} and under_way(rec, "A", {"B"}) == set()
    finally:
        k.close()


def test_the_fence_record_survives_a_restart_of_the_keeper(tmp_path: Path) -> None:
    """A keeper with a state directory writes the record (once per burst of changes); a new
    keeper on the same directory answers the same incarnations, completions and proofs, and
    counts every agent silent since the restart (a fresh journal is still refused while its
    team is live). A damaged file is set aside and the keeper starts empty."""
    from agent.net.keeper_store import RECORD_FILE
    from agent.runners.recovery import under_way

    t = [0.0]
    k = FenceKeeper(_Session(), now=lambda: t[0], state_dir=tmp_path)
    proof = FenceProof(epoch=2, coordinator="B", fenced=["C"], ballots=[])
    try:
        _life(k, "A", 1)
        _life(k, "B", 3)
        k.add_state(keys.state_key("m", "B"), _state("B", 3, 3, complete=True, proofs=[proof]))
        k.flush()
    finally:
        k.close()
    assert (tmp_path / RECORD_FILE).is_file()
    t[0] = 50.0
    again = FenceKeeper(_Session(), now=lambda: t[0], state_dir=tmp_path)
    try:
        again.token(keys.alive_key("m", "B"), True)  # B's token, sent again to the new router
        t[0] = 51.0
        rec = again.record("m")
        assert rec.seen == {"A": 1, "B": 3}
        assert rec.complete == ["B"] and rec.proofs == [proof]
        assert rec.silent_for == {"A": 1.0} and rec.alive_for == {"B": 1.0}
        assert under_way(rec, "A", {"B"}) == {"B"}
    finally:
        again.close()
    (tmp_path / RECORD_FILE).write_bytes(b"\x93not a record")
    third = FenceKeeper(_Session(), state_dir=tmp_path)
    try:
        assert third.record("m").seen == {}
        assert (tmp_path / "fence-record.damaged").read_bytes() == b"\x93not a record"
    finally:
        third.close()


def test_a_restarted_router_process_still_answers_the_record(tmp_path: Path) -> None:
    """``viscover router --state-dir``: two states of N1 heard, the router stopped and
    started again on the same port: its record still lists N1 (a drone back late after a
    router restart still hears what its team decided)."""
    from agent.net.router import free_tcp_port, start_router_process, stop_router_process
    from agent.runners.recovery import fence_record

    port = free_tcp_port()
    proc, ep = start_router_process(port, state_dir=tmp_path / "router")
    try:
        tp = ZenohTransport(client_config([ep]), None, "N1")
        try:
            seq = [0]

            def heard() -> bool:  # a state every 0.1 s until the router lists N1
                seq[0] += 1
                tp.publish(keys.state_key("m", "N1"), _state("N1", 2, seq[0]))
                rec = fence_record(tp, "m", 0.5)
                return rec is not None and rec.seen == {"N1": 2}
            assert wait_until(heard, 10.0)
            time.sleep(0.5)  # the keeper writes its record 0.2 s after a change
        finally:
            tp.close()
    finally:
        assert stop_router_process(proc) in (0, -15)
    proc, ep = start_router_process(port, state_dir=tmp_path / "router")
    try:
        tp = ZenohTransport(client_config([ep]), None, "probe")
        try:
            rec = fence_record(tp, "m", 5.0)
            assert rec is not None and rec.seen == {"N1": 2} and "N1" in rec.silent_for
        finally:
            tp.close()
    finally:
        stop_router_process(proc)
