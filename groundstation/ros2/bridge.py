"""The ROS 2 bridge of a mission: it listens like an observer and republishes what it hears as
ROS 2 topics (rmw_zenoh conventions, :class:`~groundstation.ros2.node.RosNode`) and/or into a
ROS 2 bag (:class:`~groundstation.ros2.bag.BagWriter`); what to send is decided by
:class:`~groundstation.ros2.model.MissionRos`.

It adds no load to the agents: it reads what ``viscover observe`` / ``record`` read (states,
statuses, liveliness, mocap health, commands through a
:class:`~agent.mission.watch.MissionWatch`; poses and mocap) and asks nothing. Inputs arrive
on the transport's worker thread; a timer thread sends the status (every ``status_period_s``)
and re-sends the landmarks (``landmarks_period_s``: the topics are volatile, so a late rviz
gets them within a period). ``<ns>/land`` and ``<ns>/stop`` (std_msgs/String: ``all`` or
empty for every live drone, else drone ids) become ``viscover land`` / ``stop`` commands, sent
from a thread of their own until acknowledged (:func:`agent.mission.operator.send_command`);
the outcome is logged on ``<ns>/events``. Payloads that do not decode are counted (the watch's
counter) and logged, never raised.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from collections.abc import Callable
from typing import Any

from agent.config.scenario import Scenario
from agent.mission.invariants import Claim
from agent.mission.operator import send_command
from agent.mission.watch import MissionWatch
from agent.net.contract import Declared, Transport
from agent.net.rejects import rate_limited_log
from agent.storage.events import CommandRefused, CommandSent, Event
from agent.wire import keys
from agent.wire.codec import Codec
from agent.wire.commands import CommandKind
from agent.wire.ground import MocapPose
from agent.wire.peer import AgentState, Pose, Publication
from groundstation.ros2 import rmw
from groundstation.ros2 import typesupport as ts
from groundstation.ros2.bag import BagWriter
from groundstation.ros2.messages import parse_targets
from groundstation.ros2.model import MissionRos, Out
from groundstation.ros2.names import Names
from groundstation.ros2.node import RosNode

_log = logging.getLogger(f"viscover.{__name__}")
#: the operator commands the bridge subscribes to
COMMANDS: tuple[CommandKind, ...] = ("land", "stop")


class Bridge:
    """Bridges mission ``mission`` of scenario ``sc`` heard on ``tp`` to ``node`` (None: no
    live topics) and ``bag`` (None: no bag); ``clock_ns`` stamps what arrives [ns since the
    epoch]."""

    def __init__(self, tp: Transport, sc: Scenario, mission: str, *, node: RosNode | None,
                 bag: BagWriter | None = None, names: Names | None = None,
                 scene_hz: float = 10.0, status_period_s: float = 1.0,
                 landmarks_period_s: float = 1.0, command_timeout_s: float = 10.0,
                 clock_ns: Callable[[], int] = time.time_ns) -> None:
        self.tp, self.sc, self.mission = tp, sc, mission
        self.node, self.bag, self.clock_ns = node, bag, clock_ns
        self.names = names or Names()
        self.model = MissionRos(sc, self.names, scene_hz=scene_hz)
        self.counts: dict[str, int] = {}
        self.errors = 0
        self._periods = (status_period_s, landmarks_period_s)
        self.command_timeout_s = command_timeout_s
        self._stop = threading.Event()
        self._count_lock = threading.Lock()
        self.watch = MissionWatch(tp, mission, sc, start=False)
        log = rate_limited_log(_log)
        self._c_pub: Codec[Publication] = Codec(Publication, counter=self.watch.rejects, log=log)
        self._c_mocap: Codec[MocapPose] = Codec(MocapPose, counter=self.watch.rejects, log=log)
        self.watch.listeners.append(self._on_event)
        self.watch.state_listeners.append(self._on_state)
        self._orders: queue.SimpleQueue[tuple[CommandKind, str] | None] = queue.SimpleQueue()
        self._threads = [threading.Thread(target=self._timer, name="ros2-bridge-timer",
                                          daemon=True),
                         threading.Thread(target=self._commander, name="ros2-bridge-orders",
                                          daemon=True)]
        if node is not None:
            for kind in COMMANDS:
                node.subscribe(self.names.command(kind), ts.STRING, self._order_callback(kind))
            for topic, typename in self.model.topics():  # announced before the first sample
                node.publisher(topic, typename)
        self.watch.start()
        self._handles: list[Declared] = [
            tp.subscribe(keys.all_agents(mission, "pose"), self._on_pose),
            tp.subscribe(keys.all_agents(mission, "mocap"), self._on_mocap),
        ]
        for t in self._threads:
            t.start()

    # -- output ----------------------------------------------------------------------------
    def send(self, outs: list[Out]) -> None:
        """Serialise each message once; publish it and write it to the bag."""
        for o in outs:
            try:
                cdr = ts.serialize(o.msg, o.typename)
                if self.node is not None:
                    self.node.publish(o.topic, o.typename, cdr)
                if self.bag is not None:
                    self.bag.write(o.topic, o.typename, cdr, o.stamp_ns)
            except Exception:  # a closing session, a full disk: logged, the bridge goes on
                self.errors += 1
                _log.exception("ros2 bridge: could not send %s", o.topic)
                continue
            with self._count_lock:
                self.counts[o.topic] = self.counts.get(o.topic, 0) + 1

    # -- inputs ----------------------------------------------------------------------------
    def _on_pose(self, key: str, payload: bytes) -> None:
        msg = self._c_pub.decode(payload, key)
        if msg is None:
            return
        if not isinstance(msg, Pose) or keys.try_agent_of(key) != msg.sender \
                or not self._drone(msg.sender):
            self._c_pub.reject("impossible", key, "not a pose of a mission agent")
            return
        self.send(self.model.pose(msg.sender, msg.p, msg.v, self.clock_ns()))

    def _on_mocap(self, key: str, payload: bytes) -> None:
        aid = keys.try_agent_of(key)
        if aid is None or not self.model.known(aid):
            return
        msg = self._c_mocap.decode(payload, key)
        if msg is None or msg.drone != aid or len(msg.p) != 3 or len(msg.q) != 4:
            if msg is not None:
                self._c_mocap.reject("impossible", key, "not a mocap pose of this drone")
            return
        self.send(self.model.mocap(aid, msg.p, msg.q, self.clock_ns()))

    def _drone(self, aid: str) -> bool:
        """Whether ``aid`` is bridged (a drone that joined is taken in at its first state)."""
        return self.model.known(aid) or (aid in self.watch.drones and self.model.join(aid))

    def _on_state(self, st: AgentState, claims: Claim, newer: bool) -> None:
        if not newer or not self._drone(st.sender):
            return
        ns = self.clock_ns()
        out = self.model.state(st.sender, st.phase, len(claims[0]), st.vision, st.captured,
                               ns)
        ids, owner, _p, _v = self.watch.ownership()
        self.send(out + self.model.ownership(ids, owner, ns))

    def _on_event(self, ev: Event) -> None:
        self.send([self.model.event(ev, self.clock_ns())])

    # -- commands --------------------------------------------------------------------------
    def _order_callback(self, kind: CommandKind
                        ) -> Callable[[object, rmw.Attachment | None], None]:
        """The subscription callback of command ``kind``: the String queued for the
        commander thread."""

        def on_order(msg: object, _att: rmw.Attachment | None) -> None:
            self._orders.put((kind, str(getattr(msg, "data", ""))))

        return on_order

    def _targets(self, kind: CommandKind, text: str) -> list[str]:
        """The drones a command names (every live one for ``all``); unknown names logged."""
        drones = list(self.watch.drones.items())  # one atomic copy (drones only join)
        known = [a for a, _d in drones]
        live = [a for a, d in drones if d.live]
        targets, unknown = parse_targets(text, known)
        if unknown:
            self._on_event(CommandRefused(
                source="ros2", level="warning", text=f"ros2: {kind} {text!r}: "
                f"{', '.join(unknown)} not drones of mission {self.mission}", command=kind))
        return live if targets is None else targets

    def _commander(self) -> None:
        while (order := self._orders.get()) is not None:
            kind, text = order
            targets = self._targets(kind, text)
            if not targets:
                self._on_event(CommandRefused(source="ros2", level="warning", text=f"ros2: "
                                              f"{kind}: no live drone to send it to",
                                              command=kind))
                continue
            try:
                acks = send_command(self.tp, self.mission, kind, targets, sender="ros2",
                                    timeout_s=self.command_timeout_s)
            except RuntimeError:  # the transport closed meanwhile
                return
            late = sorted(a for a, t in acks.items() if t is None)
            text = f"ros2: {kind} sent to {', '.join(targets)}" + (
                f"; no acknowledgement from {', '.join(late)}" if late else "; acknowledged")
            self._on_event(CommandSent(source="ros2", level="warning" if late else "info",
                                       text=text, command=kind, targets=targets,
                                       unacknowledged=late))

    # -- periodic --------------------------------------------------------------------------
    def _timer(self) -> None:
        status_s, landmarks_s = self._periods
        next_status = next_lm = time.monotonic()
        while not self._stop.wait(max(0.0, min(next_status, next_lm) - time.monotonic())):
            now = time.monotonic()
            ns = self.clock_ns()
            try:
                if now >= next_status:
                    next_status = now + status_s
                    self.send([self.model.status(self.watch.view(), ns)])
                if now >= next_lm:
                    next_lm = now + landmarks_s
                    ids, owner, _p, _v = self.watch.ownership()
                    self.send(self.model.ownership(ids, owner, ns, force=True))
            except Exception:  # the watch closing under us: logged, tried again next period
                _log.exception("ros2 bridge: periodic messages failed")

    def summary(self) -> dict[str, Any]:
        """Messages sent per topic, payloads rejected, send errors."""
        with self._count_lock:
            counts = dict(self.counts)
        rejected = self.watch.rejects.total + self.watch.observer.snapshot().rejected
        if self.node is not None:
            rejected += self.node.rejects.total
        return {"sent": counts, "rejected": rejected, "errors": self.errors}

    def close(self) -> None:
        """Stop listening and sending (the node and bag are the caller's to close)."""
        if self._stop.is_set():
            return
        self._stop.set()
        self._orders.put(None)
        for h in self._handles:
            h.undeclare()
        self.watch.close()
        for t in self._threads:  # a command still waiting for acks is left to time out:
            t.join(timeout=1.0)    # daemon threads, and the transport refuses once closed


def rmw_summary(node: RosNode) -> str:
    """One line: the node and how its topics are keyed."""
    convention = "TypeHashNotSupported (Humble)" if node.distro == "humble" else \
        "RIHS01 type hashes (Jazzy and later)"
    return (f"node {node.namespace}/{node.name} in ROS domain {node.domain}, "
            f"{convention}, liveliness under {rmw.ADMIN_SPACE}/{node.domain}")
