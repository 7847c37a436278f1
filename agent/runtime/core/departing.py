"""A drone leaving the mission (a :class:`~agent.runtime.core.events.Depart` event): at once, or,
when its battery will not last, after handing its work over (:class:`~agent.runtime.moves.handover.
HandOver`, up to ``hand_over_s`` mission seconds; an inspection drone takes no more work and
gives up (``battery``) what it still owns uncaptured, publishing that with one more state).
Then its departure goes on the mesh (:class:`~agent.wire.departure.AgentDeparture`, repeated:
a lossy link still delivers one) and the core ends with a
:class:`~agent.runtime.core.events.Departed` effect. Part of the agent core, stepped in its tick.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Final

from agent.runtime.core.events import Depart, Departed
from agent.runtime.core.shared import Shared
from agent.runtime.moves.handover import HandOver
from agent.runtime.moves.inspecting import Inspecting
from agent.wire import keys
from agent.wire.departure import DEPARTURE_CODEC, MAX_DETAIL, AgentDeparture

#: Copies of the departure published (a lossy link still delivers one).
DEPARTURE_REPEATS: Final = 3


class Departing:
    """One departure under way (see the module docstring).

    Args:
        shared: the agent's shared state.
        event: the departure asked for.
        put: publishes a payload on a key (the core's, counted).
        inspecting: an inspection drone's part, when it hands over (it takes no more work).
        handover: the hand-over, when the event asks for one.
    """

    def __init__(self, shared: Shared, event: Depart, put: Callable[[str, bytes], None],
                 inspecting: Inspecting | None, handover: HandOver | None) -> None:
        self.s, self.event, self._put = shared, event, put
        self.detail = event.detail
        self.handover, self.inspecting = handover, inspecting
        self.said = False  #: what it leaves with is given up and published
        self.over = False
        if handover is not None and inspecting is not None:
            inspecting.want_home = True  # take no more work

    def step(self, now: float) -> Departed | None:
        """One step of the departure at mission time ``now`` [s]; once it is over, its
        departure is published and the :class:`Departed` effect returned (else None)."""
        if self.over:
            return None
        ho = self.handover
        if ho is not None:
            done = ho.step(now)
            if not done and now - self.event.now <= self.event.hand_over_s:
                return None
            if self.inspecting is not None and not self.said:
                self.said = True
                if self.inspecting.give_up_rest():  # one more tick: the state says it
                    self.s.publish_soon()
                    return None
            left = ho.owned()
            self.detail = "work handed over" if left == 0 else \
                f"{left} landmarks left to the team"
        self.over = True
        m = self.s.machine
        msg = AgentDeparture(sender=self.s.id, incarnation=m.incarnation, t=float(now),
                             reason=self.event.reason, detail=self.detail[:MAX_DETAIL],
                             owned=int(m.owned_arrays()[0].size))
        key = keys.departure_key(self.s.cfg.mission, self.s.id)
        payload = DEPARTURE_CODEC.encode(msg)
        for _ in range(DEPARTURE_REPEATS):
            self._put(key, payload)
        return Departed(self.event.reason, self.detail)
