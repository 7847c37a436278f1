"""The strategies a scenario may name (``strategy = "..."``), each registered once here as the
moves its drones make beyond the thesis' planner step and Algorithm 7, in the order they try
them; the simulator (:mod:`agent.sim`) and the agents (:mod:`agent.runtime`) read these
entries, never the name.

A strategy is its registration line: a name and its :class:`Moves`, each move named. A move
named ``x`` is the part of the agent in module ``agent.runtime.moves.x`` (its ``MOVE``
class, :class:`agent.runtime.moves.move.Move`: its state, what it publishes, the re-split
terms it accepts), so a new behaviour is that module, one line here and its tests
(``docs/behaviours.md``). Inspection missions are not a strategy: the ``[inspection]``
table gives any strategy :data:`INSPECTION_MOVES` (:mod:`agent.strategy.inspection`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

#: A strategy's name, as a scenario gives it (a key of :data:`REGISTRY`; ``scenario check``
#: refuses any other).
StrategyName = str
#: A move's name: the module ``agent.runtime.moves.<name>`` that makes it. Moves that, under
#: way, hold the drone's pose for the tick: ``team_move`` (the leader's whole-team re-split
#: at a stage change), ``revert`` (the pulls back to the thesis-stage pose when the moves
#: ended lower), ``initial_split`` (an inspection's initial re-splits). Moves a converged
#: drone tries instead of its Algorithm-7 offer: ``regroup`` (the pair or triple re-split
#: queued after a NoTrade, if it beats the members' visions), ``take_work`` (an inspection
#: drone with nothing left: take work from a peer or fly home; always takes the tick).
MoveName = str

#: The moves that judge viewpoints on the structure's voxels (:mod:`agent.core.viewpoints`).
VIEWPOINT_MOVES: Final[frozenset[str]] = frozenset({"team_move", "revert", "regroup"})


@dataclass(frozen=True)
class Moves:
    """What a drone does beyond the thesis, tried in order each tick (figure 4.1's loop)."""

    #: the first of these under way holds the pose (no planner step, no offer)
    holding: tuple[MoveName, ...] = ()
    #: a converged drone tries these; the first that takes the tick replaces the offer
    converged: tuple[MoveName, ...] = ()


@dataclass(frozen=True)
class Strategy:
    """One strategy: its name, a one-line summary and its moves."""

    name: StrategyName
    summary: str  #: one line, for error messages and ``--help``
    moves: Moves = Moves()

    @property
    def extends_thesis(self) -> bool:
        """It makes moves beyond the thesis' planner step and Algorithm 7."""
        return bool(self.moves.holding or self.moves.converged)

    @property
    def requires_trading(self) -> bool:
        """Its moves move landmarks between agents: ``trading = true`` needed."""
        return self.extends_thesis

    @property
    def coverage_moves(self) -> bool:
        """Its moves judge viewpoints: the structure is voxelised for them, and after the
        thesis' completion its drones have the coverage stage (:mod:`agent.runtime.moves.coverage`:
        flights to a better viewpoint, then its moves, stage by stage)."""
        return bool(VIEWPOINT_MOVES & {*self.moves.holding, *self.moves.converged})


#: An inspection mission's moves, whatever its strategy (``[inspection]``).
INSPECTION_MOVES: Final = Moves(holding=("initial_split",), converged=("take_work",))

#: Every strategy, by name: one registration line each.
REGISTRY: Final[dict[StrategyName, Strategy]] = {s.name: s for s in (
    Strategy("thesis", "chapter 5 exactly: gradient ascent and Algorithm 7"),
    Strategy("potential", "the thesis, then coverage moves that leave no visible landmark "
             "unseen", Moves(holding=("team_move", "revert"), converged=("regroup",))),
)}

#: The registered strategies' names, in registration order.
STRATEGIES: tuple[StrategyName, ...] = tuple(REGISTRY)


def strategy_of(name: StrategyName) -> Strategy:
    """The registered strategy called ``name``."""
    return REGISTRY[name]


def moves_of(strategy: StrategyName, inspection: bool) -> Moves:
    """The moves a drone of ``strategy`` makes (an inspection mission's replace them)."""
    return INSPECTION_MOVES if inspection else strategy_of(strategy).moves
