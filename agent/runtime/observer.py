"""Ownership invariants and the mission observer.

Pure checks (used by the tests on in-memory ledgers and by the observer on published states):

* :func:`snapshot_violations`: on a *consistent* snapshot of every agent's ledger, each
  landmark has at least one claim (owned or held) and, at its highest version, exactly one
  claimant, which holds no other claim on it.
* :class:`VersionHistory`: order-independent check over every state ever received: a
  (landmark, version) pair is created once, so it may be claimed by one agent only. A
  landmark owned by two agents, a duplicated transfer or an abort on one side and a commit
  on the other all show up here sooner or later, whatever order the states arrive in.
* :func:`final_violations`: at completion (nothing pending anywhere), every landmark is owned
  (not held) by exactly one agent at its highest version ever seen.
* :class:`IdentityWatch`: one agent id, one process. The states of one process form a
  *stream*: one incarnation, a sequence number that only grows, a mission time that never goes
  back as the sequence number grows. Two streams of one id both heard over more than
  ``grace_s`` seconds are two processes claiming that id (a restart ends the old stream first).
  Two processes of the same incarnation that publish the same sequence numbers at the same
  mission times cannot be told apart from their states (the agents' start-up check, a live
  liveliness token, refuses the second one anyway).

Published states from different agents do not form a consistent cut (a state may be late or
lost), so the observer applies the snapshot rule only at completion and counts landmarks
without a claim in between as "in flight" rather than as violations.
"""

from __future__ import annotations

import json
import logging
import sys
import threading
import time
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any, TextIO

import numpy as np

from agent.net.transport import Transport
from agent.wire import keys
from agent.wire.codec import Codec, RateLimitedLogger, RejectCounter
from agent.wire.peer import AgentState, MissionStatus, Publication, unpack

_log = logging.getLogger(f"viscover.{__name__}")

#: claims per agent: (owned {id: version}, held {id: version})
Claims = Mapping[str, tuple[Mapping[int, int], Mapping[int, int]]]
#: one agent's claims: (owned {id: version}, held {id: version})
Claim = tuple[dict[int, int], dict[int, int]]


def snapshot_violations(claims: Claims, all_ids: Iterable[int]) -> list[str]:
    """Violations of the ownership invariant in a consistent snapshot (see module doc)."""
    out: list[str] = []
    per: dict[int, list[tuple[int, str, str]]] = {}
    for agent, (owned, held) in claims.items():
        for lid, ver in owned.items():
            per.setdefault(lid, []).append((ver, agent, "owned"))
        for lid, ver in held.items():
            per.setdefault(lid, []).append((ver, agent, "held"))
    for lid in all_ids:
        cl = per.get(int(lid))
        if not cl:
            out.append(f"landmark {lid}: no claim (lost)")
            continue
        top = max(c[0] for c in cl)
        at_top = [c for c in cl if c[0] == top]
        if len(at_top) != 1:
            out.append(f"landmark {lid}: {len(at_top)} claims at version {top}: {at_top}")
        owners = [c for c in cl if c[2] == "owned"]
        if len(owners) > 1:
            out.append(f"landmark {lid}: owned by {len(owners)} agents: {owners}")
    return out


def final_violations(claims: Claims, all_ids: Iterable[int],
                     highest: Mapping[int, int] | None = None) -> list[str]:
    """At completion: exactly one owner per landmark, nothing held, highest version."""
    out = snapshot_violations(claims, all_ids)
    count: dict[int, int] = {}
    for agent, (owned, held) in claims.items():
        if held:
            out.append(f"agent {agent}: still holds {sorted(held)} at completion")
        for lid, ver in owned.items():
            count[lid] = count.get(lid, 0) + 1
            if highest is not None and ver < highest.get(lid, ver):
                out.append(f"landmark {lid}: {agent} owns stale version {ver} "
                           f"< {highest[lid]}")
    out.extend(f"landmark {lid}: {n} owners" for lid, n in count.items() if n > 1)
    return out


class VersionHistory:
    """(landmark, version) -> agent, over every claim ever seen (order independent)."""

    def __init__(self) -> None:
        self.creator: dict[tuple[int, int], str] = {}
        self.highest: dict[int, int] = {}

    def add(self, agent: str, owned: Mapping[int, int], held: Mapping[int, int]) -> list[str]:
        """Record ``agent``'s claims; return violations (a pair claimed by two agents)."""
        out: list[str] = []
        for d in (owned, held):
            for lid, ver in d.items():
                k = (lid, ver)
                prev = self.creator.setdefault(k, agent)
                if prev != agent:
                    out.append(f"landmark {lid} version {ver} claimed by {prev} and {agent}")
                if ver > self.highest.get(lid, -1):
                    self.highest[lid] = ver
        return out


@dataclass
class _Stream:
    """One process's states under an agent id: incarnation, wall times first/last heard [s]
    and the mission time t [s] of its recent sequence numbers."""

    number: int  #: serial number among every stream seen
    incarnation: int
    first: float
    last: float
    times: dict[int, float] = field(default_factory=dict)

    def fits(self, seq: int, t: float, window: int) -> bool:
        """Whether (seq, mission t [s]) continues this stream: near its newest, t monotone."""
        if not self.times or seq <= max(self.times) - window:
            return False
        if seq in self.times:
            return abs(self.times[seq] - t) <= _T_EPS
        below = [s for s in self.times if s < seq]
        above = [s for s in self.times if s > seq]
        return (not below or t >= self.times[max(below)] - _T_EPS) and \
            (not above or t <= self.times[min(above)] + _T_EPS)

    def add(self, seq: int, t: float, now: float, window: int) -> None:
        """Record (seq, t) heard at wall time ``now`` [s]; keep the newest ``window`` seqs."""
        self.times[seq] = t
        self.last = max(self.last, now)
        if len(self.times) > window:
            del self.times[min(self.times)]


#: Mission-time tolerance [s] when matching a state to a stream (one process's t is exact).
_T_EPS = 1e-6


class IdentityWatch:
    """Two processes publishing states under one agent id (see the module docstring)."""

    def __init__(self, grace_s: float = 2.0, window: int = 64, max_streams: int = 8) -> None:
        self.grace_s, self.window, self.max_streams = grace_s, window, max_streams
        self.streams: dict[str, list[_Stream]] = {}
        self._reported: set[tuple[str, int, int]] = set()
        self._count = 0

    def add(self, agent: str, incarnation: int, seq: int, t: float, now: float) -> list[str]:
        """Record a state heard at wall time ``now`` [s]; violations: a second process."""
        streams = self.streams.setdefault(agent, [])
        fit = [s for s in streams if s.incarnation == incarnation
               and s.fits(seq, t, self.window)]
        if fit:
            mine = min(fit, key=lambda s: abs(seq - max(s.times)))
        else:
            self._count += 1
            mine = _Stream(self._count, incarnation, now, now)
            streams.append(mine)
            if len(streams) > self.max_streams:
                streams.remove(min(streams, key=lambda s: s.last))
        mine.add(seq, t, now, self.window)
        out = []
        for other in streams:
            overlap = min(mine.last, other.last) - max(mine.first, other.first)
            key = (agent, min(mine.number, other.number), max(mine.number, other.number))
            if other is mine or overlap <= self.grace_s or key in self._reported:
                continue
            self._reported.add(key)
            out.append(f"agent {agent}: two processes claim this id (incarnations "
                       f"{other.incarnation} and {mine.incarnation} both publishing for "
                       f"{overlap:.1f} s)")
        return out


def coverage_of(states: Mapping[str, AgentState]) -> float:
    """Coverage score (eq. 3.10) as the sum of the agents' published visions."""
    return float(sum(st.vision for st in states.values()))


@dataclass
class ObserverReport:
    """What the observer saw."""

    violations: list[str] = field(default_factory=list)
    states_seen: int = 0
    rejected: int = 0
    complete: bool = False
    complete_at_s: float | None = None
    coverage: float = 0.0
    coverage_initial: float | None = None
    in_flight_max: int = 0
    agents: dict[str, dict[str, Any]] = field(default_factory=dict)
    owners: dict[int, str] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        """A JSON-able dict."""
        return {
            "violations": self.violations,
            "states_seen": self.states_seen,
            "rejected": self.rejected,
            "complete": self.complete,
            "complete_at_s": self.complete_at_s,
            "coverage": self.coverage,
            "coverage_initial": self.coverage_initial,
            "in_flight_max": self.in_flight_max,
            "agents": self.agents,
            "owners": {str(k): v for k, v in sorted(self.owners.items())},
        }


class Observer:
    """Subscribes to every agent's state and status, checks the invariants on each state.

    Completion: every scenario agent's latest state has ``complete`` set, with nothing pending
    and consistent per-pair trade counts; then :func:`final_violations` is applied.
    """

    def __init__(self, transport: Transport, mission: str, agent_ids: list[str],
                 landmark_ids: list[int], *, now: Callable[[], float] = time.monotonic,
                 on_state: Iterable[Callable[[AgentState, Claim, bool], None]] = (),
                 on_status: Iterable[Callable[[MissionStatus], None]] = ()) -> None:
        self.tp = transport
        self.mission = mission
        self.agent_ids = list(agent_ids)
        self.all_ids = [int(x) for x in landmark_ids]
        self._known = np.unique(np.asarray(self.all_ids, dtype=np.int64))
        self.rejects = RejectCounter()
        self.codec: Codec[Publication] = Codec(
            Publication, counter=self.rejects, log=RateLimitedLogger(_log))
        self.latest: dict[str, AgentState] = {}
        self.latest_claims: dict[str, tuple[dict[int, int], dict[int, int]]] = {}
        self.history = VersionHistory()
        self.identity = IdentityWatch()
        self.report = ObserverReport()
        self._now = now
        #: called with (state, (owned, held), newest so far) after each accepted state, on the
        #: transport's thread, outside the lock (:class:`~agent.runtime.watch.MissionWatch`)
        self.on_state: list[Callable[[AgentState, Claim, bool], None]] = list(on_state)
        #: called with each mission status received
        self.on_status: list[Callable[[MissionStatus], None]] = list(on_status)
        self._lock = threading.Lock()
        self._t0 = now()
        self.done = threading.Event()
        self._handles = [
            transport.subscribe(keys.all_agents(mission, "state"), self._on_state),
            transport.subscribe(keys.all_agents(mission, "status"), self._on_status),
        ]

    def close(self) -> None:
        """Undeclare the subscriptions."""
        for h in self._handles:
            h.undeclare()

    def _claims(self, key: str, st: AgentState) -> tuple[dict[int, int], dict[int, int]] | None:
        """The state's (owned, held) as dicts, or None (counted) if it is not acceptable."""
        if keys.try_agent_of(key) != st.sender or st.sender not in self.agent_ids:
            self.codec.reject("sender", key, f"sender {st.sender!r}")
            return None
        owned, held = unpack(st.owned), unpack(st.held)
        if owned is None or held is None or not all(
                np.isin(ids, self._known).all() for ids in (owned[0], held[0])):
            self.codec.reject("impossible", key, "malformed set or unknown landmark")
            return None
        return (dict(zip(owned[0].tolist(), owned[1].tolist(), strict=True)),
                dict(zip(held[0].tolist(), held[1].tolist(), strict=True)))

    def _on_status(self, key: str, payload: bytes) -> None:
        """A mission status of the agent its key names, handed to the listeners."""
        msg = self.codec.decode(payload, key)
        if msg is None:
            return
        if not isinstance(msg, MissionStatus) or keys.try_agent_of(key) != msg.sender:
            self.codec.reject("impossible", key, "not a status message of this agent")
            return
        for fn in self.on_status:
            fn(msg)

    def _on_state(self, key: str, payload: bytes) -> None:
        """A state: invariants, identity, the latest per agent, then the listeners."""
        msg = self.codec.decode(payload, key)
        if msg is None:
            return
        if not isinstance(msg, AgentState):
            self.codec.reject("impossible", key, "not a state message")
            return
        claims = self._claims(key, msg)
        if claims is None:
            return
        with self._lock:
            rep = self.report
            rep.states_seen += 1
            rep.violations.extend(self.history.add(msg.sender, *claims))
            rep.violations.extend(self.identity.add(msg.sender, msg.incarnation, msg.seq,
                                                    msg.t, self._now()))
            prev = self.latest.get(msg.sender)
            newer = prev is None or (prev.incarnation, prev.seq) < (msg.incarnation, msg.seq)
            if newer:
                self._accept(msg, claims)
        for fn in self.on_state:
            fn(msg, claims, newer)

    def _accept(self, msg: AgentState, claims: tuple[dict[int, int], dict[int, int]]) -> None:
        """Make ``msg`` the sender's latest state (under the lock): coverage, completion."""
        rep = self.report
        self.latest[msg.sender] = msg
        self.latest_claims[msg.sender] = claims
        claimed: set[int] = set()
        for owned, held in self.latest_claims.values():
            claimed.update(owned)
            claimed.update(held)
        rep.in_flight_max = max(rep.in_flight_max, len(self.all_ids) - len(claimed))
        rep.coverage = coverage_of(self.latest)
        if rep.coverage_initial is None and len(self.latest) == len(self.agent_ids):
            rep.coverage_initial = rep.coverage
        self._check_complete()

    def _check_complete(self) -> None:
        if self.report.complete or set(self.latest) != set(self.agent_ids):
            return
        sts = self.latest
        for a, st in sts.items():
            if not st.complete or st.pending or st.partners or st.phase != "converged":
                return
            for b, n in st.trades_with.items():
                if b in sts and sts[b].trades_with.get(a, 0) != n:
                    return
        claims = dict(self.latest_claims)
        rep = self.report
        rep.violations.extend(final_violations(claims, self.all_ids, self.history.highest))
        rep.complete = True
        rep.complete_at_s = time.monotonic() - self._t0
        rep.owners = {lid: a for a, (owned, _h) in claims.items() for lid in owned}
        rep.agents = {
            a: {"vision": st.vision, "owned": sorted(claims[a][0]), "ok": st.counters.ok,
                "failed": st.counters.failed, "busy": st.counters.busy,
                "timeouts": st.counters.timeouts, "rejected": st.counters.rejected,
                "p": list(st.p), "v": list(st.v)}
            for a, st in sorted(sts.items())
        }
        self.done.set()

    def snapshot(self) -> ObserverReport:
        """The report so far (``rejected`` updated)."""
        with self._lock:
            self.report.rejected = self.rejects.total
            return self.report


def print_report(rep: ObserverReport, out: TextIO | None = None) -> None:
    """Human summary: violations, coverage, completion."""
    out = out or sys.stdout
    for v in rep.violations:
        print(f"VIOLATION {v}", file=out)
    init = "?" if rep.coverage_initial is None else f"{rep.coverage_initial:.4g}"
    done = (f"complete after {rep.complete_at_s:.1f} s" if rep.complete
            else "NOT complete")
    print(f"states {rep.states_seen}, rejected {rep.rejected}, coverage {init} -> "
          f"{rep.coverage:.4g}, {done}, violations {len(rep.violations)}", file=out)
    if rep.owners:
        print("final partition: " + json.dumps(
            {a: d["owned"] for a, d in rep.agents.items()}), file=out)
