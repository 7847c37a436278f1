"""The agent runtime: one drone's planner loop, trade client and server, membership and
completion detection, over any :class:`~agent.net.transport.Transport`.

Threading: :meth:`AgentRuntime.tick` runs on the caller's thread (the main loop, or a test
driving a :class:`~agent.net.memory.MemoryNetwork`); query handlers and subscription
callbacks run on transport threads. All mutable state is guarded by one re-entrant lock,
which is never held while this agent waits for a reply (so two agents querying each other
cannot deadlock). Every ledger change goes through the :class:`~agent.protocol.machine.TradeMachine`
and is journaled (fsynced when durable) before the message that depends on it is sent.

Times: ``clock.now()`` is mission time [s]; ``config.request_timeout_s`` is a real-time
transport timeout [s]; every other period in :class:`AgentConfig` is mission time.
"""

from __future__ import annotations

import logging
import random
import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from agent.clock import Clock
from agent.config.scenario import Scenario
from agent.core.orientation import angles_from_direction
from agent.core.planner import plan_step
from agent.core.trading import PartnerList, trade_stacked
from agent.core.vision import Landmarks, as_distance_term, per_landmark_cols
from agent.net.transport import Declared, Transport
from agent.protocol.machine import GenesisRec, PoseRec, Step, TradeMachine
from agent.runtime.pose import KinematicPoseSource, PoseSource
from agent.wire import keys
from agent.wire.codec import Codec, RateLimitedLogger, RejectCounter
from agent.wire.peer import (
    AgentState,
    Commit,
    Counters,
    MissionStatus,
    Offer,
    Pose,
    Publication,
    Refused,
    Reply,
    Request,
    StatusQuery,
    pack_arrays,
    unpack,
)

_log = logging.getLogger(__name__)

Array = NDArray[np.float64]
IntArray = NDArray[np.int64]

REASON_SENDER = "sender"
REASON_UNKNOWN_AGENT = "unknown_agent"
REASON_IMPOSSIBLE = "impossible"


class JournalLike(Protocol):
    """What the runtime needs of :class:`agent.storage.journal.Journal`."""

    def replay(self) -> list[Any]: ...

    def append(self, records: Any, sync: bool | None = None) -> None: ...


@dataclass
class AgentConfig:
    """Runtime constants (mission seconds unless stated)."""

    mission: str = "default"
    request_timeout_s: float = 0.3  #: real seconds a query waits for its reply
    max_offer_tries: int = 8  #: tries of one Offer to a partner not seen alive
    max_offer_tries_live: int = 30  #: tries when the partner's liveliness token is present
    backoff_s: float = 0.05  #: first retry delay, doubled per try
    backoff_cap_s: float = 0.4  #: largest retry delay
    busy_retries: int = 30  #: Busy("trading") answers tolerated per partner
    doubt_delay_s: float = 0.2  #: wait before a prepared responder asks the initiator
    state_period_s: float = 0.2  #: state publication period (5 Hz at real time)
    pose_journal_period_s: float = 1.0  #: how often the pose goes to the journal
    fresh_periods: float = 10.0  #: a state older than this many periods is stale
    complete_hold_periods: float = 3.0  #: completion must hold this long before reported
    require_all: bool = True  #: completion needs every scenario agent seen alive once
    departure_grace_periods: float = 10.0  #: no completion this long after a departure
    exit_linger_periods: float = 6.0  #: an exiting agent stays this long after completion
    final_repeats: int = 10  #: copies of the final state sent on exit (lossy links)
    seed: int = 0  #: seeds the backoff jitter


class Geometry:
    """Landmark geometry indexed by landmark id: rows, subsets, Algorithm 7."""

    def __init__(self, scenario: Scenario) -> None:
        self.ids = np.asarray(scenario.landmark_ids, dtype=np.int64)
        self.order = np.argsort(self.ids, kind="stable")
        self.sorted_ids = self.ids[self.order]
        self.cols = Landmarks.of(scenario.q, scenario.u)  #: every landmark, column layout
        self.term = as_distance_term(scenario.d_opt)

    def rows(self, lids: IntArray) -> NDArray[np.intp]:
        """Row indices (into the scenario's q, u) of landmark ids ``lids`` (all known)."""
        return self.order[np.searchsorted(self.sorted_ids, lids)]

    def subset(self, rows: NDArray[np.intp]) -> Landmarks:
        """The landmarks at ``rows``, column layout."""
        return Landmarks(np.take(self.cols.qT, rows, axis=1), np.take(self.cols.uT, rows, axis=1))

    def decide(
        self, p_i: Any, v_i: Any, ids_i: IntArray, p_r: Any, v_r: Any, ids_r: IntArray
    ) -> tuple[NDArray[np.bool_], NDArray[np.bool_]]:
        """Algorithm 7 with A = initiator I, B = responder R."""
        out = trade_stacked(
            np.asarray(p_i, dtype=np.float64), np.asarray(v_i, dtype=np.float64),
            np.asarray(p_r, dtype=np.float64), np.asarray(v_r, dtype=np.float64),
            self.subset(self.rows(np.concatenate((ids_i, ids_r)))), ids_i.size, self.term,
        )
        return out.a_to_b, out.b_to_a


#: Optional replacement of the planner for protocol tests: ``motion(runtime) -> converged``.
MotionFn = Callable[["AgentRuntime"], bool]


class SettleTest(Protocol):
    """A second convergence test for vehicles that never sit exactly on the optimum.

    ``update`` sees every measured pose while the planner still moves; it returns the pose to
    hold (mean position [m], unit camera direction) once the vehicle counts as settled, else
    None. ``reset`` is called when the planner itself declares convergence (section 4.4).
    """

    def update(self, t: float, p: Array, v: Array) -> tuple[Array, Array] | None: ...

    def reset(self) -> None: ...


@dataclass
class _Attempt:
    trade_id: str
    partner: str
    payload: bytes
    tries: int = 0
    due: float = 0.0


@dataclass
class _Retry:
    due: float
    tries: int = 0


@dataclass
class RuntimeCounters:
    """Counters of one agent process (the ones in :class:`Counters` plus details)."""

    busy: int = 0
    timeouts: int = 0
    requests: int = 0
    bytes_out: int = 0
    published: int = 0
    offers_sent: int = 0
    outcomes: dict[str, int] = field(default_factory=dict)


class AgentRuntime:
    """One agent (see the module docstring).

    Args:
        agent_id: this agent's id (must be in the scenario).
        scenario: the mission.
        transport: messaging (Zenoh or in-memory).
        journal: durable state (replayed here, at construction).
        clock: mission clock.
        pose: pose source; a :class:`KinematicPoseSource` is moved to the journaled pose.
        config: constants.
        motion: optional planner replacement (tests).
        on_change: called (without the lock) after every ledger change, for test probes.
    """

    def __init__(
        self,
        agent_id: str,
        scenario: Scenario,
        transport: Transport,
        journal: JournalLike,
        clock: Clock,
        pose: PoseSource | None = None,
        config: AgentConfig | None = None,
        *,
        motion: MotionFn | None = None,
        settle: SettleTest | None = None,
        on_change: Callable[[AgentRuntime], None] | None = None,
    ) -> None:
        keys.validate_id(agent_id)
        specs = {a.id: a for a in scenario.agents}
        if agent_id not in specs:
            raise ValueError(f"agent {agent_id!r} is not in scenario {scenario.name!r}")
        self.id = agent_id
        self.sc = scenario
        self.cfg = config or AgentConfig()
        self.tp = transport
        self.journal = journal
        self.clock = clock
        self.motion = motion
        self.settle = settle
        self.on_change = on_change
        self.geo = Geometry(scenario)
        self.order = [a.id for a in scenario.agents]
        self._lock = threading.RLock()
        self._rng = random.Random(f"{self.cfg.seed}:{agent_id}")
        self.rejects = RejectCounter()
        log = RateLimitedLogger(logging.getLogger(f"agent.{agent_id}.rx"))
        self.c_req: Codec[Request] = Codec(Request, counter=self.rejects, log=log)
        self.c_rep: Codec[Reply] = Codec(Reply, counter=self.rejects, log=log)
        self.c_pub: Codec[Publication] = Codec(Publication, counter=self.rejects, log=log)

        # Durable state: replay, genesis on first start, new incarnation.
        self.machine = TradeMachine(agent_id, self.geo.ids)
        for rec in journal.replay():
            self.machine.apply(rec)
        spec = specs[agent_id]
        if not self.machine.genesis:
            lids = np.sort(self.geo.ids[spec.landmarks])
            gen = GenesisRec(agent=agent_id,
                             owned=pack_arrays(lids, np.zeros(lids.size, dtype=np.int64)))
            self.machine.apply(gen)
            journal.append([gen], sync=True)
        journal.append(self.machine.recover(), sync=True)
        self.pose: PoseSource = pose or KinematicPoseSource(
            spec.p0, spec.v0, clock, scenario.space
        )
        lp = self.machine.last_pose
        if lp is not None and isinstance(self.pose, KinematicPoseSource):
            self.pose.p = np.asarray(lp.p, dtype=np.float64)
            self.pose.v = np.asarray(lp.v, dtype=np.float64)

        # A scenario with trading = false runs pose optimisation only: no partners.
        self.partners = PartnerList(agent_id, tuple(self.order) if scenario.trading else ())
        self.optimising = True
        self.prev_dir = np.zeros(3)
        self.others_pos: dict[str, Array] = {
            a.id: a.p0.astype(np.float64) for a in scenario.agents if a.id != agent_id
        }
        self.states: dict[str, tuple[AgentState, float]] = {}
        self.live: set[str] = set()
        self.ever_seen: set[str] = set()
        self._last_departure: float | None = None
        self.attempt: _Attempt | None = None
        self._retries: dict[str, _Retry] = {}
        self._busy_tries: dict[str, int] = {}
        self._not_before: dict[str, float] = {}
        self.counters = RuntimeCounters()
        self._owned_key: int = -1
        self._owned_lm: Landmarks = self.geo.subset(np.zeros(0, dtype=np.intp))
        self._ledger_rev = 0
        self._seq = 0
        self._pose_seq = 0
        self._next_state = 0.0
        self._next_pose_rec = 0.0
        self._dirty = True
        self.complete = False
        self._complete_since: float | None = None
        self.completed_at: float | None = None
        self._status_due = False
        self._farewell_sent = False
        self._handles: list[Declared] = []
        self._started = False

    # -- lifecycle -------------------------------------------------------------------------
    def start(self) -> None:
        """Declare the trade queryable, subscriptions and liveliness token; publish state."""
        m = self.cfg.mission
        self._handles.append(self.tp.declare_queryable(keys.trade_key(m, self.id), self._on_query))
        self._handles.append(self.tp.subscribe(keys.all_agents(m, "pose"), self._on_pose))
        self._handles.append(self.tp.subscribe(keys.all_agents(m, "state"), self._on_state))
        self._handles.append(
            self.tp.watch_liveliness(keys.all_agents(m, "alive"), self._on_join, self._on_leave)
        )
        self._handles.append(self.tp.declare_liveliness(keys.alive_key(m, self.id)))
        self._started = True
        self._publish(self.clock.now(), force=True)

    def stop(self) -> None:
        """Undeclare everything (the transport and journal are closed by their owner)."""
        for h in reversed(self._handles):
            try:
                h.undeclare()
            except Exception:  # pragma: no cover - transport already closed
                _log.debug("undeclare failed", exc_info=True)
        self._handles.clear()
        self._started = False

    # -- derived state ---------------------------------------------------------------------
    @property
    def phase(self) -> str:
        """optimising, converged, trading (our offer pending) or in_doubt (prepared)."""
        if self.machine.prepared:
            return "in_doubt"
        if self.attempt is not None or self.machine.offering:
            return "trading"
        return "optimising" if self.optimising else "converged"

    def _owned(self) -> Landmarks:
        """Our landmarks (column layout), rebuilt only when the ledger changed."""
        if self._owned_key != self._ledger_rev:
            self._owned_lm = self.geo.subset(self.geo.rows(self.machine.owned_arrays()[0]))
            self._owned_key = self._ledger_rev
        return self._owned_lm

    def vision(self) -> float:
        """Vision of this agent over its owned landmarks at its current pose."""
        p, v, _ = self.pose.current()
        lm = self._owned()
        if lm.m == 0:
            return 0.0
        return float(per_landmark_cols(p, v, lm, self.geo.term).sum())

    def _backoff(self, tries: int) -> float:
        base = min(self.cfg.backoff_cap_s, self.cfg.backoff_s * (2 ** max(0, tries - 1)))
        return base * self._rng.uniform(0.5, 1.5)

    # -- journaling ------------------------------------------------------------------------
    def _journal(self, step: Step) -> None:
        if step.records:
            self.journal.append(step.records)
            self._ledger_rev += 1
            self._dirty = True

    def _changed(self) -> None:
        if self.on_change is not None:
            self.on_change(self)

    def _success(self) -> None:
        """Section 4.5: after a successful trade reset the list and optimise again."""
        self.partners.reset()
        self._busy_tries.clear()
        self._not_before.clear()
        self.optimising = True
        self.prev_dir = np.zeros(3)
        self._complete_since = None

    # -- main loop -------------------------------------------------------------------------
    def tick(self) -> None:
        """One planner period Δt: pending-trade retries, a planner step or a trade step,
        publications and the completion check."""
        now = self.clock.now()
        self._service_pending(now)
        with self._lock:
            phase = self.phase
        if phase == "optimising":
            self._plan_once()
        elif phase == "converged":
            self._maybe_offer(now)
        if self.attempt is not None and now >= self.attempt.due:
            self._attempt_offer(now)
            self._service_pending(now)
        with self._lock:
            self._check_complete(now)
        self._publish(now)

    def _plan_once(self) -> None:
        if self.motion is not None:
            converged = self.motion(self)
        else:
            with self._lock:
                lm = self._owned()
                others = np.array(list(self.others_pos.values())).reshape(-1, 3)
            p, v, t = self.pose.current()
            step = plan_step(p, v, lm, None, self.geo.term, self.sc.params, self.sc.space,
                             others, self.prev_dir)
            converged = step.converged
            if self.settle is not None:
                rest = None if converged else self.settle.update(t, p, v)
                if converged:
                    self.settle.reset()
                elif rest is not None:  # settled: hold the centre of the motion (fig. 6.2)
                    converged = True
                    hold = getattr(self.pose, "hold", None)
                    if hold is not None:
                        hold(rest[0], angles_from_direction(rest[1])[1])
            if not converged:
                self.pose.command(step.p_dot, step.omega, self.sc.params.dt)
                self.prev_dir = step.p_dir
        if converged:
            with self._lock:
                if self.optimising and self.phase == "optimising":
                    self.optimising = False
                    self.prev_dir = np.zeros(3)
                    self._dirty = True

    def _maybe_offer(self, now: float) -> None:
        with self._lock:
            if self.phase != "converged":
                return
            partner = next(
                (x for x in self.partners.pending if self._not_before.get(x, 0.0) <= now), None
            )
            if partner is None:
                return
            p, v, _ = self.pose.current()
            step = self.machine.new_offer(partner, _vec(p), _vec(v))
            self._journal(step)
            self.attempt = _Attempt(step.outcome, partner, self.c_req.encode(step.message),
                                    due=now)
            self.counters.offers_sent += 1

    def _request(self, partner: str, payload: bytes) -> Reply | None:
        key = keys.trade_key(self.cfg.mission, partner)
        self.counters.requests += 1
        self.counters.bytes_out += len(payload)
        raw = self.tp.request(key, payload, self.cfg.request_timeout_s, kind="trade")
        if raw is None:
            return None
        return self.c_rep.decode(raw, key)

    def _attempt_offer(self, now: float) -> None:
        att = self.attempt
        if att is None:
            return
        reply = self._request(att.partner, att.payload)
        with self._lock:
            if self.attempt is not att:
                return
            if reply is None or getattr(reply, "trade_id", None) != att.trade_id:
                self.counters.timeouts += 1
                att.tries += 1
                limit = (self.cfg.max_offer_tries_live if att.partner in self.live
                         else self.cfg.max_offer_tries)
                if att.tries < limit:
                    att.due = self.clock.now() + self._backoff(att.tries)
                    return
                self._journal(self.machine.abort_offer(att.trade_id, "timeout"))
                self.partners.drop(att.partner)
                self.attempt = None
                self._count("timeout")
                self._dirty = True
            else:
                step = self.machine.on_offer_reply(att.trade_id, reply)
                self._journal(step)
                self._count(step.outcome)
                if step.outcome == "ignored":
                    return  # an answer that does not belong to this offer: keep waiting
                self.attempt = None
                if step.outcome == "commit":
                    self._retries[att.trade_id] = _Retry(due=now)
                    self._success()
                elif step.outcome == "retry_later":
                    self.counters.busy += 1
                    n = self._busy_tries.get(att.partner, 0) + 1
                    self._busy_tries[att.partner] = n
                    if n > self.cfg.busy_retries:
                        self.partners.drop(att.partner)
                    else:
                        self._not_before[att.partner] = now + self._backoff(n)
                        if att.partner in self.partners.pending:
                            self.partners.pending.remove(att.partner)
                            self.partners.pending.append(att.partner)
                else:  # drop, drop_both
                    if step.outcome == "drop":
                        self.counters.busy += 1
                    self.partners.drop(att.partner)
                self._dirty = True
        self._changed()

    def _service_pending(self, now: float) -> None:
        """Send Commit for unacknowledged commits and StatusQuery for trades in doubt."""
        with self._lock:
            commits = self.machine.unacked_commits()
            doubts = self.machine.doubts()
            live = {t for t, _ in commits} | {t for t, _ in doubts}
            for t in list(self._retries):
                if t not in live:
                    del self._retries[t]
        for tid, partner in commits:
            self._resolve(now, tid, partner, Commit(sender=self.id, trade_id=tid), now,
                          self.machine.on_commit_reply, {"done"})
        for tid, partner in doubts:
            self._resolve(now, tid, partner, StatusQuery(sender=self.id, trade_id=tid),
                          now + self.cfg.doubt_delay_s, self.machine.on_decision,
                          {"committed", "restored"})

    def _resolve(self, now: float, tid: str, partner: str, request: Request, first_due: float,
                 handle: Callable[[str, Reply], Step], final: set[str]) -> None:
        """One due try of a pending trade's request (Commit or StatusQuery) to ``partner``:
        ``handle`` the reply; unless its outcome is ``final``, retry later with backoff."""
        r = self._retries.setdefault(tid, _Retry(due=first_due))
        if now < r.due:
            return
        reply = self._request(partner, self.c_req.encode(request))
        with self._lock:
            step = handle(tid, reply) if reply is not None else Step()
            self._journal(step)
            if step.outcome == "committed":  # R learned the decision: the trade succeeded
                self._success()
            if step.outcome not in final:
                if reply is None:
                    self.counters.timeouts += 1
                r.tries += 1
                r.due = self.clock.now() + self._backoff(r.tries)
        if step.records:
            self._changed()

    def _count(self, outcome: str) -> None:
        self.counters.outcomes[outcome] = self.counters.outcomes.get(outcome, 0) + 1

    # -- trade server ----------------------------------------------------------------------
    def _on_query(self, payload: bytes, selector: str) -> bytes | None:
        req = self.c_req.decode(payload, selector)
        if req is None:
            return None
        if req.sender not in self.others_pos and req.sender != self.id:
            self.c_req.reject(REASON_UNKNOWN_AGENT, selector, f"sender {req.sender!r}")
            return None
        with self._lock:
            if isinstance(req, Offer):
                if not _unit_ok(req.v):
                    self.c_req.reject(REASON_IMPOSSIBLE, selector, "offer direction not unit")
                    return self.c_rep.encode(
                        Refused(sender=self.id, trade_id=req.trade_id, reason="bad_pose"))
                att = self.attempt
                if (att is not None and att.partner == req.sender and self.id > req.sender
                        and not self.machine.prepared):
                    # Both offered to each other: the larger id yields (its offer cannot have
                    # been prepared by a partner that is itself offering), else both would
                    # answer Busy("trading") and back off together.
                    self._journal(self.machine.abort_offer(att.trade_id, "yield"))
                    self.attempt = None
                    self._count("yield")
                phase = self.phase
                busy = None if phase == "converged" else (
                    "optimising" if phase == "optimising" else "trading")
                p, v, _ = self.pose.current()
                step = self.machine.on_offer(req, _vec(p), _vec(v), busy, self.geo.decide)
                self._journal(step)
                if step.outcome == "no_trade":
                    self.partners.drop(req.sender)
                    self._dirty = True
                elif step.outcome in ("invalid", "conflict"):
                    self.c_req.reject(REASON_IMPOSSIBLE, selector, f"offer {step.outcome}")
            elif isinstance(req, Commit):
                step = self.machine.on_commit(req)
                self._journal(step)
                if step.outcome == "committed":
                    self._retries.pop(req.trade_id, None)
                    self._success()
            else:
                step = self.machine.on_status_query(req)
            out = self.c_rep.encode(step.message)
        if step.records:
            self._changed()
        return out

    # -- subscriptions ---------------------------------------------------------------------
    def _check_sender(self, key: str, sender: str, codec: Codec[Any]) -> bool:
        agent = keys.try_agent_of(key)
        if agent is None or agent != sender:
            codec.reject(REASON_SENDER, key, f"sender {sender!r} on {key}")
            return False
        if sender not in self.others_pos and sender != self.id:
            codec.reject(REASON_UNKNOWN_AGENT, key, f"unknown agent {sender!r}")
            return False
        return True

    def _peer_publication(self, key: str, payload: bytes, kind: type[Any], what: str) -> Any:
        """Decode a peer's publication of type ``kind`` on ``key``; None (counted) if bad,
        None (silently) if it is our own."""
        msg = self.c_pub.decode(payload, key)
        if msg is None:
            return None
        if not isinstance(msg, kind):
            self.c_pub.reject(REASON_IMPOSSIBLE, key, f"{type(msg).__name__} on a {what} key")
            return None
        if not self._check_sender(key, msg.sender, self.c_pub) or msg.sender == self.id:
            return None
        return msg

    def _on_pose(self, key: str, payload: bytes) -> None:
        msg = self._peer_publication(key, payload, Pose, "pose")
        if msg is None:
            return
        if not _unit_ok(msg.v):
            self.c_pub.reject(REASON_IMPOSSIBLE, key, "direction not unit")
            return
        with self._lock:
            if msg.sender in self.others_pos:
                self.others_pos[msg.sender] = np.asarray(msg.p, dtype=np.float64)

    def _on_state(self, key: str, payload: bytes) -> None:
        msg = self._peer_publication(key, payload, AgentState, "state")
        if msg is None:
            return
        owned, held = unpack(msg.owned), unpack(msg.held)
        if not (_unit_ok(msg.v) and owned is not None and held is not None
                and self.machine.knows(owned[0]) and self.machine.knows(held[0])):
            self.c_pub.reject(REASON_IMPOSSIBLE, key, "state with impossible values")
            return
        with self._lock:
            prev = self.states.get(msg.sender)
            if prev is not None and (prev[0].incarnation, prev[0].seq) >= (msg.incarnation,
                                                                           msg.seq):
                return  # older or repeated
            self.states[msg.sender] = (msg, self.clock.now())
            # Liveliness is the authority on who is alive now, but a join event can be missed
            # (token declared while our watcher was being set up): a state proves the agent
            # has started.
            self.ever_seen.add(msg.sender)
            self.others_pos[msg.sender] = np.asarray(msg.p, dtype=np.float64)

    def _on_join(self, key: str) -> None:
        aid = keys.try_agent_of(key)
        if aid is None or aid == self.id or aid not in self.order:
            return
        with self._lock:
            self.live.add(aid)
            self.ever_seen.add(aid)
            if self.sc.trading and aid not in self.partners.everyone:
                present = set(self.partners.everyone) | {aid}
                self.partners.everyone = tuple(a for a in self.order if a in present)
            if self.sc.trading and aid not in self.partners.pending:
                self.partners.pending.append(aid)
                self._complete_since = None
            if aid not in self.others_pos:
                spec = next(a for a in self.sc.agents if a.id == aid)
                self.others_pos[aid] = spec.p0.astype(np.float64)
            self._dirty = True

    def _on_leave(self, key: str) -> None:
        aid = keys.try_agent_of(key)
        if aid is None or aid == self.id:
            return
        with self._lock:
            self.live.discard(aid)
            last = self.states.get(aid)
            if last is None or not _quiet_state(last[0]):
                # Left in the middle of its work (a crash?): give it time to come back.
                self._last_departure = self.clock.now()
                self._complete_since = None
            self.partners.forget(aid)
            self._not_before.pop(aid, None)
            self._dirty = True

    # -- completion ------------------------------------------------------------------------
    def _quiet(self) -> bool:
        return self.phase == "converged" and not self.partners.pending \
            and not self.machine.pending_ids

    def completion_blocker(self, now: float) -> str:
        """Why the mission is not complete in this agent's view (diagnostics)."""
        with self._lock:
            if not self._quiet():
                return (f"self not quiet: phase {self.phase}, partners {self.partners.pending}, "
                        f"pending {self.machine.pending_ids}")
            missing = set(self.order) - {self.id} - self.ever_seen
            if missing:
                return f"never seen {sorted(missing)}"
            out = []
            for aid in sorted(self.live):
                entry = self.states.get(aid)
                if entry is None:
                    out.append(f"{aid}: no state")
                    continue
                st, t = entry
                out.append(f"{aid}: age {now - t:.1f} s, phase {st.phase}, partners "
                           f"{st.partners}, pending {st.pending}, trades {st.trades_with}")
            return f"live {sorted(self.live)}; my trades {self.machine.trades_with}; " + \
                "; ".join(out)

    def _check_complete(self, now: float) -> None:
        ok = self._quiet()
        # Every scenario agent must have been seen once (so nobody completes before the others
        # start); afterwards only live agents count (a departed agent cannot trade), but the
        # departure of an agent that was not quiet holds completion back for a grace period
        # so that a restarting agent (crash, journal recovery) can rejoin first.
        if ok and self.cfg.require_all and not (set(self.order) - {self.id} <= self.ever_seen):
            ok = False
        if ok and self._last_departure is not None and \
                now - self._last_departure < self.cfg.departure_grace_periods \
                * self.cfg.state_period_s:
            ok = False
        fresh = self.cfg.fresh_periods * self.cfg.state_period_s
        # Agents to check: the live ones, plus any whose state is fresh (a missed liveliness
        # join must not let us overlook an agent that is still working).
        check = self.live | {a for a, (_st, t) in self.states.items() if now - t <= fresh}
        check.discard(self.id)
        if ok:
            for aid in check:
                entry = self.states.get(aid)
                if entry is None or now - entry[1] > fresh:
                    ok = False
                    break
                st = entry[0]
                if not _quiet_state(st):
                    ok = False
                    break
                if st.trades_with.get(self.id, 0) != self.machine.trades_with.get(aid, 0):
                    ok = False
                    break
        if ok:
            live = sorted(check)
            for i, a in enumerate(live):
                sa = self.states[a][0]
                for b in live[i + 1:]:
                    if sa.trades_with.get(b, 0) != self.states[b][0].trades_with.get(a, 0):
                        ok = False
        if not ok:
            self._complete_since = None
            if self.complete:
                self.complete = False
                self._dirty = True
            return
        if self._complete_since is None:
            self._complete_since = now
        hold = self.cfg.complete_hold_periods * self.cfg.state_period_s
        if not self.complete and now - self._complete_since >= hold:
            self.complete = True
            self.completed_at = now
            self._dirty = True
            self._status_due = True

    # -- publications ----------------------------------------------------------------------
    def state_message(self) -> AgentState:
        """This agent's state now (call with or without the lock)."""
        with self._lock:
            p, v, t = self.pose.current()
            self._seq += 1
            c = self.counters
            return AgentState(
                sender=self.id,
                incarnation=self.machine.incarnation,
                seq=self._seq,
                t=float(t),
                p=_vec(p),
                v=_vec(v),
                phase=self.phase,  # type: ignore[arg-type]
                owned=pack_arrays(*self.machine.owned_arrays()),
                held=pack_arrays(*self.machine.held_arrays()),
                vision=self.vision(),
                counters=Counters(ok=self.machine.ok, failed=self.machine.failed, busy=c.busy,
                                  timeouts=c.timeouts, rejected=self.rejects.total),
                partners=list(self.partners.pending),
                pending=self.machine.pending_ids,
                trades_with=dict(self.machine.trades_with),
                complete=self.complete,
            )

    def _publish(self, now: float, force: bool = False) -> None:
        if not self._started:
            return
        m = self.cfg.mission
        status: MissionStatus | None = None
        with self._lock:
            due = force or self._dirty or now >= self._next_state
            moving = self.phase == "optimising"
            if now >= self._next_pose_rec:
                p, v, t = self.pose.current()
                self.journal.append([PoseRec(p=_vec(p), v=_vec(v), t=float(t))], sync=False)
                self._next_pose_rec = now + self.cfg.pose_journal_period_s
            if due:
                state = self.state_message()
                self._dirty = False
                self._next_state = now + self.cfg.state_period_s
                if self._status_due or (self.complete and force):
                    self._status_due = False
                    status = MissionStatus(sender=self.id, t=now, complete=self.complete,
                                           coverage=self._coverage_estimate(),
                                           agents=sorted(self.live | {self.id}))
        if moving or due:
            p, v, t = self.pose.current()
            self._pose_seq += 1
            pose = Pose(sender=self.id, seq=self._pose_seq, t=float(t), p=_vec(p), v=_vec(v))
            self._put(keys.pose_key(m, self.id), self.c_pub.encode(pose))
        if due:
            self._put(keys.state_key(m, self.id), self.c_pub.encode(state))
        if status is not None:
            self._put(keys.status_key(m, self.id), self.c_pub.encode(status))

    def exit_due(self, now: float) -> bool:
        """True once completion has held for ``exit_linger_periods`` state periods (peers and
        observers had time to hear it); the first time, the final state and mission status
        are sent ``final_repeats`` more times so that a lossy link still delivers one."""
        with self._lock:
            if not self.complete or self.completed_at is None or \
                    now - self.completed_at < self.cfg.exit_linger_periods * \
                    self.cfg.state_period_s:
                return False
            first = not self._farewell_sent
            self._farewell_sent = True
        if first:
            for _ in range(self.cfg.final_repeats):
                self._publish(now, force=True)
        return True

    def _put(self, key: str, payload: bytes) -> None:
        try:
            self.tp.publish(key, payload)
            self.counters.published += 1
            self.counters.bytes_out += len(payload)
        except RuntimeError:  # transport closed under us (shutdown)
            _log.debug("publish on closed transport ignored")

    def _coverage_estimate(self) -> float:
        total = self.vision()
        for aid, (st, _t) in self.states.items():
            if aid in self.live:
                total += st.vision
        return total


def _quiet_state(st: AgentState) -> bool:
    """Converged, empty partner list, nothing pending."""
    return st.phase == "converged" and not st.partners and not st.pending


def _vec(a: Any) -> tuple[float, float, float]:
    return (float(a[0]), float(a[1]), float(a[2]))


def _unit_ok(v: tuple[float, float, float]) -> bool:
    n = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]) ** 0.5
    return 0.9 < n < 1.1
