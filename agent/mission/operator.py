"""The operator's side of a mission on the mesh: who is live, mission commands sent until
every target acknowledged (``viscover land``, ``viscover stop``, ``viscover launch``), and how
the operator ended a mission (``viscover launch`` hears the commands: :func:`ordered_end`)."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterable

from agent.net.transport import Transport
from agent.storage.events import Command, Event
from agent.wire import keys
from agent.wire.commands import ACK_CODEC, COMMAND_CODEC, CommandKind, MissionCommand
from agent.wire.departure import DEPARTURE_CODEC


def live_agents(tp: Transport, mission: str, wait_s: float = 0.5) -> set[str]:
    """Ids whose liveliness token is present on the mission, as seen within ``wait_s``: on a
    Zenoh session by a liveliness query (it ends as soon as the routers answered, in
    milliseconds: an agent's start-up does not wait ``wait_s``), else by watching the tokens
    for ``wait_s``."""
    session = getattr(tp, "session", None)
    if session is not None:
        try:
            replies = session.liveliness().get(keys.all_agents(mission, "alive"),
                                               timeout=wait_s)
            return {aid for r in replies if r.ok is not None
                    and (aid := keys.try_agent_of(str(r.ok.key_expr))) is not None}
        except Exception:  # a closed or odd session: watch the tokens instead
            pass
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
    """Publish ``command`` to ``targets`` every ``period_s`` until each acknowledged (a
    CommandAck, or its departure naming this command) or ``timeout_s`` passed:
    {agent: seconds until its first acknowledgement, or None}."""
    want = sorted(set(targets))
    acks: dict[str, float | None] = dict.fromkeys(want)
    lock = threading.Lock()
    t0 = time.monotonic()
    seq = time.time_ns() // 1000 % (2**62)
    msg = MissionCommand(sender=sender, seq=seq, command=command, targets=want)

    def acknowledged(agent: str) -> None:
        with lock:
            if agent in acks and acks[agent] is None:
                acks[agent] = time.monotonic() - t0

    def on_ack(key: str, payload: bytes) -> None:
        ack = ACK_CODEC.decode(payload, key)
        if ack is not None and ack.seq == seq and ack.commander == sender and \
                keys.try_agent_of(key) == ack.sender:
            acknowledged(ack.sender)

    def on_departure(key: str, payload: bytes) -> None:
        # An agent leaving because of this very command has obeyed it (its acks may be lost).
        d = DEPARTURE_CODEC.decode(payload, key)
        if d is not None and keys.try_agent_of(key) == d.sender and \
                d.reason == f"operator_{command}" and f"(command {seq})" in d.detail:
            acknowledged(d.sender)

    sub = tp.subscribe(keys.all_agents(mission, "command_ack"), on_ack)
    gone = tp.subscribe(keys.all_agents(mission, "departure"), on_departure)
    try:
        while time.monotonic() - t0 < timeout_s:
            with lock:
                if all(v is not None for v in acks.values()):
                    break
            tp.publish(keys.command_key(mission), COMMAND_CODEC.encode(msg), kind="command")
            time.sleep(period_s)
    finally:
        sub.undeclare()
        gone.undeclare()
    with lock:
        return dict(acks)


def order_listener(orders: list[tuple[str, list[str]]]) -> Callable[[Event], None]:
    """A :class:`~agent.mission.watch.MissionWatch` listener appending (command, targets) of
    each mission command heard (its ``command`` events, once per command) to ``orders``."""

    def heard(ev: Event) -> None:
        if isinstance(ev, Command):
            orders.append((ev.command, list(ev.targets)))

    return heard


def ordered_end(orders: Iterable[tuple[str, list[str]]], ids: Iterable[str]) -> str:
    """What the operator ordered, as typed: ``land --all`` (every agent of ``ids``, or no
    target: every agent), ``stop --id B``; several commands joined by ``; `` in order."""
    everyone = set(ids)
    said: list[str] = []
    for command, targets in orders:
        who = "--all" if not targets or everyone <= set(targets) else \
            f"--id {','.join(sorted(targets))}"
        if f"{command} {who}" not in said:
            said.append(f"{command} {who}")
    return "; ".join(said)
