"""The agent runtime: one drone's tick loop over any :class:`~agent.net.transport.Transport`.

:class:`AgentRuntime` owns the parts of one agent and the lock they share
(:class:`~agent.runtime.shared.Shared`): the planner step (figure 4.1),
the :class:`~agent.runtime.trade_client.TradeClient` (offers, retries),
the :class:`~agent.runtime.trade_server.TradeServer` (the trade queryable),
:class:`~agent.runtime.membership.Membership` (liveliness, peers' states and poses) and
:class:`~agent.runtime.completion.Completion` (global termination), and it publishes this
agent's pose, state and mission status.

Threading: :meth:`AgentRuntime.tick` runs on the caller's thread (the process loop of
:mod:`agent.runners.process`, or a test driving a :class:`~agent.net.memory.MemoryNetwork`);
query handlers and subscription callbacks run on transport threads. The lock is never held
while this agent waits for a reply.

Times: ``clock.now()`` is mission time [s]; ``config.request_timeout_s`` is a real-time
transport timeout [s]; every other period in :class:`AgentConfig` is mission time.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from collections.abc import Callable

import numpy as np

from agent.clock import Clock
from agent.config.scenario import AgentSpec, Scenario
from agent.core.trading import PartnerList
from agent.core.vision import Landmarks, per_landmark_cols
from agent.net.contract import Declared, Transport
from agent.protocol.machine import TradeMachine
from agent.protocol.records import PoseRec
from agent.runtime.adoption import Adoption
from agent.runtime.completion import Completion
from agent.runtime.inspecting import Inspecting
from agent.runtime.joining import Joining
from agent.runtime.membership import Membership
from agent.runtime.moves import CoverageMoves
from agent.runtime.planning import Planning
from agent.runtime.pose import KinematicPoseSource, PoseSource, SettleTest, battery_of
from agent.runtime.revert import Revert
from agent.runtime.shared import (
    AgentConfig,
    JournalLike,
    Phase,
    RuntimeCounters,
    Shared,
    vec3,
)
from agent.runtime.trade_client import TradeClient
from agent.runtime.trade_server import TradeServer
from agent.runtime.work_taker import WorkTaker
from agent.wire import keys
from agent.wire.codec import Codec, RateLimitedLogger, RejectCounter
from agent.wire.peer import (
    AgentState,
    Counters,
    MissionStatus,
    Pose,
    Publication,
    Reply,
    Request,
    pack_arrays,
)

__all__ = ["AgentConfig", "AgentRuntime", "MotionFn", "SettleTest"]

_log = logging.getLogger(f"viscover.{__name__}")

#: Optional replacement of the planner for protocol tests: ``motion(runtime) -> converged``.
MotionFn = Callable[["AgentRuntime"], bool]


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
        settle: optional second convergence test (flown vehicles).
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
        join: AgentSpec | None = None,
    ) -> None:
        keys.validate_id(agent_id)
        specs = {a.id: a for a in scenario.agents}
        if join is not None:  # a drone not in the scenario joining with nothing
            if agent_id in specs:
                raise ValueError(f"agent {agent_id!r} is in scenario {scenario.name!r}: it "
                                 "takes part from the start, it cannot join")
            specs[agent_id] = join
        if agent_id not in specs:
            raise ValueError(f"agent {agent_id!r} is not in scenario {scenario.name!r}")
        self.id = agent_id
        self.sc = scenario
        self.cfg = config or AgentConfig()
        if join is not None:  # it joins a running mission: nobody is waiting for it to start
            self.cfg = dataclasses.replace(self.cfg, require_all=False)
        self.tp = transport
        self.journal = journal
        self.clock = clock
        self.motion = motion
        self.settle = settle
        self.shared = s = Shared(agent_id, scenario, journal, clock, self.cfg)
        if on_change is not None:
            s.on_change = lambda: on_change(self)
        self.rejects = RejectCounter()
        log = RateLimitedLogger(logging.getLogger(f"viscover.agent.{agent_id}.rx"))
        c_req: Codec[Request] = Codec(Request, counter=self.rejects, log=log)
        c_rep: Codec[Reply] = Codec(Reply, counter=self.rejects, log=log)
        self.c_pub: Codec[Publication] = Codec(Publication, counter=self.rejects, log=log)

        spec = specs[agent_id]
        s.open_ledger(spec.landmarks, time.time())
        if (loop := s.crash_loop()) is not None:
            _log.warning("agent %s: %s", agent_id, loop)
        self.pose: PoseSource = pose or KinematicPoseSource(
            spec.p0, spec.v0, clock, scenario.space
        )
        lp = s.machine.last_pose
        if lp is not None and isinstance(self.pose, KinematicPoseSource):
            self.pose.p = np.asarray(lp.p, dtype=np.float64)
            self.pose.v = np.asarray(lp.v, dtype=np.float64)

        self.completion = Completion(s)
        s.on_success.append(self.completion.restart)
        self.members = members = Membership(s, self.c_pub, self.completion.restart)
        pose_now = self.pose.current
        self.client = TradeClient(s, transport, members, c_req, c_rep, pose_now)
        self.adoption = Adoption(s, members, self.client, c_req, pose_now, self.completion)
        self.planning = Planning(s, scenario, self.members, self.pose, self._owned,
                                 None if motion is None else (lambda: motion(self)), settle)
        self.adoption.on_adopted.append(self.planning.arm_relocation)
        if scenario.inspection is not None:
            self.planning.inspecting = ins = Inspecting(
                agent_id, scenario, self.pose, s.owned_rows, self.planning.others,
                s.record_capture, list(s.machine.captured))
            self.members.state_hooks.append(ins.on_peer_state)
        if join is not None:
            s.partners.reset(())  # partners come as they admit it (Joining)
        self.joining = Joining(s, members, self.client, c_req, pose_now,
                               joiner=join is not None)
        self.server = TradeServer(s, members, self.client, self.adoption, self.joining, c_req,
                                  c_rep, pose_now)
        self.completion.waiting = self.adoption.waiting
        self.revert = Revert(s, members, c_req, pose_now, self.vision)
        self.moves = CoverageMoves(s, members, c_req, pose_now, self.revert)
        self.taker = None if (i := self.planning.inspecting) is None else WorkTaker(
            i, s, members, self.moves)  # an inspection drone's re-splits
        self.completion.next_stage = self.moves.next_stage
        self.client.on_no_trade.append(self.moves.after_no_trade)
        self._owned_rev = -1
        self._owned_lm: Landmarks = s.geo.subset(np.zeros(0, dtype=np.intp))
        self._seq = self._pose_seq = 0
        self._next_state = 0.0
        self._next_pose_rec = 0.0
        self._farewell_sent = False
        self._handles: list[Declared] = []
        self._started = False

    # -- views of the shared state ----------------------------------------------------------
    @property
    def machine(self) -> TradeMachine:
        """The trade state machine (ledger)."""
        return self.shared.machine

    @property
    def partners(self) -> PartnerList:
        """Section 4.5's partner list."""
        return self.shared.partners

    @property
    def counters(self) -> RuntimeCounters:
        """This process's counters."""
        return self.shared.counters

    @property
    def phase(self) -> Phase:
        """optimising, converged, trading (our offer pending) or in_doubt (prepared)."""
        return self.shared.phase

    @property
    def optimising(self) -> bool:
        """Whether the pose optimisation runs (False once converged)."""
        return self.shared.optimising

    @optimising.setter
    def optimising(self, value: bool) -> None:
        self.shared.optimising = value

    @property
    def live(self) -> set[str]:
        """Peers whose liveliness token is present."""
        return self.members.live

    @property
    def complete(self) -> bool:
        """Whether the mission is complete in this agent's view."""
        return self.completion.complete

    @property
    def completed_at(self) -> float | None:
        """Mission time completion was first reported [s]."""
        return self.completion.completed_at

    # -- lifecycle -------------------------------------------------------------------------
    def start(self) -> None:
        """Declare the trade queryable, subscriptions and liveliness token; publish state."""
        m = self.cfg.mission
        members = self.members
        self._handles.append(self.tp.declare_queryable(keys.trade_key(m, self.id),
                                                       self.server.on_query))
        self._handles.append(self.tp.subscribe(keys.all_agents(m, "pose"), members.on_pose))
        self._handles.append(self.tp.subscribe(keys.all_agents(m, "state"), members.on_state))
        self._handles.append(self.tp.watch_liveliness(keys.all_agents(m, "alive"),
                                                      members.on_join, members.on_leave))
        self._handles.append(self.tp.declare_liveliness(keys.alive_key(m, self.id)))
        if not isinstance(self.pose, KinematicPoseSource):  # flown: the mocap exists
            self._handles.append(self.server.poses.listen(self.tp))
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

    # -- vision ----------------------------------------------------------------------------
    def _owned(self) -> Landmarks:
        """Our landmarks (column layout), rebuilt only when the ledger changed."""
        s = self.shared
        if self._owned_rev != s.ledger_rev:
            self._owned_lm = s.geo.subset(s.geo.rows(s.machine.owned_arrays()[0]))
            self._owned_rev = s.ledger_rev
        return self._owned_lm

    def vision(self) -> float:
        """Eq. 3.4: this agent's vision of its owned landmarks at its current pose (with
        occlusion, of those the structure does not hide)."""
        p, v, _ = self.pose.current()
        lm = self._owned()
        if lm.m == 0:
            return 0.0
        each = per_landmark_cols(p, v, lm, self.shared.geo.term)
        return float(self.planning.structure.seen_vision(each, np.asarray(p), lm).sum())

    # -- main loop -------------------------------------------------------------------------
    def tick(self) -> None:
        """One planner period Δt: pending-trade retries, a planner step or a trade step,
        publications and the completion check."""
        s = self.shared
        if s.failed is not None:  # the trade server hit a journal failure: leave
            raise s.failed
        now = self.clock.now()
        self.joining.tick(now)
        self.adoption.tick(now)
        if s.machine.fenced_out is not None and self._started:
            self.stop()  # lost to the team: it leaves the mission (its token goes)
        with s.lock:  # frozen by a fence round, fenced out, not admitted yet: no trade steps
            trades = not s.machine.frozen and s.machine.fenced_out is None \
                and self.joining.admitted
        if trades:
            self.client.service_pending(now)
        with s.lock:
            phase = s.phase
        if trades and (self.moves.continue_group(now) or self.moves.maybe_team_move(now)
                       or self.revert.step(now)
                       or (self.taker is not None and self.taker.initial_split(now))):
            pass  # our group re-split or revert pulls are under way: hold the pose meanwhile
        elif phase == "optimising":
            self.planning.step()
        elif phase == "converged" and trades and self.taker is not None:
            self.taker.tick(now)  # an inspection drone with nothing left: take work or go home
        elif phase == "converged" and trades and not self.moves.maybe_regroup(now):
            self.client.maybe_offer(now)
        if trades and s.attempt is not None and now >= s.attempt.due:
            self.client.attempt_offer(now)
            self.client.service_pending(now)
        with s.lock:
            self.completion.check(now, self.members)
        self._publish(now)

    def completion_blocker(self, now: float) -> str:
        """Why the mission is not complete in this agent's view (diagnostics)."""
        return self.completion.blocker(now, self.members)

    # -- publications ----------------------------------------------------------------------
    def state_message(self) -> AgentState:
        """This agent's state now (call with or without the lock)."""
        s = self.shared
        with s.lock:
            p, v, t = self.pose.current()
            self._seq += 1
            c = s.counters
            m = s.machine
            return AgentState(
                sender=self.id, incarnation=m.incarnation, seq=self._seq, t=float(t),
                p=vec3(p), v=vec3(v), phase=s.phase,
                owned=pack_arrays(*m.owned_arrays()), held=pack_arrays(*m.held_arrays()),
                vision=self.vision(),
                counters=Counters(ok=m.ok, failed=m.failed, busy=c.busy, timeouts=c.timeouts,
                                  rejected=self.rejects.total),
                partners=list(s.partners.pending), pending=m.pending_ids,
                trades_with=dict(m.trades_with), complete=self.completion.complete,
                fenced=self.adoption.claims.proven(), fence_epoch=m.fence_epoch,
                fence_proofs=self.adoption.claims.proofs(),
                contested=int(m.contested_arrays()[0].size),
                members=sorted(m.members - {self.id}),
                fenced_out=m.fenced_out is not None, stage=s.stage,
                stage1_vision=s.stage1_vision, reverting=s.reverting,
                captured=b"" if (ins := self.planning.inspecting) is None else ins.bits(),
                trades=list(m.recent), battery=battery_of(self.pose),
            )

    def _publish(self, now: float, force: bool = False) -> None:
        if not self._started:
            return
        s, m = self.shared, self.cfg.mission
        status: MissionStatus | None = None
        with s.lock:
            due = force or s.dirty or now >= self._next_state
            moving = s.phase == "optimising"
            if now >= self._next_pose_rec:
                p, v, t = self.pose.current()
                self.journal.append([PoseRec(p=vec3(p), v=vec3(v), t=float(t))], sync=False)
                self._next_pose_rec = now + self.cfg.pose_journal_period_s
            if due:
                state = self.state_message()
                s.dirty = False
                self._next_state = now + self.cfg.state_period_s
                done = self.completion
                if done.announce or (done.complete and force):
                    done.announce = False
                    status = MissionStatus(
                        sender=self.id, t=now, complete=done.complete,
                        coverage=self.members.coverage_estimate(self.vision()),
                        agents=sorted(self.members.live | {self.id}))
        if moving or due:
            p, v, t = self.pose.current()
            self._pose_seq += 1
            pose = Pose(sender=self.id, seq=self._pose_seq, t=float(t), p=vec3(p), v=vec3(v))
            self._put(keys.pose_key(m, self.id), self.c_pub.encode(pose))
        if due:
            self._put(keys.state_key(m, self.id), self.c_pub.encode(state))
        if status is not None:
            self._put(keys.status_key(m, self.id), self.c_pub.encode(status))

    def exit_due(self, now: float) -> bool:
        """True once completion has held for ``exit_linger_periods`` state periods (peers and
        observers had time to hear it); the first time, the final state and mission status
        are sent ``final_repeats`` more times so that a lossy link still delivers one."""
        with self.shared.lock:
            at = self.completion.completed_at
            if not self.completion.complete or at is None or \
                    now - at < self.cfg.exit_linger_periods * self.cfg.state_period_s:
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
            self.shared.counters.published += 1
            self.shared.counters.bytes_out += len(payload)
        except RuntimeError:  # transport closed under us (shutdown)
            _log.debug("publish on closed transport ignored")
