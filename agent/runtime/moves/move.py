"""The contract of a strategy's move as one agent makes it, and how the core finds the part that
makes a registered move.

A strategy's registration line (:mod:`agent.strategy.registry`) names its moves; the move
named ``x`` is made by the :class:`Move` subclass ``MOVE`` of module
``agent.runtime.moves.x`` (:func:`move_class`). One instance per agent
(:func:`make_moves`) owns everything the move needs: its state, what it adds to the agent's
published state (:meth:`Move.published`) and which re-split offers it accepts, with what
decision (:meth:`Move.terms`). It reads the agent through :class:`MoveContext` and changes
the shared state only through :class:`~agent.runtime.core.shared.Shared`'s named methods.

A ``holding`` move under way holds the drone's pose for the tick (no planner step, no offer);
a ``taking`` move is tried by a converged drone before its Algorithm-7 offer and may take the
tick. Both are generators (:data:`~agent.runtime.core.events.Asking`): they may ask the runtime
for a long pure computation and wait for it. The recipe for a new move is in
``docs/behaviours.md``.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, ClassVar, Literal

from agent.protocol.machine import DecideFn
from agent.runtime.core.events import Asking
from agent.runtime.core.shared import Shared
from agent.runtime.ends.membership import Membership
from agent.runtime.ends.trade_client import PoseNow
from agent.runtime.moves.coverage import CoverageMoves
from agent.runtime.moves.inspecting import Inspecting
from agent.runtime.moves.work_taker import WorkTaker
from agent.strategy.registry import MoveName
from agent.wire.codec import Codec
from agent.wire.peer import Offer, Request

__all__ = ["Move", "MoveContext", "make_moves", "move_class"]

#: When a move is tried (see the module docstring).
MoveKind = Literal["holding", "taking"]


@dataclass(frozen=True)
class MoveContext:
    """What a move may read and use of its agent: the shared state (changed through its named
    methods only), the peers, the request codec, the pose now ([m; world ENU]), the vision of
    its set (eq. 3.4), and the core's parts a move builds on: the re-split legs and stages
    (``coverage``), an inspection's tours and re-splits (``inspecting``, ``taker``; None in
    coverage missions)."""

    shared: Shared
    members: Membership
    c_req: Codec[Request]
    pose_now: PoseNow
    vision: Callable[[], float]
    coverage: CoverageMoves
    inspecting: Inspecting | None
    taker: WorkTaker | None


class Move:
    """One registered move of one agent (see the module docstring)."""

    #: when the tick tries it: ``holding`` (before the planner step) or ``taking`` (converged)
    kind: ClassVar[MoveKind]

    def __init__(self, ctx: MoveContext) -> None:
        self.ctx = ctx

    def step(self, now: float) -> Asking[bool]:
        """The move at mission time ``now`` [s]: True if it holds the pose (``holding``) or
        took the tick (``taking``)."""
        raise NotImplementedError

    def published(self) -> Mapping[str, Any]:
        """Fields of :class:`~agent.wire.peer.AgentState` this move owns, with their values
        now (none by default)."""
        return {}

    def terms(self, req: Offer) -> DecideFn | None:
        """The decision for a re-split offer ``req`` (``req.regroup`` set) this move accepts,
        or None: not one of its own (offers no move claims move nothing)."""
        return None


def move_class(name: MoveName) -> type[Move]:
    """The :class:`Move` that makes the move called ``name``: ``MOVE`` of module
    ``agent.runtime.moves.<name>``."""
    try:
        module = importlib.import_module(f"{__package__}.{name}")
    except ModuleNotFoundError as e:
        raise LookupError(f"move {name!r}: no module agent.runtime.moves.{name}") from e
    cls = getattr(module, "MOVE", None)
    if not (isinstance(cls, type) and issubclass(cls, Move)):
        raise LookupError(f"move {name!r}: agent.runtime.moves.{name} has no MOVE class")
    return cls


def make_moves(names: tuple[MoveName, ...], kind: MoveKind, ctx: MoveContext) -> list[Move]:
    """One agent's moves ``names`` of ``kind``, in their registered order."""
    moves = [move_class(name)(ctx) for name in names]
    wrong = [name for name, m in zip(names, moves, strict=True) if m.kind != kind]
    if wrong:
        raise LookupError(f"moves {wrong} are not {kind} moves")
    return moves
