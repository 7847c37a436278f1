"""Mission events as typed msgspec Structs: what the mission watch
(:mod:`agent.mission.watch`), the launcher and the recorder emit, what a run folder's
``events.jsonl`` holds (one JSON object a line) and what its readers (the report, the replay,
the ROS 2 bag converter) decode.

Every event has ``time`` [s since the epoch, wall; default: now], ``source`` (an agent id, or
``recorder``, ``launch``, ``observer``, ``ros2``), ``kind`` (the tag of a tagged union),
``level`` (``info``, ``warning``, ``error``) and ``text`` (one line for people), then the
kind's own fields. The recorder adds ``t`` [s since the recording started].

Versioning: ``schema`` (:data:`EVENTS_SCHEMA`) is written only when it differs from 1
(``omit_defaults``), like every other field at its default (``t`` before the recorder sets it,
a legacy ``trade``'s missing ``trade`` / ``role`` / ``n``, a ``process`` line's ``pid``), so
the lines are those the dict-based events wrote before: same keys, same meanings, and old run
folders read. Fields no default covers (``level`` included) are always written. A line with
fields this build does not know still decodes (they are ignored); a newer ``schema`` does not.

Reading (:class:`EventDecoder`, :func:`read_events`) never raises on a line: one that is not
JSON, has an unknown ``kind``, a field of the wrong type, a required field missing or another
``schema`` is counted (:class:`~agent.wire.codec.RejectCounter`), logged at most once every
10 s per reason (:class:`~agent.wire.codec.RateLimitedLogger`) and skipped.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path
from typing import Final, Literal, TypeAlias

import msgspec

from agent.wire.codec import (
    REASON_SCHEMA,
    REASON_UNDECODABLE,
    RateLimitedLogger,
    RejectCounter,
    truncate,
)
from agent.wire.commands import CommandKind

_log = logging.getLogger(f"viscover.{__name__}")

#: Schema of the events this build writes and reads.
EVENTS_SCHEMA: Final = 1
#: How much an event matters (Foxglove and ROS log levels, the report's row colours).
Level = Literal["info", "warning", "error"]
#: The two fault counters of an agent's state a ``fault`` event reports.
FaultWhat = Literal["timeouts", "rejected"]
_wall_now = time.time


class MissionEvent(msgspec.Struct, kw_only=True, frozen=True, omit_defaults=True,
                   tag_field="kind"):
    """The fields every mission event has (module docstring); a kind is a subclass."""

    time: float = msgspec.field(default_factory=_wall_now)  #: [s since the epoch, wall]
    source: str
    level: Level
    text: str
    t: float | None = None  #: [s since the recording started]; set by the recorder
    schema: int = EVENTS_SCHEMA

    @property
    def kind(self) -> str:
        """The event's kind: the tag written as ``kind``."""
        return str(type(self).__struct_config__.tag)


# -- the mission watch: states, statuses, liveliness, mocap health, commands ---------------
class FirstState(MissionEvent, tag="first_state", kw_only=True, frozen=True):
    """The first state heard of an agent."""

    incarnation: int


class Restart(MissionEvent, tag="restart", kw_only=True, frozen=True):
    """An agent's state with a new incarnation (it restarted)."""

    incarnation: int  #: the new one


class PhaseChange(MissionEvent, tag="phase", kw_only=True, frozen=True):
    """An agent's phase changed from ``previous`` to ``phase``."""

    phase: str
    previous: str


class Trade(MissionEvent, tag="trade", kw_only=True, frozen=True):
    """One side of a committed trade (:mod:`agent.mission.trade_events`): the source's
    ``count``-th trade with ``partner``; landmark ids ascending. ``trade``, ``role`` and ``n``
    are None for a state without terms (the owned sets' difference)."""

    partner: str
    count: int
    gained: list[int]
    given: list[int]
    trade: str | None = None  #: trade id
    role: Literal["initiator", "responder"] | None = None
    n: int | None = None  #: ordinal among the source's committed trades


class TradeGap(MissionEvent, tag="trade_gap", kw_only=True, frozen=True):
    """Trades that committed between two states heard but no state reported (states lost)."""

    count: int


class NoTrade(MissionEvent, tag="no_trade", kw_only=True, frozen=True):
    """Offers that moved nothing; ``count`` the agent's failed trades in all."""

    count: int


class Fault(MissionEvent, tag="fault", kw_only=True, frozen=True):
    """An agent's timeouts or rejected payloads rose; ``count`` in all."""

    what: FaultWhat
    count: int


class Complete(MissionEvent, tag="complete", kw_only=True, frozen=True):
    """An agent's state says it sees the mission complete."""


class MissionComplete(MissionEvent, tag="mission_complete", kw_only=True, frozen=True):
    """An agent's mission status changed its view of completion."""

    complete: bool


class Join(MissionEvent, tag="join", kw_only=True, frozen=True):
    """An agent's liveliness token appeared."""


class Leave(MissionEvent, tag="leave", kw_only=True, frozen=True):
    """An agent's liveliness token went away."""


class MocapHealth(MissionEvent, tag="mocap", kw_only=True, frozen=True):
    """A drone's motion-capture rigid body changed state: ``ok``, ``stale`` or ``missing``."""

    state: str


class Command(MissionEvent, tag="command", kw_only=True, frozen=True):
    """A mission command heard (once per sender and ``seq``); ``targets`` empty: everyone."""

    command: CommandKind
    targets: list[str]
    seq: int


class Ack(MissionEvent, tag="ack", kw_only=True, frozen=True):
    """An agent acknowledged command ``seq`` of ``commander``."""

    command: CommandKind
    commander: str
    seq: int


class Violation(MissionEvent, tag="violation", kw_only=True, frozen=True):
    """An invariant violation the observer found (:mod:`agent.mission.invariants`)."""


# -- the launcher and the processes' output lines (:func:`agent.mission.recorder.line_event`) --
class Process(MissionEvent, tag="process", kw_only=True, frozen=True):
    """A process started (``pid``), or a ``viscover:`` line it printed (no ``pid``)."""

    pid: int | None = None


class Crash(MissionEvent, tag="crash", kw_only=True, frozen=True):
    """An agent process exited with ``status`` and was restarted with its journal."""

    status: int


class Exited(MissionEvent, tag="exit", kw_only=True, frozen=True):
    """An agent process exited with ``status`` (not restarted)."""

    status: int


class LaunchEnd(MissionEvent, tag="launch_end", kw_only=True, frozen=True):
    """``viscover launch`` ended with exit ``status``."""

    status: int


class Flight(MissionEvent, tag="flight", kw_only=True, frozen=True):
    """A flying agent's phase line (armed, took off, landing, ...)."""


class Failsafe(MissionEvent, tag="failsafe", kw_only=True, frozen=True):
    """A failsafe line of a flying agent (mocap lost or stale, left the mission, ...)."""


class ProcessError(MissionEvent, tag="error", kw_only=True, frozen=True):
    """A ``viscover: error:`` line of a process."""


class LogLine(MissionEvent, tag="log", kw_only=True, frozen=True):
    """A WARNING or ERROR log line of a process."""


# -- the recorder ---------------------------------------------------------------------------
class Recording(MissionEvent, tag="recording", kw_only=True, frozen=True):
    """The recording started, into the MCAP file ``path``."""

    path: str


class RecordingEnd(MissionEvent, tag="recording_end", kw_only=True, frozen=True):
    """The recording ended: messages written per MCAP topic, payloads rejected."""

    messages: dict[str, int]
    rejected: int


# -- the ROS 2 bridge (its ``<ns>/events`` topic) ------------------------------------------
class CommandRefused(MissionEvent, tag="command_refused", kw_only=True, frozen=True):
    """A ROS 2 land / stop the bridge did not send (unknown drones, or none live)."""

    command: CommandKind


class CommandSent(MissionEvent, tag="command_sent", kw_only=True, frozen=True):
    """A ROS 2 land / stop sent to ``targets``; ``unacknowledged`` never acknowledged it."""

    command: CommandKind
    targets: list[str]
    unacknowledged: list[str]


class Capture(MissionEvent, tag="capture", kw_only=True, frozen=True):
    """An inspection's team captured set grew: the new ``landmarks`` (ids ascending),
    ``captured`` of ``total`` now."""

    landmarks: list[int]
    captured: int
    total: int


#: Any mission event (decode with :class:`EventDecoder`).
Event: TypeAlias = (
    FirstState | Restart | PhaseChange | Trade | TradeGap | NoTrade | Fault | Complete
    | MissionComplete | Join | Leave | MocapHealth | Command | Ack | Violation | Process
    | Crash | Exited | LaunchEnd | Flight | Failsafe | ProcessError | LogLine | Recording
    | RecordingEnd | CommandRefused | CommandSent | Capture)
#: Every kind's Struct, in the order of :data:`Event`.
EVENT_TYPES: Final[tuple[type[MissionEvent], ...]] = (
    FirstState, Restart, PhaseChange, Trade, TradeGap, NoTrade, Fault, Complete,
    MissionComplete, Join, Leave, MocapHealth, Command, Ack, Violation, Process, Crash,
    Exited, LaunchEnd, Flight, Failsafe, ProcessError, LogLine, Recording, RecordingEnd,
    CommandRefused, CommandSent, Capture)

_encoder = msgspec.json.Encoder()


def encode_event(ev: MissionEvent) -> bytes:
    """One event as a JSON object (a line of ``events.jsonl`` without its newline)."""
    return _encoder.encode(ev)


class EventDecoder:
    """Decodes lines of ``events.jsonl``; a line that does not decode is counted in
    ``counter``, logged through ``log`` (rate-limited) and returned as None, never raised."""

    def __init__(self, counter: RejectCounter | None = None,
                 log: RateLimitedLogger | None = None) -> None:
        self.counter = counter if counter is not None else RejectCounter()
        self.log = log if log is not None else RateLimitedLogger(_log)
        self._decoder: msgspec.json.Decoder[Event] = msgspec.json.Decoder(Event)

    def reject(self, reason: str, where: str, detail: str) -> None:
        """Count (under ``where``) and log, rate-limited, one line skipped for ``reason``."""
        self.counter.add(reason, truncate(where))
        self.log.log(reason, f"skipped an event line of {truncate(where) or '<unknown>'}: "
                             f"{truncate(detail)}")

    def decode(self, line: bytes | str, where: str = "", n: int = 0) -> Event | None:
        """The event of line ``n`` (0: unnumbered) of ``where`` (a file, a topic), or None."""
        at = f"line {n}: " if n else ""
        try:
            ev = self._decoder.decode(line)
        except msgspec.DecodeError as exc:  # not JSON, or not an event (ValidationError)
            self.reject(REASON_UNDECODABLE, where, f"{at}{exc}")
            return None
        if ev.schema != EVENTS_SCHEMA:
            self.reject(REASON_SCHEMA, where,
                        f"{at}schema {ev.schema}, expected {EVENTS_SCHEMA}")
            return None
        return ev


def read_events(path: Path, decoder: EventDecoder | None = None) -> list[Event]:
    """The events of an ``events.jsonl`` (none if there is no such file); lines that do not
    decode (a torn last line, another build's) are skipped and counted in ``decoder``."""
    if not path.is_file():
        return []
    dec = decoder if decoder is not None else EventDecoder()
    out: list[Event] = []
    for n, line in enumerate(path.read_bytes().splitlines(), 1):
        if line.strip() and (ev := dec.decode(line, str(path), n)) is not None:
            out.append(ev)
    return out
