"""Mission commands: what an operator tells the agents (``viscover land``, ``viscover stop``),
and the agents' acknowledgements.

* :class:`MissionCommand` on ``viscover/<m>/command``: ``land`` (an orderly end: leave the
  mission; a flying agent flies home, as after completion, and lands; a kinematic one exits)
  or ``stop`` (emergency: leave at once; a flying agent stops commanding and has the flight
  controller land where it is, in its own LAND mode), for every agent (``targets`` empty) or
  the listed ones. ``seq`` numbers one command of one ``sender``; the sender repeats it until
  every target acknowledged (lossy links). Either way the agent announces its departure
  (:mod:`agent.wire.departure`).
* :class:`CommandAck` on ``viscover/<m>/command_ack/<id>``: agent ``sender`` received
  command (``commander``, ``seq``); repeated for each copy it receives.
"""

from __future__ import annotations

from typing import Annotated, Final, Literal

import msgspec

from agent.wire.codec import Codec, RateLimitedLogger, RejectCounter

SCHEMA: Final = 1
#: Largest number of targets one command may list (more is rejected as hostile).
MAX_TARGETS: Final = 256

CommandKind = Literal["land", "stop"]
#: An agent or operator id as on the wire: the key-segment rule of :mod:`agent.wire.keys`.
WireId = Annotated[str, msgspec.Meta(pattern=r"^[A-Za-z0-9_-]{1,32}$")]
Seq = Annotated[int, msgspec.Meta(ge=0, lt=2**62)]


class MissionCommand(msgspec.Struct, kw_only=True):
    """An operator's command to the agents (see the module docstring)."""

    sender: WireId = "operator"
    seq: Seq
    command: CommandKind
    targets: Annotated[list[WireId], msgspec.Meta(max_length=MAX_TARGETS)] = \
        msgspec.field(default_factory=list)
    schema: int = SCHEMA

    def addresses(self, agent_id: str) -> bool:
        """Whether this command is for ``agent_id``."""
        return not self.targets or agent_id in self.targets


class CommandAck(msgspec.Struct, kw_only=True):
    """Agent ``sender`` received command ``seq`` of ``commander`` and obeys it."""

    sender: WireId
    commander: WireId
    seq: Seq
    command: CommandKind
    schema: int = SCHEMA


COMMAND_CODEC: Codec[MissionCommand] = Codec(MissionCommand)
ACK_CODEC: Codec[CommandAck] = Codec(CommandAck)


def codec_for_commands(counter: RejectCounter, log: RateLimitedLogger) -> Codec[MissionCommand]:
    """A command codec counting and logging its rejections where the receiver wants."""
    return Codec(MissionCommand, counter=counter, log=log)
