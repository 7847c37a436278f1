"""What goes into an agent core and what comes out of it (the shape of raft's Step / Ready).

:meth:`agent.runtime.core.AgentCore.step` takes one :data:`Event` and returns the
:data:`Effect` list the runtime carries out, in order: it persists every :class:`Persist`
(fsynced when asked) before it sends anything after it, publishes, returns the
:class:`Reply` to the query that caused it, and sends an :class:`Ask` (a query of ours) and
feeds its reply back as an :class:`Answer`, and runs a :class:`Compute` (a pure computation
of the tick, e.g. a planner step) outside the core and feeds its result back the same way.
Only these suspend the core's tick; queries, samples and liveliness changes are stepped
meanwhile, as they arrive (an agent answers its peers while it computes).

Pure data: no I/O here, nothing that reads a clock.
"""

from __future__ import annotations

from collections.abc import Callable, Generator
from dataclasses import dataclass
from typing import Literal, TypeVar, cast

from agent.net.contract import HedgedReply

# -- events -------------------------------------------------------------------------------


@dataclass(frozen=True)
class Start:
    """The runtime declared the agent's key expressions: publish the first state."""

    now: float  #: mission time [s]


@dataclass(frozen=True)
class Tick:
    """One planner period Δt is due (figure 4.1) at mission time ``now`` [s]."""

    now: float


@dataclass(frozen=True)
class Query:
    """A trade query addressed to this agent (answered by the :class:`Reply` effect)."""

    payload: bytes
    selector: str


#: What a sample is: a peer's pose or state, or the ground station's mocap of a drone.
SampleKind = Literal["pose", "state", "mocap"]


@dataclass(frozen=True)
class Sample:
    """A publication on a key expression this agent subscribed to."""

    kind: SampleKind
    key: str
    payload: bytes


@dataclass(frozen=True)
class Liveliness:
    """A peer's liveliness token appeared (``alive``) or vanished."""

    key: str
    alive: bool


@dataclass(frozen=True)
class Answer:
    """What the tick waits on: the reply to its :class:`Ask` (None: no reply in time), the
    :class:`~agent.net.contract.HedgedReply` of an :class:`AskHedged`, the result of a
    :class:`Compute`."""

    reply: object


@dataclass(frozen=True)
class Farewell:
    """The agent leaves complete: send the final state and status again (lossy links)."""

    now: float  #: mission time [s]


Event = Start | Tick | Query | Sample | Liveliness | Answer | Farewell

# -- effects ------------------------------------------------------------------------------


@dataclass(frozen=True)
class Persist:
    """Append ``records`` to the journal (``sync``: fsync; None: the journal's default)
    before any effect after this one."""

    records: tuple[object, ...]
    sync: bool | None = None


@dataclass(frozen=True)
class Publish:
    """Publish ``payload`` on the concrete ``key``."""

    key: str
    payload: bytes


@dataclass(frozen=True)
class Reply:
    """The answer to the :class:`Query` being stepped (None: no answer)."""

    payload: bytes | None


@dataclass(frozen=True)
class Ask:
    """Query ``key`` once, waiting at most ``timeout`` real seconds; the reply payload (or
    None) comes back as an :class:`Answer`."""

    key: str
    payload: bytes
    timeout: float
    kind: str


@dataclass(frozen=True)
class AskHedged:
    """Query ``key`` with copy ``k`` (``copies[k]``) sent ``offsets[k]`` real seconds after
    the first, the first reply of any copy taken (:class:`~agent.net.contract.
    HedgingTransport`); the :class:`~agent.net.contract.HedgedReply` comes back as an
    :class:`Answer`."""

    key: str
    copies: tuple[bytes, ...]
    offsets: tuple[float, ...]
    timeout: float
    kind: str


@dataclass(frozen=True)
class Compute:
    """Call ``fn`` (a pure computation of the tick over values it was given: it reads no core
    state) outside the core; its result comes back as an :class:`Answer`."""

    fn: Callable[[], object]


@dataclass(frozen=True)
class Leave:
    """The team fenced this agent out: undeclare everything (its token goes)."""


#: What suspends the core's tick until an :class:`Answer`.
Wait = Ask | AskHedged | Compute
Effect = Persist | Publish | Reply | Ask | AskHedged | Compute | Leave

#: A part of the core that may wait: it yields :data:`Wait` effects and is sent their answers
#: (``bytes | None`` for an :class:`Ask`, :class:`~agent.net.contract.HedgedReply` for an
#: :class:`AskHedged`, the result for a :class:`Compute`), and returns ``T``.
T = TypeVar("T")
Asking = Generator[Wait, object, T]


def compute(fn: Callable[[], T]) -> Asking[T]:
    """Yield ``fn`` as a :class:`Compute`; its result."""
    got = yield Compute(fn)
    return cast(T, got)


def ask_once(key: str, payload: bytes, timeout: float, kind: str) -> Asking[bytes | None]:
    """Yield one :class:`Ask`; its reply payload (None: none in time)."""
    got = yield Ask(key, payload, timeout, kind)
    return got if isinstance(got, bytes) else None


def ask_hedged(key: str, copies: tuple[bytes, ...], offsets: tuple[float, ...], timeout: float,
               kind: str) -> Asking[HedgedReply]:
    """Yield one :class:`AskHedged`; what it got."""
    got = yield AskHedged(key, copies, offsets, timeout, kind)
    return got if isinstance(got, HedgedReply) else HedgedReply(None)
