"""The registered move ``take_work`` (inspection missions): a drone with nothing of its own
left re-splits with the peer whose remaining tour is longest (:func:`~agent.strategy.
inspection.next_action`), else flies home; a ``taking`` move that always takes the tick.
Made by :class:`~agent.runtime.moves.work_taker.WorkTaker`, which owns its state."""

from __future__ import annotations

from agent.protocol.machine import DecideFn
from agent.runtime.core.events import Asking
from agent.runtime.moves.initial_split import inspection_leg_terms
from agent.runtime.moves.move import Move
from agent.wire.peer import Offer


class TakeWork(Move):
    """Taking work from a peer, or the flight home."""

    kind = "taking"

    def step(self, now: float) -> Asking[bool]:
        """Try to take work (or fly home): always takes the tick."""
        yield from ()
        if self.ctx.taker is not None:
            self.ctx.taker.tick(now)
        return True

    def terms(self, req: Offer) -> DecideFn | None:
        """A leg of a peer's re-split, for our current set exactly."""
        return inspection_leg_terms(req)


MOVE = TakeWork
