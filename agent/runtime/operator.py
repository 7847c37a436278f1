"""The operator's side of a mission on the mesh: who is live, and mission commands sent until
every target acknowledged (``viscover land``, ``viscover stop``, ``viscover launch``)."""

from __future__ import annotations

import threading
import time
from collections.abc import Iterable

from agent.net.transport import Transport
from agent.wire import keys
from agent.wire.commands import ACK_CODEC, COMMAND_CODEC, CommandKind, MissionCommand


def live_agents(tp: Transport, mission: str, wait_s: float = 0.5) -> set[str]:
    """Ids whose liveliness token is present on the mission, as seen within ``wait_s``."""
    live: set[str] = set()
    lock = threading.Lock()

    def join(key: str) -> None:
        aid = keys.try_agent_of(key)
        if aid is not None:
            with lock:
                live.add(aid)

    def leave(key: str) -> None:
        aid = keys.try_agent_of(key)
        if aid is not None:
            with lock:
                live.discard(aid)

    watch = tp.watch_liveliness(keys.all_agents(mission, "alive"), join, leave)
    try:
        time.sleep(wait_s)
    finally:
        watch.undeclare()
    with lock:
        return set(live)


def send_command(tp: Transport, mission: str, command: CommandKind, targets: Iterable[str],
                 *, sender: str = "operator", timeout_s: float = 10.0,
                 period_s: float = 0.2) -> dict[str, float | None]:
    """Publish ``command`` to ``targets`` every ``period_s`` until each acknowledged or
    ``timeout_s`` passed: {agent: seconds until its first acknowledgement, or None}."""
    want = sorted(set(targets))
    acks: dict[str, float | None] = dict.fromkeys(want)
    lock = threading.Lock()
    t0 = time.monotonic()
    seq = time.time_ns() // 1000 % (2**62)
    msg = MissionCommand(sender=sender, seq=seq, command=command, targets=want)

    def on_ack(key: str, payload: bytes) -> None:
        ack = ACK_CODEC.decode(payload, key)
        if ack is None or ack.seq != seq or ack.commander != sender:
            return
        if keys.try_agent_of(key) != ack.sender:
            return
        with lock:
            if ack.sender in acks and acks[ack.sender] is None:
                acks[ack.sender] = time.monotonic() - t0

    sub = tp.subscribe(keys.all_agents(mission, "command_ack"), on_ack)
    try:
        while time.monotonic() - t0 < timeout_s:
            with lock:
                if all(v is not None for v in acks.values()):
                    break
            tp.publish(keys.command_key(mission), COMMAND_CODEC.encode(msg), kind="command")
            time.sleep(period_s)
    finally:
        sub.undeclare()
    with lock:
        return dict(acks)
