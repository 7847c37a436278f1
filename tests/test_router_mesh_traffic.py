"""Traffic per drone (``bench/bench_traffic.py``): what a drone sends must not grow with the
team. A state names at most ``PARTNERS_PUBLISHED`` partners however many are left (receivers
only need whether any are), completion is still agreed, and the counting network counts what
the protocol says it sends (a state at 5 Hz, a pose at most every tick)."""

from __future__ import annotations

import pytest

from agent.net.memory import MemoryTransport
from agent.wire.peer import PARTNERS_PUBLISHED, AgentState
from bench.bench_traffic import _CODEC, CountingNetwork, bench_memory


class _Keep(CountingNetwork):
    """Also keeps every state published."""

    def __init__(self) -> None:
        super().__init__()
        self.states: list[AgentState] = []

    def _publish(self, sender: MemoryTransport, key: str, payload: bytes, kind: str) -> None:
        if kind == "state":
            st = _CODEC.decode(payload, key)
            assert isinstance(st, AgentState)
            self.states.append(st)
        super()._publish(sender, key, payload, kind)


def test_states_name_few_partners_and_completion_is_agreed(monkeypatch: pytest.MonkeyPatch
                                                           ) -> None:
    """8 drones: at the start every drone has 7 partners to try, its states name 3; the
    mission completes (every drone converged with none left: emptiness is what completion
    reads) with no violation."""
    nets: list[_Keep] = []

    def counting() -> _Keep:
        nets.append(_Keep())
        return nets[-1]

    monkeypatch.setattr("bench.bench_traffic.CountingNetwork", counting)
    row = bench_memory(8, per_drone=4)
    assert row["complete"] and row["violations"] == 0
    states = nets[0].states
    assert max(len(s.partners) for s in states) == PARTNERS_PUBLISHED < 7
    assert any(s.complete and not s.partners for s in states)


def test_counted_rates_are_the_protocols() -> None:
    """4 drones: each sends its state at 5 Hz of mission time (a few more on changes) and a
    pose at most every planner tick (10 Hz); it hears the 3 others' states, and what one sends
    as trade queries another receives."""
    row = bench_memory(4, per_drone=4)
    sent, got = row["sent"]["by_kind"], row["received"]["by_kind"]
    assert 4.9 <= sent["state"]["msgs_per_s"] <= 6.5
    assert 0 < sent["pose"]["msgs_per_s"] <= 10.01
    assert got["state"]["msgs_per_s"] == pytest.approx(3 * sent["state"]["msgs_per_s"],
                                                       rel=0.02)
    assert got["trade"]["msgs_per_s"] == pytest.approx(sent["trade"]["msgs_per_s"])
