"""What is happening on a mission, from any machine of the mesh: the
:class:`~agent.mission.observer.Observer` (invariants, completion, one process per id) plus
liveliness, motion-capture health and mission commands, turned into

* **events** (typed Structs of :mod:`agent.storage.events`: ``time`` [s since the epoch],
  ``source``, ``kind``, ``level``, ``text`` and the kind's fields) handed to every listener:
  from an agent's successive states ``first_state``, ``restart``, ``phase``, ``trade``,
  ``trade_gap``, ``no_trade``, ``fault`` (timeouts, rejected payloads) and ``complete``
  (:func:`~agent.mission.trade_events.state_events`), then ``mission_complete``, ``join``,
  ``leave``, ``mocap``, ``command``, ``ack``, ``violation``;
* a **view** (:class:`MissionView`) for ``viscover status``: per drone (the scenario's, then
  drones that joined) its phase (``fenced`` once the team declared it lost; the stage of the
  coverage moves, and whether it reverts), landmarks, vision, trades, link health and how long
  ago its last state was heard, mocap health, battery and last fault; coverage, landmarks
  seen / not seen by their owner, orphaned landmarks and fenced drones, elapsed time; and
  whether the mesh is gone: the session lost its router and peers (asked of the Zenoh session,
  :func:`session_probe`), or, where that cannot be asked, nothing was heard for
  :data:`MESH_GONE_S`. Times come from one :class:`~agent.clock.Clock` (wall time by default).

Payloads that do not decode are counted (``rejected``), never raised. Not split: events,
view and mesh health read one lock-guarded record of the drones, fed by one set of
subscriptions (the rendering is :mod:`~.status`'s).
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from agent.clock import Clock, WallClock
from agent.config.scenario import Scenario
from agent.mission.invariants import Claim
from agent.mission.observer import Observer, fence_keys
from agent.mission.trade_events import state_events
from agent.net.contract import Declared, Transport
from agent.net.rejects import LockedRejectCounter, rate_limited_log
from agent.protocol.captures import captured_count
from agent.storage.events import (
    Ack,
    Command,
    Event,
    Join,
    Leave,
    MissionComplete,
    MocapHealth,
    Violation,
)
from agent.storage.recording import owner_index, seen_by_owner
from agent.wire import keys
from agent.wire.codec import Codec
from agent.wire.commands import CommandAck, MissionCommand
from agent.wire.ground import MocapStatus
from agent.wire.peer import AgentState, Battery, MissionStatus

_log = logging.getLogger(f"viscover.{__name__}")
#: a drone whose last state is older than this [s wall] has a stale link
STALE_S = 3.0
#: a drone not heard this long [s wall] after the watch began (or after :meth:`MissionWatch.
#: expect`, when its process was started) is "never heard"; until then "not heard yet": an
#: agent process needs a few seconds to load, reach the router and publish its first state
HEARD_WITHIN_S = 15.0
#: nothing heard on the mission for longer than this [s wall]: the mesh is gone (a session
#: that cannot be asked for its router), or quiet (its router still answers)
MESH_GONE_S = 10.0


def session_probe(tp: Transport) -> Callable[[], bool] | None:
    """Whether the Zenoh session of ``tp`` has a router or a peer right now (None: a transport
    that cannot tell, e.g. in memory); a closed session has none."""
    info = getattr(getattr(tp, "session", None), "info", None)
    if info is None:
        return None

    def linked() -> bool:
        try:
            return bool(info.routers_zid()) or bool(info.peers_zid())
        except Exception:  # the session is closing
            return False

    return linked


@dataclass
class Drone:
    """What is known of one drone (times [s] from the watch's clock)."""

    state: AgentState | None = None
    owned: set[int] = field(default_factory=set)
    last_seen: float | None = None
    live: bool | None = None  #: liveliness token present (None: never seen)
    mocap: str | None = None  #: ok / stale / missing (None: no ground station)
    fault: str = ""  #: the last fault, failsafe or violation, in a few words


@dataclass(frozen=True)
class DroneRow:
    """One line of ``viscover status``."""

    id: str
    phase: str
    owned: int
    vision: float
    trades: str  #: successful / failed
    link: str  #: ok, stale, left, not heard yet, never heard, token, no state
    heard: str  #: age of its last state: "3.2 s ago" ("-": never)
    mocap: str
    fault: str
    done: bool
    battery: Battery | None = None  #: a flying agent's, as it published it (None: no battery)


@dataclass(frozen=True)
class MissionView:
    """The mission at one instant: drones, coverage, landmarks seen by their owner."""

    mission: str
    rows: list[DroneRow]
    coverage: float
    seen: int
    not_seen: int
    unowned: int
    elapsed_s: float  #: wall seconds since the first state heard (0: none yet)
    mission_t: float  #: the latest mission time published [s]
    complete: bool
    violations: list[str]
    rejected: int
    fenced: list[str] = field(default_factory=list)  #: drones the team declared lost
    orphaned: int = 0  #: landmarks a fenced drone held that nobody owns yet
    mesh_gone_s: float | None = None  #: the mesh is gone: seconds since it was last heard
    mesh: str = ""  #: one line when the mesh is gone or quiet (empty: nothing to say)
    captured: int | None = None  #: inspection missions: landmarks captured (drones' union)
    #: the coverage when the mission completed, and the mission time t then [s] (None: not
    #: complete); ``coverage`` is now's (a flown mission goes on home)
    coverage_complete: float | None = None
    complete_t: float | None = None
    #: an inspection that ended: how (``complete at t = X s`` or ``INCOMPLETE: G given up
    #: (...)``, agent.protocol.inspection_end); empty before it ended, and for coverage
    verdict: str = ""
    #: inspection missions: the peers' capture claims the drones refused, together
    refused_claims: int = 0


class MissionWatch:
    """Observer, liveliness, mocap health and commands of one mission (module docstring)."""

    def __init__(self, tp: Transport, mission: str, sc: Scenario, *, start: bool = True,
                 clock: Clock | None = None, tls_dir: str | None = None,
                 linked: Callable[[], bool] | None = None) -> None:
        """``clock``: time of links and view (default: wall); ``linked``: whether the session has
        its router or peers now (default :func:`session_probe`); ``tls_dir``: :func:`fence_keys`."""
        self.tp, self.mission, self.sc, self.tls = tp, mission, sc, tls_dir
        self.clock: Clock = clock if clock is not None else WallClock()
        self.linked = linked if linked is not None else session_probe(tp)
        self.ids = [a.id for a in sc.agents]
        self._lm_ids = np.asarray(sc.landmark_ids, dtype=np.int64)
        self.rejects = LockedRejectCounter()
        log = rate_limited_log(_log)
        self._c_mocap: Codec[MocapStatus] = Codec(MocapStatus, counter=self.rejects, log=log)
        self._c_cmd: Codec[MissionCommand] = Codec(MissionCommand, counter=self.rejects, log=log)
        self._c_ack: Codec[CommandAck] = Codec(CommandAck, counter=self.rejects, log=log)
        self.drones = {a: Drone() for a in self.ids}
        #: called with each event (see the module docstring)
        self.listeners: list[Callable[[Event], None]] = []
        #: called with (state, (owned, held), newest so far) after the watch took it in
        self.state_listeners: list[Callable[[AgentState, Claim, bool], None]] = []
        self._lock = threading.Lock()
        self._first: float | None = None
        self._heard: float | None = None  #: when anything of the mission last arrived
        self._linked_at = self.clock.now()  #: when the session last had a router or peer
        #: since when each drone could have been heard (:meth:`expect`; default: the start)
        self._expected: dict[str, float] = {}
        self._began = self._linked_at
        self._seen_cmds: set[tuple[str, ...]] = set()
        self._status: dict[str, bool] = {}
        self._violations = 0
        self._handles: list[Declared] = []
        if start:
            self.start()

    def start(self) -> None:
        """Create the observer and subscribe (after the listeners are in place)."""
        self.observer = Observer(self.tp, self.mission, self.ids, list(self.sc.landmark_ids),
                                 fence_keys=fence_keys(self.tls), initial=self.sc.initial_sets(),
                                 on_state=[self._on_state], on_status=[self._on_status])
        m, tp = self.mission, self.tp
        self._handles = [
            tp.watch_liveliness(keys.all_agents(m, "alive"), self._join, self._leave),
            tp.subscribe(keys.all_agents(m, "mocap_status"), self._on_mocap),
            tp.subscribe(keys.command_key(m), self._on_command),
            tp.subscribe(keys.all_agents(m, "command_ack"), self._on_ack),
        ]

    def close(self) -> None:
        """Undeclare every subscription (the observer's too)."""
        for h in self._handles:
            h.undeclare()
        if hasattr(self, "observer"):
            self.observer.close()

    def emit(self, ev: Event) -> None:
        """Hand one event to every listener (a failing listener is logged, not raised)."""
        src = ev.source
        if ev.level != "info" and src in self.drones:
            self.drones[src].fault = ev.text.removeprefix(f"agent {src}: ").removeprefix(
                f"{src}: ")
        for fn in list(self.listeners):
            try:
                fn(ev)
            except Exception:
                _log.exception("event listener failed")

    # -- inputs ----------------------------------------------------------------------------
    def _on_state(self, st: AgentState, claims: Claim, newer: bool) -> None:
        """A state the observer accepted: link time, events against the previous one."""
        now = self._hear()
        with self._lock:
            if st.sender not in self.drones:  # a drone that joined the mission
                self.ids.append(st.sender)
                self.drones[st.sender] = Drone()
            d = self.drones[st.sender]
            self._first = now if self._first is None else self._first
            d.last_seen = now
            prev, prev_owned, owned = d.state, d.owned, set(claims[0])
            if newer:
                d.state, d.owned = st, owned
            viol = self.observer.report.violations
            fresh, self._violations = viol[self._violations:], len(viol)
        for ev in state_events(prev, prev_owned, st, owned) if newer else []:
            self.emit(ev)
        for v in fresh:
            who = v.split()[1].rstrip(":") if v.startswith("agent ") else "observer"
            self.emit(Violation(source=who, level="error", text=v))
        for fn in list(self.state_listeners):
            fn(st, claims, newer)

    def _hear(self) -> float:
        """Something of the mission arrived now: the time [s]."""
        now = self._heard = self.clock.now()
        return now

    def _on_status(self, msg: MissionStatus) -> None:
        """A mission status: an event when an agent's view of completion changes."""
        self._hear()
        if self._status.get(msg.sender) == msg.complete:
            return
        self._status[msg.sender] = msg.complete
        word = "complete" if msg.complete else "no longer complete"
        self.emit(MissionComplete(source=msg.sender, level="info", text=f"{msg.sender}: "
                                  f"mission {word} (coverage {msg.coverage:.4g})",
                                  complete=msg.complete))

    def _join(self, key: str) -> None:
        self._liveliness(key, True)

    def _leave(self, key: str) -> None:
        self._liveliness(key, False)

    def _liveliness(self, key: str, live: bool) -> None:
        """A liveliness token came or went: the drone's link and an event."""
        aid = keys.try_agent_of(key)
        if aid not in self.drones:
            return
        if live:
            self._hear()
        d = self.drones[aid]
        d.live = live
        done = d.state is not None and d.state.complete
        if live:
            self.emit(Join(source=aid, level="info", text=f"{aid}: joined the mission"))
        else:
            self.emit(Leave(source=aid, level="info" if done else "warning",
                            text=f"{aid}: left the mission"))

    def _on_mocap(self, key: str, payload: bytes) -> None:
        """A mocap health message: an event when a drone's rigid body changes state."""
        msg = self._c_mocap.decode(payload, key)
        if msg is None or msg.drone not in self.drones or keys.try_agent_of(key) != msg.drone:
            return
        self._hear()
        d = self.drones[msg.drone]
        if d.mocap != msg.state:
            d.mocap = msg.state
            self.emit(MocapHealth(source=msg.drone, level="info" if msg.state == "ok" else
                                  "warning", text=f"{msg.drone}: mocap {msg.state}",
                                  state=msg.state))

    def _on_command(self, key: str, payload: bytes) -> None:
        """A mission command: one event per (sender, seq), however often it is repeated."""
        cmd = self._c_cmd.decode(payload, key)
        if cmd is not None:
            self._hear()
        if cmd is None or ("cmd", cmd.sender, str(cmd.seq)) in self._seen_cmds:
            return
        self._seen_cmds.add(("cmd", cmd.sender, str(cmd.seq)))
        to = ", ".join(cmd.targets) or "every agent"
        self.emit(Command(source=cmd.sender, level="warning", text=f"{cmd.sender}: "
                          f"{cmd.command} to {to}", command=cmd.command,
                          targets=list(cmd.targets), seq=cmd.seq))

    def _on_ack(self, key: str, payload: bytes) -> None:
        """An agent's acknowledgement: one event per (agent, commander, seq)."""
        ack = self._c_ack.decode(payload, key)
        mark = ("ack", "" if ack is None else ack.sender, "" if ack is None else ack.commander,
                "" if ack is None else str(ack.seq))
        if ack is None or keys.try_agent_of(key) != ack.sender or mark in self._seen_cmds:
            return
        self._seen_cmds.add(mark)
        self.emit(Ack(source=ack.sender, level="info", text=f"{ack.sender}: obeys "
                      f"{ack.command} of {ack.commander}", command=ack.command,
                      commander=ack.commander, seq=ack.seq))

    # -- the view --------------------------------------------------------------------------
    def ownership(self) -> tuple[list[str], np.ndarray, np.ndarray, np.ndarray]:
        """At one instant: the drones (the scenario's, then those that joined), the row among
        them of each landmark's owner (-1: none; a fenced drone owns nothing), their positions
        (n, 3) [m; world ENU] and unit camera directions (n, 3) (a scenario drone not heard yet:
        its initial pose)."""
        fenced = set(self.observer.snapshot().fenced)
        with self._lock:
            ids = list(self.ids)
            states = [self.drones[a].state for a in ids]
            owned = [np.fromiter(() if a in fenced else self.drones[a].owned, dtype=np.int64)
                     for a in ids]
        start = {a.id: (a.p0, a.v0) for a in self.sc.agents}
        p, v = np.zeros((len(ids), 3)), np.zeros((len(ids), 3))
        for i, (a, st) in enumerate(zip(ids, states, strict=True)):
            p[i], v[i] = (st.p, st.v) if st is not None else start[a]
        return ids, owner_index(self._lm_ids, owned), p, v

    def owners(self) -> np.ndarray:
        """Row (as in :meth:`ownership`) of each landmark's current owner, -1 for none."""
        return self.ownership()[1]

    def expect(self, drone: str) -> None:
        """``drone``'s process starts now: it is "not heard yet" for :data:`HEARD_WITHIN_S`
        from now (a launcher calls this as it starts each agent)."""
        with self._lock:
            self._expected[drone] = self.clock.now()

    def _link(self, a: str, d: Drone, now: float) -> tuple[str, str]:
        """Link health in a word or two, and the age of the last state ("3.2 s ago")."""
        if d.last_seen is None:
            if d.live is not None:
                return "token, no state", "-"
            since = self._expected.get(a, self._began)
            return ("not heard yet" if now - since < HEARD_WITHIN_S else "never heard"), "-"
        age = now - d.last_seen
        health = "left" if d.live is False else "ok" if age < STALE_S else "stale"
        return health, f"{age:.1f} s ago"

    def _mesh(self, now: float) -> tuple[float | None, str]:
        """(seconds since the mesh was last heard when it is gone, else None; one line on it):
        gone once the session has no router or peer (or, where that cannot be asked, nothing
        arrived for :data:`MESH_GONE_S`); quiet when nothing arrived for that long but the
        router answers (every drone gone?)."""
        linked = None if self.linked is None else self.linked()
        if linked:
            self._linked_at = now
        heard = self._heard
        quiet = None if heard is None or now - heard <= MESH_GONE_S else now - heard
        if linked is False or (linked is None and quiet is not None):
            gone = now - max(self._linked_at, heard if heard is not None else -np.inf)
            return gone, f"mesh gone: no router/peers heard for {gone:.0f} s"
        if quiet is not None:
            return None, (f"mesh quiet: nothing heard on mission {self.mission} for "
                          f"{quiet:.0f} s (its router answers)")
        return None, ""

    def mesh_health(self) -> tuple[float | None, str]:
        """The mesh now, as :meth:`view` says it: (seconds since it was last heard when it
        is gone, else None; one line when it is gone or quiet, else "")."""
        return self._mesh(self.clock.now())

    def view(self) -> MissionView:
        """The mission now (see :class:`MissionView`)."""
        ids, owner, p, v = self.ownership()
        seen = seen_by_owner(np.asarray(self.sc.q), np.asarray(self.sc.u), owner, p, v)
        rep = self.observer.snapshot()
        scenario = {a.id for a in self.sc.agents}
        now = self.clock.now()
        gone, mesh = self._mesh(now)
        rows = []
        with self._lock:
            for a in ids:
                d, st = self.drones[a], self.drones[a].state
                phase: str = "fenced" if a in rep.fenced else "-" if st is None else st.phase
                if st is not None and st.stage > 1 and a not in rep.fenced:  # coverage moves
                    phase += f", stage {st.stage}" + (", reverting" if st.reverting else "")
                link, heard = self._link(a, d, now)
                rows.append(DroneRow(
                    id=a if a in scenario else f"{a} (joined)", phase=phase,
                    owned=0 if a in rep.fenced else len(d.owned),
                    vision=0.0 if st is None else st.vision,
                    trades="-" if st is None else f"{st.counters.ok} / {st.counters.failed}",
                    link=link, heard=heard, mocap=d.mocap or "-", fault=d.fault or "-",
                    battery=None if st is None else st.battery, done=bool(st and st.complete)))
            t = max((d.state.t for d in self.drones.values() if d.state), default=0.0)
            first = self._first
            caps = [d.state.captured for d in self.drones.values() if d.state is not None]
            refused = sum(d.state.refused_claims for d in self.drones.values() if d.state)
        captured = None if self.sc.inspection is None else captured_count(caps, self._lm_ids.size)
        return MissionView(
            mission=self.mission, rows=rows, coverage=rep.coverage, seen=int(seen.sum()),
            not_seen=int(((owner >= 0) & ~seen).sum()), unowned=int((owner < 0).sum()),
            elapsed_s=0.0 if first is None else now - first, mission_t=t,
            complete=rep.complete, violations=list(rep.violations),
            rejected=rep.rejected + self.rejects.total, fenced=sorted(rep.fenced),
            orphaned=len(rep.orphaned), mesh_gone_s=gone, mesh=mesh, captured=captured,
            coverage_complete=rep.coverage_complete, complete_t=rep.complete_t,
            verdict="" if rep.inspection is None else str(rep.inspection["verdict"]),
            refused_claims=refused)
