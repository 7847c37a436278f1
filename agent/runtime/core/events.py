"""What goes into an agent core and what comes out of it (the shape of raft's Step / Ready).

:meth:`agent.runtime.core.agent_core.AgentCore.step` takes one :data:`Event` and returns the
:data:`Effect` list the runtime carries out, in order: it persists every :class:`Persist`
(fsynced when asked) before it sends anything after it, publishes, returns the
:class:`Reply` to the query that caused it, and sends an :class:`Ask` (a query of ours) and
feeds its reply back as an :class:`Answer`, and runs a :class:`Compute` (a pure computation
of the tick, e.g. a planner step) outside the core and feeds its result back the same way.
Only these suspend the core's tick; queries, samples and liveliness changes are stepped
meanwhile, as they arrive (an agent answers its peers while it computes).

Time and the vehicle enter only here: every event carries the mission time ``now`` it is
stepped at, and :class:`Start` and :class:`Tick` the vehicle's :class:`Fix` (where the
runtime read it). Every action on the world leaves as an effect: a :class:`Command` of the
vehicle (a wait: the runtime executes it and answers with the vehicle's new :class:`Fix`), a
:class:`Hold`, a camera :class:`Trigger` (after the :class:`Persist` of its capture record),
a :class:`Leave`.

Pure data: no I/O here, nothing that reads a clock.
"""

from __future__ import annotations

from collections.abc import Callable, Generator
from dataclasses import dataclass
from typing import Literal, TypeVar, cast

import numpy as np
from numpy.typing import NDArray

from agent.core.tilt import TiltLimits
from agent.net.contract import HedgedReply
from agent.wire.departure import DepartureReason
from agent.wire.peer import Battery
from agent.wire.signing import Refusal

Array = NDArray[np.float64]


@dataclass(frozen=True)
class Fix:
    """The vehicle as the runtime last read it: position ``p`` (3,) [m; world ENU], unit
    camera direction ``v`` (3,) [world ENU] at mission time ``t`` [s]; its battery and its
    gimbal's tilt limits where it has them (a kinematic vehicle has neither)."""

    p: Array
    v: Array
    t: float
    battery: Battery | None = None
    tilt: TiltLimits | None = None


# -- events -------------------------------------------------------------------------------


@dataclass(frozen=True)
class Start:
    """The runtime declared the agent's key expressions: publish the first state."""

    now: float  #: mission time [s]
    fix: Fix  #: the vehicle now
    #: the vehicle's camera confirms each image (a flown drone's): an inspection's capture
    #: counts (journaled, published) only at its :class:`ImageTaken`, not at its Trigger
    camera: bool = False


@dataclass(frozen=True)
class Tick:
    """One planner period Δt is due (figure 4.1) at mission time ``now`` [s]."""

    now: float
    fix: Fix  #: the vehicle now


@dataclass(frozen=True)
class Query:
    """A trade query addressed to this agent (answered by the :class:`Reply` effect), at
    mission time ``now`` [s]. On the secured profile the runtime opened its envelope
    (:mod:`agent.wire.signed`): ``signer`` is its authenticated sender and ``payload`` the
    inner request, or ``refusal`` says why it was refused (counted by the core; a stale
    request is answered with the refusal's signed answer; ``evicted``: entries of the seal's
    bounded replay memory opening it evicted, counted)."""

    payload: bytes
    selector: str
    now: float
    signer: str | None = None
    refusal: Refusal | None = None
    evicted: int = 0


#: What a sample is: a peer's pose or state, or the ground station's mocap of a drone.
SampleKind = Literal["pose", "state", "mocap"]


@dataclass(frozen=True)
class Sample:
    """A publication on a key expression this agent subscribed to."""

    kind: SampleKind
    key: str
    payload: bytes
    now: float  #: mission time [s] it is stepped at


@dataclass(frozen=True)
class Liveliness:
    """A peer's liveliness token appeared (``alive``) or vanished."""

    key: str
    alive: bool
    now: float  #: mission time [s] it is stepped at


@dataclass(frozen=True)
class Answer:
    """What the tick waits on: the reply to its :class:`Ask` (None: no reply in time), the
    :class:`~agent.net.contract.HedgedReply` of an :class:`AskHedged`, the result of a
    :class:`Compute`, the vehicle's :class:`Fix` after a :class:`Command`), at mission time
    ``now`` [s]."""

    reply: object
    now: float
    #: the secured profile: why the runtime refused the reply's envelope (then ``reply`` is
    #: None, or a :class:`~agent.net.contract.HedgedReply` without payload)
    refusal: Refusal | None = None


@dataclass(frozen=True)
class Farewell:
    """The agent leaves complete: send the final state and status again (lossy links)."""

    now: float  #: mission time [s]


@dataclass(frozen=True)
class Depart:
    """The drone leaves the mission for ``reason`` (:data:`~agent.wire.departure.
    DepartureReason`; ``detail``: one human line): with ``hand_over_s`` > 0 (its battery
    will not last) it first hands every landmark it owns over to its peers, for at most that
    many mission seconds; then it says so on the mesh and ends with a :class:`Departed`."""

    now: float  #: mission time [s]
    reason: DepartureReason
    detail: str = ""
    hand_over_s: float = 0.0


@dataclass(frozen=True)
class ImageTaken:
    """The camera's word on the image a :class:`Trigger` asked for landmarks ``ids`` (with
    :attr:`Start.camera`): taken (``ok``: MAVLink CAMERA_IMAGE_CAPTURED with capture_result
    1, or ArduPilot's CAMERA_FEEDBACK) or not (``reason``: refused, failed, no answer after
    the retries), heard at mission time ``now`` [s]. Only a taken image makes a capture."""

    now: float
    ids: tuple[int, ...]
    ok: bool
    reason: str = ""


Event = Start | Tick | Query | Sample | Liveliness | Answer | Farewell | Depart | ImageTaken

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
class Listen:
    """Hear exactly these peers' pose streams (``viscover/<m>/pose/<id>``) from now on: the
    subscriptions the shell holds follow this set (:mod:`agent.runtime.ends.pose_interest`)."""

    peers: frozenset[str]


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
class Command:
    """Fly linear velocity ``p_dot`` (3,) [m/s; world ENU] and angular velocity ``omega``
    (3,) [rad/s; world ENU] for ``dt`` [s] (eq. 5.1; a flown vehicle: as set-points); the
    vehicle's :class:`Fix` after it comes back as an :class:`Answer`."""

    p_dot: Array
    omega: Array
    dt: float


@dataclass(frozen=True)
class Hold:
    """Hold position ``p`` (3,) [m; world ENU] and camera yaw ``yaw`` [rad, ENU, from east]
    (figure 6.2: a settled flown vehicle; a kinematic one holds by itself)."""

    p: Array
    yaw: float


@dataclass(frozen=True)
class Trigger:
    """Take one image for the capture of landmarks ``ids``: without a confirming camera its
    record was persisted by a :class:`Persist` before this effect (nothing to do for a
    kinematic vehicle); with one (:attr:`Start.camera`) the capture is journaled only once
    the camera's :class:`ImageTaken` says the image was taken."""

    ids: tuple[int, ...]


@dataclass(frozen=True)
class Departed:
    """The drone has left the mission (its departure published): ``reason``, ``detail`` (one
    line, e.g. what it handed over)."""

    reason: DepartureReason
    detail: str


@dataclass(frozen=True)
class Leave:
    """The team fenced this agent out: undeclare everything (its token goes)."""


#: What suspends the core's tick until an :class:`Answer`.
Wait = Ask | AskHedged | Compute | Command
Effect = (Persist | Publish | Listen | Reply | Ask | AskHedged | Compute | Command | Hold
          | Trigger | Departed | Leave)

#: A part of the core that may wait: it yields :data:`Wait` effects and is sent their answers
#: (``bytes | None`` for an :class:`Ask`, :class:`~agent.net.contract.HedgedReply` for an
#: :class:`AskHedged`, the result for a :class:`Compute`), and returns ``T``.
T = TypeVar("T")
Asking = Generator[Wait, object, T]


def _answer(got: object) -> Answer:
    """What a waiting part was sent: the :class:`Answer` stepped in."""
    return got if isinstance(got, Answer) else Answer(got, 0.0)


def compute(fn: Callable[[], T]) -> Asking[T]:
    """Yield ``fn`` as a :class:`Compute`; its result."""
    got = _answer((yield Compute(fn)))
    return cast(T, got.reply)


def command(p_dot: Array, omega: Array, dt: float) -> Asking[Fix | None]:
    """Yield one :class:`Command`; the vehicle's fix after it (None: the runtime has none)."""
    got = _answer((yield Command(p_dot, omega, dt)))
    return got.reply if isinstance(got.reply, Fix) else None


def ask_once(key: str, payload: bytes, timeout: float, kind: str
             ) -> Asking[bytes | Refusal | None]:
    """Yield one :class:`Ask`; its reply payload (None: none in time; a :class:`Refusal`:
    the runtime refused the reply's envelope)."""
    got = _answer((yield Ask(key, payload, timeout, kind)))
    if got.refusal is not None:
        return got.refusal
    return got.reply if isinstance(got.reply, bytes) else None


def ask_hedged(key: str, copies: tuple[bytes, ...], offsets: tuple[float, ...], timeout: float,
               kind: str) -> Asking[tuple[HedgedReply, Refusal | None]]:
    """Yield one :class:`AskHedged`; what it got, and why the runtime refused the reply's
    envelope (None: it did not)."""
    got = _answer((yield AskHedged(key, copies, offsets, timeout, kind)))
    reply = got.reply if isinstance(got.reply, HedgedReply) else HedgedReply(None)
    return reply, got.refusal
