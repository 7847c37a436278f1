"""The registered strategy's moves (:mod:`agent.strategy.registry`), as the core's tick asks
them (:meth:`agent.runtime.core.agent_core.AgentCore.step`): one :class:`StrategyDriver` per
agent that tries the strategy's moves in their registered order, each the
:class:`~agent.runtime.moves.move.Move` of its name (``agent.runtime.moves.<name>``).

The tick is the thesis' (figure 4.1 and section 4.5): while a move of the strategy is under way
the agent holds its pose (:meth:`StrategyDriver.holds`); else it optimises while it is
optimising; converged, the strategy may take the tick (:meth:`StrategyDriver.converged`)
before the agent offers Algorithm 7 to its next partner. A re-split offered to the agent is
judged by the first move that claims it (:meth:`StrategyDriver.terms`); what each move
publishes joins the agent's state (:meth:`StrategyDriver.published`).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, TypeVar

from agent.protocol.machine import DecideFn
from agent.protocol.regroup import nothing_moves
from agent.runtime.core.events import Asking
from agent.runtime.moves.move import Move, MoveContext, make_moves
from agent.strategy.registry import Moves
from agent.wire.peer import Offer

M = TypeVar("M", bound=Move)


class StrategyDriver:
    """A strategy's part of one agent's tick: its registered moves, tried in order."""

    def __init__(self, holding: Sequence[Move], taking: Sequence[Move]) -> None:
        self.holding, self.taking = list(holding), list(taking)

    def holds(self, now: float) -> Asking[bool]:
        """Whether a move of the strategy is under way at mission time ``now`` [s] (started
        or driven on now): the agent holds its pose this tick."""
        for move in self.holding:
            if (yield from move.step(now)):
                return True
        return False

    def converged(self, now: float) -> Asking[bool]:
        """The agent is converged and may trade: the strategy's moves at ``now`` [s]; True if
        one took the tick (no Algorithm-7 offer this tick)."""
        for move in self.taking:
            if (yield from move.step(now)):
                return True
        return False

    def terms(self, req: Offer) -> DecideFn:
        """The decision for a re-split offer ``req``: the first move's that claims it, else
        one that moves nothing (a strategy without such moves takes no re-split)."""
        for move in (*self.holding, *self.taking):
            decide = move.terms(req)
            if decide is not None:
                return decide
        return nothing_moves

    def find(self, kind: type[M]) -> M | None:
        """This agent's move of class ``kind``, if its strategy registers it (diagnostics)."""
        return next((m for m in (*self.holding, *self.taking) if isinstance(m, kind)), None)

    def published(self) -> dict[str, Any]:
        """The state fields the moves own, with their values now."""
        out: dict[str, Any] = {}
        for move in (*self.holding, *self.taking):
            out.update(move.published())
        return out


def strategy_driver(moves: Moves, ctx: MoveContext) -> StrategyDriver:
    """The driver of one agent making ``moves`` (its strategy's, or an inspection's)."""
    return StrategyDriver(make_moves(moves.holding, "holding", ctx),
                          make_moves(moves.converged, "taking", ctx))
