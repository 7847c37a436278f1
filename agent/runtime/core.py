"""The agent core: one drone's decisions as a pure state machine, ``step(event) -> effects``.

:class:`AgentCore` holds everything one agent knows and decides: the ledger (the trade state
machine, :class:`~agent.runtime.shared.Shared`), its peers
(:class:`~agent.runtime.membership.Membership`), completion, the fence rounds, the stage and
the strategy's state (the planner step of figure 4.1, the coverage moves, inspection). It has
no lock, no transport and no journal: :meth:`AgentCore.step` takes one
:mod:`event <agent.runtime.events>` and returns the effects to carry out, records to persist
first among them. Its two ports: the mission clock (read) and the pose source (read, and
commanded by the planner: the kinematic pose is the planner's own state; a flown one reads
the vehicle's latest telemetry and passes set-points to its streamer, without waiting).

The tick (:class:`~agent.runtime.events.Tick`) is a generator: where it needs a reply (an
offer, a Commit, a fence vote) it returns an :class:`~agent.runtime.events.Ask` and waits;
the runtime sends it and steps the reply back in as an
:class:`~agent.runtime.events.Answer`. A long pure computation (a planner step, a re-split
search) is handed out the same way (:class:`~agent.runtime.events.Compute`). Queries,
samples and liveliness changes are stepped meanwhile (two agents querying each other cannot
deadlock; an agent answers while it computes). One tick at a time.

The runtime that carries the effects out over a transport and a journal is
:class:`agent.runtime.agent.AgentRuntime`; tests step cores directly.
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Callable, Iterable

import numpy as np

from agent.clock import Clock
from agent.config.scenario import AgentSpec, Scenario
from agent.core.vision import Landmarks, per_landmark_cols
from agent.protocol.records import PoseRec, Record
from agent.runtime.adoption import Adoption
from agent.runtime.completion import Completion
from agent.runtime.drivers import strategy_driver
from agent.runtime.events import (
    Answer,
    Asking,
    Effect,
    Event,
    Farewell,
    Leave,
    Liveliness,
    Persist,
    Publish,
    Query,
    Reply,
    Sample,
    Start,
    Tick,
)
from agent.runtime.inspecting import Inspecting
from agent.runtime.joining import Joining
from agent.runtime.membership import Membership
from agent.runtime.moves import CoverageMoves
from agent.runtime.planning import Planning
from agent.runtime.pose import KinematicPoseSource, PoseSource, SettleTest, battery_of
from agent.runtime.revert import Revert
from agent.runtime.shared import AgentConfig, Phase, Shared, vec3
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
    Request,
    pack_arrays,
)
from agent.wire.peer import Reply as ReplyMsg

__all__ = ["AgentCore", "MotionFn"]

_log = logging.getLogger(f"viscover.{__name__}")

#: Optional replacement of the planner for protocol tests: ``motion() -> converged``.
MotionFn = Callable[[], bool]


class AgentCore:
    """One agent's state and decisions (see the module docstring).

    Args:
        agent_id: this agent's id (in the scenario, or joining with ``join``).
        scenario: the mission.
        replayed: the records of its journal, in order (empty on a first start).
        clock: mission clock (read only).
        pose: pose source (read, and moved by the planner); a kinematic one is moved to
            the journal's last pose.
        config: constants.
        hedging: whether the transport can send a query as several copies.
        wall: Unix time [s] of this start (stamped on the incarnation record).
        motion: optional planner replacement (tests).
        settle: optional second convergence test (flown vehicles).
        join: the spec of a drone not in the scenario joining with nothing.
    """

    def __init__(
        self,
        agent_id: str,
        scenario: Scenario,
        replayed: Iterable[Record],
        clock: Clock,
        pose: PoseSource,
        config: AgentConfig,
        *,
        hedging: bool = False,
        wall: float = 0.0,
        motion: MotionFn | None = None,
        settle: SettleTest | None = None,
        join: AgentSpec | None = None,
    ) -> None:
        specs = {a.id: a for a in scenario.agents}
        if join is not None:
            specs[agent_id] = join
            config = dataclasses.replace(config, require_all=False)  # nobody waits for it
        self.id = agent_id
        self.cfg = config
        self.pose = pose
        self.shared = s = Shared(agent_id, scenario, clock, config)
        self.rejects = RejectCounter()
        log = RateLimitedLogger(logging.getLogger(f"viscover.agent.{agent_id}.rx"))
        c_req: Codec[Request] = Codec(Request, counter=self.rejects, log=log)
        c_rep: Codec[ReplyMsg] = Codec(ReplyMsg, counter=self.rejects, log=log)
        self.c_pub: Codec[Publication] = Codec(Publication, counter=self.rejects, log=log)
        s.open_ledger(replayed, specs[agent_id].landmarks, wall)
        lp = s.machine.last_pose  # a restart: the kinematic vehicle is where it was
        if lp is not None and isinstance(pose, KinematicPoseSource):
            pose.p = np.asarray(lp.p, dtype=np.float64)
            pose.v = np.asarray(lp.v, dtype=np.float64)

        self.completion = Completion(s)
        s.on_success.append(self.completion.restart)
        self.members = members = Membership(s, self.c_pub, self.completion.restart)
        pose_now = pose.current
        self.client = TradeClient(s, hedging, members, c_req, c_rep, pose_now)
        self.adoption = Adoption(s, members, self.client, c_req, pose_now, self.completion)
        self.planning = Planning(s, scenario, members, pose, self._owned, motion, settle)
        self.adoption.on_adopted.append(self.planning.arm_relocation)
        if scenario.inspection is not None:
            self.planning.inspecting = ins = Inspecting(
                agent_id, scenario, pose, s.owned_rows, self.planning.others,
                s.record_capture, list(s.machine.captured))
            members.state_hooks.append(ins.on_peer_state)
        if join is not None:
            s.partners.reset(())  # partners come as they admit it (Joining)
        self.joining = Joining(s, members, self.client, c_req, pose_now, joiner=join is not None)
        self.server = TradeServer(s, members, self.client, self.adoption, self.joining, c_req,
                                  c_rep, pose_now)
        self.completion.waiting = self.adoption.waiting
        self.revert = Revert(s, members, c_req, pose_now, self.vision)
        self.moves = CoverageMoves(s, members, c_req, pose_now, self.revert)
        self.taker = None if (i := self.planning.inspecting) is None else WorkTaker(
            i, s, members, self.moves)  # an inspection drone's re-splits
        self.completion.next_stage = self.moves.next_stage
        self.client.on_no_trade.append(self.moves.after_no_trade)
        #: what the strategy adds to the thesis' tick (agent.runtime.drivers)
        self.driver = strategy_driver(scenario.strategy, self.moves, self.revert, self.taker)
        self._owned_rev = -1
        self._owned_lm: Landmarks = s.geo.subset(np.zeros(0, dtype=np.intp))
        self._seq = self._pose_seq = 0
        self._next_state = 0.0
        self._next_pose_rec = 0.0
        self._farewell_sent = False
        self.started = False  #: publishing (after :class:`Start`, until it leaves)
        self._tick: Asking[None] | None = None  #: the tick waiting for an answer
        self._out: list[Effect] = []  #: effects of the step under way

    # -- views -----------------------------------------------------------------------------
    @property
    def phase(self) -> Phase:
        """optimising, converged, trading (our offer pending) or in_doubt (prepared)."""
        return self.shared.phase

    @property
    def waiting(self) -> bool:
        """Whether the tick waits for an answer (to an ask, or a computation's result)."""
        return self._tick is not None

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

    def take_unpersisted(self) -> list[Effect]:
        """The records made outside a step (start-up, a runner's hand-over) as effects."""
        out: list[Effect] = [Persist(u.records, u.sync) for u in self.shared.unpersisted]
        self.shared.unpersisted.clear()
        return out

    # -- the one entry -----------------------------------------------------------------------
    def step(self, event: Event) -> list[Effect]:
        """Take ``event``; the effects to carry out, in order (see :mod:`agent.runtime.events`;
        every record to persist comes before the message that depends on it)."""
        self._out = self.take_unpersisted()
        if isinstance(event, Tick):
            if self._tick is not None:
                raise RuntimeError(f"agent {self.id}: tick stepped while one waits for an answer")
            self._resume(self._ticking(event.now), None)
        elif isinstance(event, Answer):
            if self._tick is None:
                raise RuntimeError(f"agent {self.id}: an answer stepped with nothing waiting")
            self._resume(self._tick, event.reply)
        elif isinstance(event, Query):
            reply = self.server.on_query(event.payload, event.selector)
            self._flush()
            self._out.append(Reply(reply))
        elif isinstance(event, Sample):
            if event.kind == "pose":
                self.members.on_pose(event.key, event.payload)
            elif event.kind == "state":
                self.members.on_state(event.key, event.payload)
            else:
                self.server.poses.on_mocap(event.key, event.payload)
        elif isinstance(event, Liveliness):
            if event.alive:
                self.members.on_join(event.key)
            else:
                self.members.on_leave(event.key)
        elif isinstance(event, Start):
            self.started = True
            self._publish(event.now, force=True)
        elif isinstance(event, Farewell):
            for _ in range(self.cfg.final_repeats):
                self._publish(event.now, force=True)
        self._flush()
        out, self._out = self._out, []
        return out

    def fail(self, error: Exception) -> None:
        """The journal failed (disk full, I/O error): answer nothing more, leave at the next
        tick."""
        self.shared.fail(error)

    def _flush(self) -> None:
        """Hand the records made so far out as :class:`Persist` effects."""
        self._out += self.take_unpersisted()

    def _resume(self, tick: Asking[None], answer: object) -> None:
        """Run ``tick`` to what it waits for next (kept, waiting) or to its end."""
        self._tick = None
        try:
            ask = tick.send(answer)
        except StopIteration:
            return
        self._tick = tick
        self._flush()
        self._out.append(ask)

    # -- the tick ----------------------------------------------------------------------------
    def _ticking(self, now: float) -> Asking[None]:
        """One planner period Δt: pending-trade retries, a planner step or a trade step,
        publications and the completion check."""
        s = self.shared
        if s.failed is not None:  # a query hit a journal failure: leave
            raise s.failed
        yield from self.joining.tick(now)
        yield from self.adoption.tick(now)
        if s.machine.fenced_out is not None and self.started:
            self.started = False
            self._out.append(Leave())  # lost to the team: it leaves the mission
        # frozen by a fence round, fenced out, not admitted yet: no trade steps
        trades = not s.machine.frozen and s.machine.fenced_out is None \
            and self.joining.admitted
        if trades:
            yield from self.client.service_pending(now)
        phase = s.phase
        if trades and (self.moves.continue_group(now) or (yield from self.driver.holds(now))):
            pass  # a re-split's legs or the strategy's move under way: hold the pose
        elif phase == "optimising":
            yield from self.planning.step()
        elif phase == "converged" and trades and not (yield from self.driver.converged(now)):
            self.client.maybe_offer(now)
        if trades and s.attempt is not None and now >= s.attempt.due:
            yield from self.client.attempt_offer(now)
            yield from self.client.service_pending(now)
        self.completion.check(now, self.members)
        self._publish(now)

    def completion_blocker(self, now: float) -> str:
        """Why the mission is not complete in this agent's view (diagnostics)."""
        return self.completion.blocker(now, self.members)

    # -- publications ------------------------------------------------------------------------
    def state_message(self) -> AgentState:
        """This agent's state now."""
        s = self.shared
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
            capturable=b"" if ins is None else ins.capturable_bits,
            given_up=[] if ins is None else list(ins.given_up_bits()),
        )

    def _publish(self, now: float, force: bool = False) -> None:
        """Our pose (while it moves or with the state), state (when changed or due) and
        mission status (when completion changed) as :class:`Publish` effects; the pose to the
        journal once a ``pose_journal_period_s``."""
        if not self.started:
            return
        s, m = self.shared, self.cfg.mission
        status: MissionStatus | None = None
        state: AgentState | None = None
        due = s.take_publish_soon() or force or now >= self._next_state
        moving = s.phase == "optimising"
        if now >= self._next_pose_rec:
            p, v, t = self.pose.current()
            s.persist([PoseRec(p=vec3(p), v=vec3(v), t=float(t))], sync=False)
            self._next_pose_rec = now + self.cfg.pose_journal_period_s
        if due:
            state = self.state_message()
            self._next_state = now + self.cfg.state_period_s
            done = self.completion
            if done.announce or (done.complete and force):
                done.announce = False
                status = MissionStatus(
                    sender=self.id, t=now, complete=done.complete,
                    coverage=self.members.coverage_estimate(self.vision()),
                    agents=sorted(self.members.live | {self.id}))
        self._flush()
        if moving or due:
            p, v, t = self.pose.current()
            self._pose_seq += 1
            pose = Pose(sender=self.id, seq=self._pose_seq, t=float(t), p=vec3(p), v=vec3(v))
            self._put(keys.pose_key(m, self.id), self.c_pub.encode(pose))
        if state is not None:
            self._put(keys.state_key(m, self.id), self.c_pub.encode(state))
        if status is not None:
            self._put(keys.status_key(m, self.id), self.c_pub.encode(status))

    def _put(self, key: str, payload: bytes) -> None:
        self._out.append(Publish(key, payload))
        c = self.shared.counters
        c.published += 1
        c.bytes_out += len(payload)

    def exit_due(self, now: float) -> tuple[bool, bool]:
        """(True once completion has held for ``exit_linger_periods`` state periods, True
        the first time: then step a :class:`Farewell` so that a lossy link still delivers
        the final state)."""
        at = self.completion.completed_at
        if not self.completion.complete or at is None or \
                now - at < self.cfg.exit_linger_periods * self.cfg.state_period_s:
            return False, False
        first = not self._farewell_sent
        self._farewell_sent = True
        return True, first
