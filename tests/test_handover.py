"""A drone that must leave (its battery) hands its work over by trades before it goes (a
:class:`~agent.runtime.core.events.Depart` event with a hand-over,
:mod:`agent.runtime.core.departing`,
:class:`agent.runtime.moves.handover.HandOver`): in memory, on virtual time, at 0 and 30 % loss,
an inspection drone gives every landmark it owns to its peer in the middle of the mission,
owns nothing when it leaves, and the peer captures everything capturable; every landmark is
owned exactly once throughout the checked ledger changes, and nothing waits for a fence
round (no fence, no adoption)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from agent.config.parse import load_scenario
from agent.net.faults import FaultConfig
from agent.runtime.core.events import Depart
from agent.runtime.shell.runtime import AgentConfig
from agent.testing.memsim import MemoryMission
from agent.wire import keys
from agent.wire.departure import DEPARTURE_CODEC
from agent.world.structure import resolve_structure
from tests.conftest import flown_tables, scenario_path
from tests.test_adoption_memory import assert_every_landmark_owned_once


@pytest.mark.parametrize("drop", [
    pytest.param(0.0, id="lossless", marks=pytest.mark.long),  # make test: [30% loss], harder
    pytest.param(0.3, id="30% loss")])
def test_a_leaving_drone_hands_its_work_over_and_nothing_is_lost(tmp_path: Path,
                                                                 drop: float) -> None:
    sc = resolve_structure(load_scenario(scenario_path("inspect_u_building")))
    sc = dataclasses.replace(sc, lost_after=0.0)  # nobody is declared lost: no fence at all
    m = MemoryMission(sc, tmp_path, FaultConfig(drop_default=drop) if drop else None, seed=3,
                      config=AgentConfig(mission="mem", seed=3))
    try:
        table = flown_tables(m)[0]
        capturable = set(np.asarray(sc.landmark_ids)[table.capturable].tolist())
        assert not m.run(6.0)  # A and B at work
        a = m.agents["A"]
        owned_before = len(a.core.machine.owned)
        assert owned_before > 0
        said = []
        m.transports["B"].subscribe(keys.departure_key("mem", "A"),
                                    lambda k, p: said.append(DEPARTURE_CODEC.decode(p, k)))
        a.step(Depart(m.clock.now(), "battery", hand_over_s=60.0))
        while a.departed is None:
            m.step()
            assert m.clock.now() < 60.0, "the hand-over did not finish"
        assert a.departed.reason == "battery"
        assert a.departed.detail == "work handed over" and len(a.core.machine.owned) == 0
        assert a.core.departing is not None and a.core.departing.handover is not None
        assert a.core.departing.handover.legs >= 1
        left_at = m.clock.now()
        m.step()  # its departure reaches B
        assert said and said[0] is not None and said[0].reason == "battery" \
            and said[0].owned == 0
        a.stop()  # it leaves the mission (its liveliness token goes) and flies home
        m.crash("A")
        m.restarts -= 1
        m.exited["A"] = {}
        assert m.run(left_at + 400.0), f"not complete at {m.clock.now():.0f} s"
        assert m.violations == [] and m.final_violations() == []
        assert m.fenced == set()
        assert_every_landmark_owned_once(m)
        b = m.agents["B"]
        inspecting = b.core.planning.inspecting
        assert inspecting is not None  # an inspection mission
        captured = set(inspecting.captured.ids())
        assert capturable <= captured
    finally:
        m.close()
