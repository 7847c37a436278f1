"""What agents say when a mission ends: landmarks unseen by their owner and landmarks
orphaned by an agent that left for good (issue: loss must not be reported as success)."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

from agent.clock import ManualClock
from agent.runners.process import quality_warning, result_line
from agent.runners.quality import orphaned, unseen_owned
from agent.testing.memsim import MemoryMission
from agent.wire.peer import unpack
from tests.agent_helpers import fixed_motion, random_scene


def test_a_departed_agents_landmarks_are_reported_orphaned(tmp_path: Path) -> None:
    """N2 crashes for good once every agent heard its state; nothing is adopted
    (``lost_after = 0``): the survivors complete, and both name exactly N2's last published
    landmarks as orphaned, in the JSON line and in a one-line warning."""
    sc = dataclasses.replace(random_scene(3, 12, 5), lost_after=0.0)
    m = MemoryMission(sc, tmp_path, None, motion=fixed_motion(5))
    assert m.run(60.0, until=lambda mm: all(
        "N2" in rt.core.members.states for a, rt in mm.agents.items() if a != "N2"))
    gone = set(m.agents["N2"].core.machine.owned)
    assert gone  # N2 held something worth reporting
    m.crash("N2")
    survivors = [m.agents["N0"], m.agents["N1"]]
    assert m.run(300.0, until=lambda _m: all(rt.complete for rt in survivors))
    for rt in survivors:
        last = unpack(rt.core.members.states["N2"][0].owned)
        assert last is not None
        expect = sorted(set(last[0].tolist()) - set(m.owner_of()))
        assert orphaned(rt) == {"N2": expect} and expect
        doc = json.loads(result_line(rt, ManualClock(), {}))
        assert doc["orphaned"] == {"N2": expect}
        warning = quality_warning(rt)
        assert f"{len(expect)} landmark(s) orphaned by N2, which left" in warning
    m.close()


def test_unseen_own_landmarks_are_named(tmp_path: Path) -> None:
    """With fixed poses an agent may own landmarks it cannot see; unseen_owned lists exactly
    those with zero vision (checked against the per-landmark vision directly)."""
    from agent.core.vision import per_landmark

    sc = random_scene(2, 16, 11)
    m = MemoryMission(sc, tmp_path, None, motion=fixed_motion(11, max_ticks=0))
    assert m.run(120.0)
    for rt in m.agents.values():
        p, v, _ = rt.pose.current()
        ids = sorted(rt.core.machine.owned)
        rows = [sc.landmark_ids.index(i) for i in ids]
        each = per_landmark(p, v, sc.q[rows], sc.u[rows], sc.d_opt)
        assert unseen_owned(rt) == [i for i, e in zip(ids, each, strict=True) if e <= 0.0]
    assert any(unseen_owned(rt) for rt in m.agents.values())  # the case is exercised
    m.close()


def test_landmarks_adopted_by_an_agent_that_left_complete_are_not_orphaned(
        tmp_path: Path) -> None:
    """N2 is lost and fenced, N0 and N1 adopt its landmarks and complete; N1 then leaves (its
    last state complete). N0's end-of-mission line names no orphan: what N1 adopted from N2
    has an owner that finished the mission."""
    sc = dataclasses.replace(random_scene(3, 12, 5), lost_after=1.0)
    m = MemoryMission(sc, tmp_path, None, motion=fixed_motion(5))
    assert m.run(60.0, until=lambda mm: all(
        "N2" in rt.core.members.states for a, rt in mm.agents.items() if a != "N2"))
    m.crash("N2")
    n0, n1 = m.agents["N0"], m.agents["N1"]
    assert m.run(300.0, until=lambda _m: n0.complete and n1.complete
                 and "N2" in n0.core.machine.fenced and not m.final_violations())
    assert m.run(m.net.now + 2.0, until=lambda _m: False) is False  # states settle
    assert n1.core.machine.adopted, "N1 adopted nothing: the case is not exercised"
    m.crash("N1")  # leaves a completed mission
    m.run(m.net.now + 1.0, until=lambda _m: "N1" not in n0.core.members.live)
    assert "N1" not in n0.core.members.live
    assert orphaned(n0) == {}
    assert "orphaned" not in quality_warning(n0)
    # As an agent that restarted after N1 left (it never heard N1's adoption): N2 is fenced,
    # its claims are void, and nothing is named orphaned (chaos seed 5 named N1's adoptions).
    del n0.core.members.states["N1"]
    assert orphaned(n0) == {}
    m.close()
