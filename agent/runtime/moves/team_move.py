"""The registered move ``team_move`` (strategy "potential", teams of four or more): at each
stage change after stage 2 the leader (the first live member in team order) re-splits the
whole team's sets between new poses, leg by leg; a ``holding`` move (its legs hold the pose).
Made by :class:`~agent.runtime.moves.coverage.CoverageMoves`, which owns its state."""

from __future__ import annotations

from agent.protocol.machine import DecideFn
from agent.runtime.core.events import Asking
from agent.runtime.moves.move import Move
from agent.wire.peer import Offer


class TeamMove(Move):
    """The leader's whole-team re-split at a stage change (eq. 3.10 on the team)."""

    kind = "holding"

    def step(self, now: float) -> Asking[bool]:
        """Start the re-split when this agent leads it: True if a leg is now in flight."""
        return (yield from self.ctx.coverage.maybe_team_move(now))

    def terms(self, req: Offer) -> DecideFn | None:
        """A leg of a peer's re-split, in the coverage stages."""
        return self.ctx.coverage.leg_terms(req)


MOVE = TeamMove
