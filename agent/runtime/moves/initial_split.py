"""The registered move ``initial_split`` (inspection missions): at the start each drone carries
out its part of the team's initial re-splits (the pure
:func:`~agent.strategy.inspection.initial_resplits` of the mission's start), leg by leg; a
``holding`` move (a leg in flight holds the pose; otherwise the drone flies its tour
meanwhile). Made by :class:`~agent.runtime.moves.work_taker.WorkTaker`, which owns its
state."""

from __future__ import annotations

from agent.protocol.machine import DecideFn
from agent.protocol.regroup import regroup_decision
from agent.runtime.core.events import Asking
from agent.runtime.moves.move import Move
from agent.wire.peer import Offer


class InitialSplit(Move):
    """This drone's part of the initial re-splits."""

    kind = "holding"

    def step(self, now: float) -> Asking[bool]:
        """The next leg, if any: True while one is in flight."""
        yield from ()
        taker = self.ctx.taker
        return taker is not None and taker.initial_split(now)

    def terms(self, req: Offer) -> DecideFn | None:
        """A leg of a peer's re-split (initial, taking work, or a hand-over), for our current
        set exactly, at any stage."""
        return inspection_leg_terms(req)


def inspection_leg_terms(req: Offer) -> DecideFn | None:
    """The decision for a re-split leg offered to an inspection drone (not a pull)."""
    g = req.regroup
    return regroup_decision(g) if g is not None and not g.pull else None


MOVE = InitialSplit
