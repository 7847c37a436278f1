"""An agent's end of the mission commands (:mod:`agent.wire.commands`): every copy of a
command addressed to it is acknowledged on ``viscover/<m>/command_ack/<id>``; the first one
(``stop`` overriding a pending ``land``) is kept for the process loop to obey before anything
else."""

from __future__ import annotations

import logging
import threading
import time

from agent.net.contract import Declared, Transport
from agent.net.rejects import LockedRejectCounter, rate_limited_log
from agent.wire import keys
from agent.wire.commands import ACK_CODEC, CommandAck, MissionCommand, codec_for_commands

_log = logging.getLogger(f"viscover.{__name__}")


class Orders:
    """Mission commands received by agent ``agent_id`` (see the module docstring)."""

    def __init__(self, transport: Transport, mission: str, agent_id: str) -> None:
        self.tp, self.mission, self.id = transport, mission, agent_id
        self.rejects = LockedRejectCounter()
        self.codec = codec_for_commands(self.rejects, rate_limited_log(_log))
        self._lock = threading.Lock()
        self.received: MissionCommand | None = None  #: the command to obey (None: none yet)
        self._sub: Declared = transport.subscribe(keys.command_key(mission), self._on_command)

    def _on_command(self, key: str, payload: bytes) -> None:
        cmd = self.codec.decode(payload, key)
        if cmd is None or not cmd.addresses(self.id):
            return
        with self._lock:
            if self.received is None or (cmd.command == "stop"
                                         and self.received.command != "stop"):
                self.received = cmd
        ack = CommandAck(sender=self.id, commander=cmd.sender, seq=cmd.seq, command=cmd.command)
        try:
            self.tp.publish(keys.command_ack_key(self.mission, self.id), ACK_CODEC.encode(ack),
                            kind="command")
        except RuntimeError:  # transport closing
            pass

    def reaffirm(self, repeats: int = 3, spacing_s: float = 0.05) -> None:
        """Acknowledge the obeyed command ``repeats`` more times, ``spacing_s`` [s wall]
        apart, before leaving: on a lossy link the one ack per copy received may all be
        lost once the agent is gone (its departure counts as an ack too)."""
        c = self.received
        if c is None:
            return
        ack = ACK_CODEC.encode(CommandAck(sender=self.id, commander=c.sender, seq=c.seq,
                                          command=c.command))
        for k in range(repeats):
            if k:
                time.sleep(spacing_s)
            try:
                self.tp.publish(keys.command_ack_key(self.mission, self.id), ack,
                                kind="command")
            except RuntimeError:  # transport closing
                return

    def describe(self) -> str:
        """One line: what was ordered, by whom."""
        c = self.received
        if c is None:
            return "no command"
        return f"{c.command} ordered by {c.sender} (command {c.seq})"

    def close(self) -> None:
        """Stop listening."""
        self._sub.undeclare()
