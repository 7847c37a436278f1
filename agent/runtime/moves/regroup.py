"""The registered move ``regroup`` (strategy "potential", stage 2 on): after Algorithm 7 moved
nothing with a converged partner, a converged drone offers a pair (or triple) re-split of
their sets between new poses if it beats their visions (eq. 3.10 on the group); a ``taking``
move. Made by :class:`~agent.runtime.moves.coverage.CoverageMoves`, which owns its state
(the queued partner, the group in progress, the bound on re-splits per member)."""

from __future__ import annotations

from agent.protocol.machine import DecideFn
from agent.runtime.core.events import Asking
from agent.runtime.moves.move import Move
from agent.wire.peer import Offer


class Regroup(Move):
    """The pair or triple re-split queued after a NoTrade."""

    kind = "taking"

    def step(self, now: float) -> Asking[bool]:
        """Offer the queued re-split if it helps: True if an offer is now in flight."""
        return (yield from self.ctx.coverage.maybe_regroup(now))

    def terms(self, req: Offer) -> DecideFn | None:
        """A leg of a peer's re-split, in the coverage stages."""
        return self.ctx.coverage.leg_terms(req)


MOVE = Regroup
