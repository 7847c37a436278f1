"""The registered strategy's moves (:mod:`agent.strategy.registry`), as the core's tick asks
them (:meth:`agent.runtime.core.AgentCore.step`): one :class:`StrategyDriver` per agent that
tries the strategy's moves in their registered order, each carried out by the agent's part
that knows how (:func:`strategy_driver`'s tables).

The tick is the thesis' (figure 4.1 and section 4.5): while a move of the strategy is under way
the agent holds its pose (:meth:`StrategyDriver.holds`); else it optimises while it is
optimising; converged, the strategy may take the tick (:meth:`StrategyDriver.converged`)
before the agent offers Algorithm 7 to its next partner.

The moves and the parts that carry them out:

* ``team_move``, ``regroup``: :class:`~agent.runtime.moves.CoverageMoves` (the leader's
  whole-team re-split at a stage change; a queued pair or triple re-split);
* ``revert``: :class:`~agent.runtime.revert.Revert` (the pulls back to the thesis-stage pose);
* ``initial_split``, ``take_work``: :class:`~agent.runtime.work_taker.WorkTaker` (an
  inspection's initial re-splits; taking work from a peer, or flying home).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping

from agent.runtime.events import Asking
from agent.runtime.moves import CoverageMoves
from agent.runtime.revert import Revert
from agent.runtime.work_taker import WorkTaker
from agent.strategy.registry import (
    INSPECTION_MOVES,
    HoldingMove,
    Moves,
    StrategyName,
    TakingMove,
    strategy_of,
)

#: One move at mission time ``now`` [s]: True if it holds the pose / takes the tick.
MoveStep = Callable[[float], Asking[bool]]


def asking(step: Callable[[float], bool | None], result: bool | None = None) -> MoveStep:
    """A move that asks nothing, as the tick calls moves (``result``: what it answers
    whatever ``step`` returns; None: ``step``'s answer)."""
    def move(now: float) -> Asking[bool]:
        yield from ()
        out = step(now)
        return bool(out) if result is None else result
    return move


class StrategyDriver:
    """A strategy's part of one agent's tick: its registered :class:`Moves`, tried in order."""

    def __init__(self, moves: Moves, holding: Mapping[HoldingMove, MoveStep],
                 taking: Mapping[TakingMove, MoveStep]) -> None:
        self.moves = moves
        self._holding = [holding[m] for m in moves.holding]
        self._taking = [taking[m] for m in moves.converged]

    def holds(self, now: float) -> Asking[bool]:
        """Whether a move of the strategy is under way at mission time ``now`` [s] (started
        or driven on now): the agent holds its pose this tick."""
        for move in self._holding:
            if (yield from move(now)):
                return True
        return False

    def converged(self, now: float) -> Asking[bool]:
        """The agent is converged and may trade: the strategy's moves at ``now`` [s]; True if
        one took the tick (no Algorithm-7 offer this tick)."""
        for move in self._taking:
            if (yield from move(now)):
                return True
        return False


def strategy_driver(strategy: StrategyName, moves: CoverageMoves, revert: Revert,
                    taker: WorkTaker | None) -> StrategyDriver:
    """The driver of an agent of strategy ``strategy`` (``taker``: an inspection mission's,
    whose moves replace the strategy's)."""
    holding: dict[HoldingMove, MoveStep] = {
        "team_move": moves.maybe_team_move, "revert": asking(revert.step)}
    taking: dict[TakingMove, MoveStep] = {"regroup": moves.maybe_regroup}
    if taker is None:
        return StrategyDriver(strategy_of(strategy).moves, holding, taking)
    holding["initial_split"] = asking(taker.initial_split)
    taking["take_work"] = asking(taker.tick, result=True)
    return StrategyDriver(INSPECTION_MOVES, holding, taking)
