"""What a strategy adds to the thesis' agent, as the core's tick asks it
(:meth:`agent.runtime.core.AgentCore.step`): one :class:`StrategyDriver` per agent, chosen by
the registered strategy's flags (:mod:`agent.strategy.registry`) and the mission's kind.

The tick is the thesis' (figure 4.1 and section 4.5): while a move of the strategy is under way
the agent holds its pose (:meth:`StrategyDriver.holds`); else it optimises while it is
optimising; converged, the strategy may take the tick (:meth:`StrategyDriver.converged`)
before the agent offers Algorithm 7 to its next partner.

* ``thesis``: nothing added.
* ``potential``: the leader's whole-team re-split at a stage change and the revert pulls hold
  the pose; converged, a queued pair or triple re-split is offered
  (:mod:`agent.runtime.moves`, :mod:`agent.runtime.revert`).
* an inspection mission (any strategy): the initial re-splits hold the pose; converged, the
  drone takes work from a peer or flies home, and never offers Algorithm 7
  (:mod:`agent.runtime.work_taker`).
"""

from __future__ import annotations

from typing import Protocol

from agent.runtime.events import Asking
from agent.runtime.moves import CoverageMoves
from agent.runtime.revert import Revert
from agent.runtime.work_taker import WorkTaker
from agent.strategy.registry import StrategyName, strategy_of


class StrategyDriver(Protocol):
    """A strategy's part of one agent's tick (see the module docstring)."""

    def holds(self, now: float) -> Asking[bool]:
        """Whether a move of the strategy is under way at mission time ``now`` [s] (started
        or driven on now): the agent holds its pose this tick. (May compute outside the
        core: :mod:`agent.runtime.events`.)"""

    def converged(self, now: float) -> Asking[bool]:
        """The agent is converged and may trade: the strategy's own step at ``now`` [s];
        True if it took the tick (no Algorithm-7 offer this tick)."""


class ThesisDriver:
    """Chapter 5 exactly: nothing beyond the planner and Algorithm 7."""

    def holds(self, now: float) -> Asking[bool]:
        """Never: the thesis makes no move of its own."""
        yield from ()
        return False

    def converged(self, now: float) -> Asking[bool]:
        """Never: a converged agent offers Algorithm 7 to its next partner."""
        yield from ()
        return False


class PotentialDriver:
    """``strategy = "potential"``: the coverage moves after the thesis stage."""

    def __init__(self, moves: CoverageMoves, revert: Revert) -> None:
        self.moves, self.revert = moves, revert

    def holds(self, now: float) -> Asking[bool]:
        """The leader's whole-team re-split starting, or the revert's pulls under way."""
        return (yield from self.moves.maybe_team_move(now)) or self.revert.step(now)

    def converged(self, now: float) -> Asking[bool]:
        """The queued re-split (a pair or a triple after a NoTrade), if one beats the
        current visions."""
        return (yield from self.moves.maybe_regroup(now))


class InspectionDriver:
    """An inspection mission: tours and captures, re-splits of the work."""

    def __init__(self, taker: WorkTaker) -> None:
        self.taker = taker

    def holds(self, now: float) -> Asking[bool]:
        """This drone's part of the initial re-splits is in flight."""
        yield from ()
        return self.taker.initial_split(now)

    def converged(self, now: float) -> Asking[bool]:
        """Nothing left to capture: take work from a peer, or go home (always the tick)."""
        yield from ()
        self.taker.tick(now)
        return True


def strategy_driver(strategy: StrategyName, moves: CoverageMoves, revert: Revert,
                    taker: WorkTaker | None) -> StrategyDriver:
    """The driver of an agent of strategy ``strategy`` (``taker``: an inspection mission's)."""
    if taker is not None:
        return InspectionDriver(taker)
    if strategy_of(strategy).coverage_moves:
        return PotentialDriver(moves, revert)
    return ThesisDriver()
