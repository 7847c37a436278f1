"""The waits of agent cores parked by :class:`~agent.testing.core_net.CoreNet` (its ``park``
mode): a tick's :class:`~agent.runtime.core.events.Ask`,
:class:`~agent.runtime.core.events.AskHedged`,
:class:`~agent.runtime.core.events.Compute` or :class:`~agent.runtime.core.events.Command` is kept,
the core waiting, until a test answers it, late and in any order across agents, while the
core is stepped everything else meanwhile (queries of its peers, samples, liveliness).

How an ask is answered (:data:`How`): ``"reply"``, its query delivered to its target at
answer time and the reply taken (each by the fate of the tick that asked); ``"timeout"``,
no reply in time, the query lost on its way (never delivered); ``"late"``, the query
delivered and answered by the target, but its reply arrived after the asker had stopped
waiting (None). A computation is run when it is answered, or earlier
(:meth:`~agent.testing.core_net.CoreNet.compute_early`: a worker finished it, its result
delivered later); a command is flown when it is answered.
"""

from __future__ import annotations

import random
from dataclasses import dataclass
from typing import Literal

from agent.net.contract import HedgedReply
from agent.runtime.core.events import AskHedged, Wait


@dataclass(frozen=True)
class Fate:
    """How the network treats the messages of one step: a random source and the chances of
    a message lost and a message duplicated."""

    rng: random.Random
    loss: float = 0.0
    dup: float = 0.0

    def lost(self) -> bool:
        """Whether the next message is lost."""
        return self.loss > 0.0 and self.rng.random() < self.loss

    def copies(self) -> int:
        """How many copies of the next message arrive (0: lost)."""
        if self.lost():
            return 0
        return 2 if self.dup > 0.0 and self.rng.random() < self.dup else 1


__all__ = ["HOWS", "NOT_YET", "Fate", "How", "Parked", "WaitStats", "hedged"]

#: How a parked ask is answered (see the module docstring).
How = Literal["reply", "timeout", "late"]
HOWS: tuple[How, ...] = ("reply", "timeout", "late")


class _NotYet:
    """The result of a computation not run yet."""

    def __repr__(self) -> str:
        return "NOT_YET"


NOT_YET = _NotYet()


@dataclass
class Parked:
    """One core's tick waiting: what for, the fate of its messages, the order it was parked
    in (``seq``), the mission time [s] and the net's step count then; a computation's result
    if run before its answer."""

    wait: Wait
    fate: Fate
    seq: int
    at: float
    steps: int
    early: object = NOT_YET


@dataclass
class WaitStats:
    """What became of the parked waits (a test labels its runs with them)."""

    parked: int = 0  #: waits parked
    computes: int = 0  #: of which computations
    commands: int = 0  #: of which vehicle commands
    answered: int = 0  #: waits answered
    #: answered while another agent's wait, parked before it, was still waiting
    out_of_order: int = 0
    #: answered after other steps ran (the clock moved or other events were stepped)
    late: int = 0
    timeouts: int = 0  #: asks answered None without their query delivered
    late_replies: int = 0  #: asks whose query was delivered and whose reply came too late
    stale: int = 0  #: computations answered with a result computed before
    dropped: int = 0  #: waits of an agent that crashed or left before their answer


def hedged(ask: AskHedged, payload: bytes | None) -> HedgedReply:
    """What the hedging transport returns for ``ask``: ``payload`` as the reply of its first
    copy (None: no copy answered), every copy sent."""
    out = sum(len(c) for c in ask.copies)
    if payload is None:
        return HedgedReply(None, sent=len(ask.copies), bytes_out=out)
    return HedgedReply(payload, copy=0, rtt_s=0.0, sent=len(ask.copies), bytes_out=out)
