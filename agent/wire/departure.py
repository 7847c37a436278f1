"""An agent's word that it leaves the mission before completing it, and why.

:class:`AgentDeparture` on ``viscover/<m>/departure/<id>``, sent a few times (lossy links) just
before the agent withdraws its liveliness token. Peers need nothing more than the token to
drop it from their partner lists; the departure tells operators, observers and recordings
*why* (a pilot took over, a failsafe, an operator's command, a failed journal, ...) and what
the agent still held, so that the mission can decide what happens to those landmarks.
"""

from __future__ import annotations

from typing import Annotated, Final, Literal

import msgspec

from agent.wire.codec import Codec, RateLimitedLogger, RejectCounter

SCHEMA: Final = 1
#: Longest free-text detail carried (longer is rejected as hostile).
MAX_DETAIL: Final = 200

#: Why an agent left. ``operator_land`` / ``operator_stop``: a mission command; ``pilot``,
#: ``failsafe``, ``link_lost``, ``disarmed``, ``battery``, ``landed``: the vehicle left our
#: control (:mod:`agent.flight.monitor`); ``mocap_lost``: the stale-mocap failsafe landed it;
#: ``flight_failure``: take-off or landing failed; ``journal_failed``: nothing more can be
#: made durable; ``timeout``: not complete in time; ``signal``: SIGINT/SIGTERM; ``fenced``:
#: the team declared this agent lost and adopted its landmarks (:mod:`agent.protocol.fencing`).
DepartureReason = Literal["operator_land", "operator_stop", "pilot", "failsafe", "link_lost",
                          "disarmed", "battery", "landed", "mocap_lost", "flight_failure",
                          "journal_failed", "timeout", "signal", "fenced"]
WireId = Annotated[str, msgspec.Meta(pattern=r"^[A-Za-z0-9_-]{1,32}$")]


class AgentDeparture(msgspec.Struct, kw_only=True, frozen=True):
    """Agent ``sender`` (incarnation ``incarnation``) leaves the mission at mission time ``t``
    [s] for ``reason`` (``detail``: one human line), holding ``owned`` landmarks."""

    sender: WireId
    incarnation: Annotated[int, msgspec.Meta(ge=0, le=1_000_000)]
    t: float
    reason: DepartureReason
    detail: Annotated[str, msgspec.Meta(max_length=MAX_DETAIL)] = ""
    owned: Annotated[int, msgspec.Meta(ge=0, le=10_000_000)] = 0
    schema: int = SCHEMA


DEPARTURE_CODEC: Codec[AgentDeparture] = Codec(AgentDeparture)


def codec_for_departures(counter: RejectCounter,
                         log: RateLimitedLogger) -> Codec[AgentDeparture]:
    """A departure codec counting and logging its rejections where the receiver wants."""
    return Codec(AgentDeparture, counter=counter, log=log)


def departure_reason_of_release(code: str) -> DepartureReason:
    """The departure reason for a vehicle monitor's release code (``Verdict.code`` of
    :mod:`agent.flight.monitor`); unknown codes are reported as ``failsafe``."""
    known: dict[str, DepartureReason] = {
        "mode_changed": "pilot", "autopilot_failsafe": "failsafe", "link_lost": "link_lost",
        "disarmed": "disarmed", "battery_critical": "battery", "landed": "landed"}
    return known.get(code, "failsafe")
