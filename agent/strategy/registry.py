"""The strategies a scenario may name (``strategy = "..."``), each registered once here with
the behaviours the simulator (:mod:`agent.sim`) and the agents (:mod:`agent.runtime`) run for
it; both read these flags, never the name.

A strategy that combines behaviours that exist is one line in :data:`REGISTRY` (and its
name in :data:`StrategyName`); a new behaviour is a module of :mod:`agent.strategy` plus a
flag here that the drivers read. Inspection missions are not a strategy: the ``[inspection]``
table turns them on for any strategy (:mod:`agent.strategy.inspection`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, get_args

#: The names a scenario may give (checked by :func:`strategy_of` and by mypy).
StrategyName = Literal["thesis", "potential"]


@dataclass(frozen=True)
class Strategy:
    """One strategy and the behaviours it turns on."""

    name: StrategyName
    summary: str  #: one line, for error messages and ``--help``
    #: it moves landmarks between agents, so ``trading = true`` is required
    requires_trading: bool
    #: after the thesis stage: relocations, pair / triple / whole-team re-splits judged on
    #: potential vision and the revert safeguard (:mod:`agent.core.coverage_moves`,
    #: :mod:`agent.strategy.potential`); the structure is voxelised for its viewpoints
    coverage_moves: bool


#: Every strategy, by name: its registration line.
REGISTRY: dict[StrategyName, Strategy] = {s.name: s for s in (
    Strategy("thesis", "chapter 5 exactly: gradient ascent and Algorithm 7",
             requires_trading=False, coverage_moves=False),
    Strategy("potential", "the thesis, then coverage moves that leave no visible landmark "
             "unseen", requires_trading=True, coverage_moves=True),
)}

STRATEGIES: tuple[StrategyName, ...] = get_args(StrategyName)


def strategy_of(name: StrategyName) -> Strategy:
    """The registered strategy called ``name``."""
    return REGISTRY[name]
