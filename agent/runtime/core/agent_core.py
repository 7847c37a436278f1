"""The agent core: one drone's decisions as a pure state machine, ``step(event) -> effects``.

:class:`AgentCore` holds everything one agent knows and decides: the ledger (the trade state
machine, :class:`~agent.runtime.core.shared.Shared`), its peers
(:class:`~agent.runtime.ends.membership.Membership`), completion, the fence rounds, the stage and
the strategy's state. No clock, lock, transport, journal or file: :meth:`AgentCore.step` takes
one :mod:`event <agent.runtime.core.events>` (with its mission time; Start and Tick with the
vehicle's fix) and returns the effects to carry out, records to persist first among them;
every action on the vehicle is an effect (:mod:`agent.runtime.core.vehicle`).

The tick is a generator: where it needs a reply (an offer, a Commit, a fence vote), a long
pure computation (a planner step, a re-split search) or the vehicle's fix after a command, it
returns an Ask, a Compute or a Command (:mod:`agent.runtime.core.events`) and waits for the
Answer. Queries, samples and liveliness changes are stepped meanwhile (an agent answers while
it computes). One tick at a time, carried out by :class:`~agent.runtime.shell.runtime.
AgentRuntime`; tests step cores directly.
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Callable, Iterable

import numpy as np
from numpy.typing import NDArray

from agent.config.scenario import AgentSpec, Scenario
from agent.core.vision import Landmarks, per_landmark_cols
from agent.protocol.machine import TradeMachine
from agent.protocol.records import CaptureRec, PoseRec, Record
from agent.runtime.core.departing import Departing
from agent.runtime.core.events import (
    Answer,
    Asking,
    Depart,
    Effect,
    Event,
    Farewell,
    Fix,
    Leave,
    Listen,
    Liveliness,
    Publish,
    Query,
    Reply,
    Sample,
    Start,
    Tick,
)
from agent.runtime.core.published import agent_state
from agent.runtime.core.shared import AgentConfig, Phase, Shared, vec3
from agent.runtime.core.standing import Standing, standing
from agent.runtime.core.vehicle import SettleTest, VehicleView
from agent.runtime.ends.completion import Completion
from agent.runtime.ends.joining import Joining
from agent.runtime.ends.membership import Membership
from agent.runtime.ends.pose_interest import PoseInterest
from agent.runtime.ends.trade_client import TradeClient
from agent.runtime.ends.trade_server import TradeServer
from agent.runtime.fencing.adoption import Adoption
from agent.runtime.moves.coverage import CoverageMoves
from agent.runtime.moves.drivers import strategy_driver
from agent.runtime.moves.handover import HandOver
from agent.runtime.moves.inspecting import Inspecting
from agent.runtime.moves.move import MoveContext
from agent.runtime.moves.planning import Planning
from agent.runtime.moves.shots import inspection_event
from agent.runtime.moves.work_taker import WorkTaker
from agent.strategy.registry import moves_of
from agent.wire import keys
from agent.wire.codec import Codec, RateLimitedLogger, RejectCounter
from agent.wire.peer import (
    AgentState,
    MissionStatus,
    Pose,
    Publication,
    Request,
)
from agent.wire.peer import Reply as ReplyMsg
from agent.world.inputs import World

__all__ = ["AgentCore", "MotionFn"]

Array = NDArray[np.float64]

_log = logging.getLogger(f"viscover.{__name__}")

#: Optional replacement of the planner for protocol tests: ``motion() -> converged``.
MotionFn = Callable[[], bool]


class AgentCore:
    """One agent's state and decisions (see the module docstring).

    Args:
        agent_id: this agent's id (in the scenario, or joining with ``join``).
        scenario: the mission.
        replayed: the records of its journal, in order (empty on a first start).
        config: constants.
        world: the mission's structure, prepared (:func:`agent.world.prepare.prepare_world`).
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
        config: AgentConfig,
        world: World,
        *,
        hedging: bool = False,
        wall: float = 0.0,
        motion: MotionFn | None = None,
        settle: SettleTest | None = None,
        join: AgentSpec | None = None,
    ) -> None:
        specs = {a.id: a for a in scenario.agents}
        config = config.for_team(len(specs))  # the state period of a large team
        if join is not None:
            specs[agent_id] = join
            config = dataclasses.replace(config, require_all=False)  # nobody waits for it
        self.id = agent_id
        self.cfg = config
        self.shared = s = Shared(agent_id, scenario, config, world)
        self.rejects = RejectCounter()
        log = RateLimitedLogger(logging.getLogger(f"viscover.agent.{agent_id}.rx"),
                                clock=lambda: s.now)  # mission time, stepped in
        c_req: Codec[Request] = Codec(Request, counter=self.rejects, log=log)
        c_rep: Codec[ReplyMsg] = Codec(ReplyMsg, counter=self.rejects, log=log)
        self.c_pub: Codec[Publication] = Codec(Publication, counter=self.rejects, log=log)
        s.open_ledger(replayed := list(replayed), specs[agent_id].landmarks, wall)
        spec = specs[agent_id]
        lp = s.machine.last_pose  # a restart: where the journal last saw it, until a fix
        self.pose = pose = VehicleView(Fix(
            np.asarray(spec.p0 if lp is None else lp.p, dtype=np.float64),
            np.asarray(spec.v0 if lp is None else lp.v, dtype=np.float64),
            0.0 if lp is None else float(lp.t)), s.act)

        self.completion = Completion(s)
        s.on_success.append(self.completion.restart)
        self.members = members = Membership(s, self.c_pub, self.completion.restart)
        pose_now = pose.current
        self.client = TradeClient(s, hedging, members, c_req, c_rep, pose_now)
        self.adoption = Adoption(s, members, self.client, c_req, pose_now, self.completion)
        #: re-splits leg by leg, and the stages (the registered moves build on them)
        self.moves = CoverageMoves(s, members, c_req, pose_now)
        self.planning = Planning(s, scenario, members, pose, self._owned, motion, settle,
                                 self.moves.in_move_stage)
        self.adoption.on_adopted.append(self.planning.arm_relocation)
        ins: Inspecting | None = None
        if scenario.inspection is not None:
            self.planning.inspecting = ins = Inspecting(
                agent_id, scenario, world, pose, s.owned_rows, self.planning.others,
                s.record_capture, [r for r in replayed if isinstance(r, CaptureRec)], config)
            members.state_hooks.append(ins.on_peer_state)
        if join is not None:
            s.partners.reset(())  # partners come as they admit it (Joining)
        self.joining = Joining(s, members, self.client, c_req, pose_now, joiner=join is not None)
        self.completion.waiting = self.adoption.waiting
        self.taker = None if ins is None else WorkTaker(ins, s, members, self.moves)
        self.completion.next_stage = self.moves.next_stage
        self.client.on_no_trade.append(self.moves.after_no_trade)
        #: the strategy's registered moves, tried in order each tick (agent.runtime.moves)
        self.driver = strategy_driver(
            moves_of(scenario.strategy, scenario.inspection is not None),
            MoveContext(s, members, c_req, pose_now, self.vision, self.moves, ins, self.taker))
        self.server = TradeServer(s, members, self.client, self.adoption, self.joining, c_req,
                                  c_rep, pose_now, self.driver.terms)
        self.interest = self.server.poses.interest = PoseInterest(s, members)  #: pose streams
        self._owned_rev = -1
        self._owned_lm: Landmarks = s.geo.subset(np.zeros(0, dtype=np.intp))
        self._seq = self._pose_seq = 0
        self._next_state = self._next_soon = 0.0  # the next periodic state; changes' gap
        self._next_pose_rec = 0.0
        self.started = False  #: publishing (after :class:`Start`, until it leaves)
        self._tick: Asking[None] | None = None  #: the tick waiting for an answer
        self.departing: Departing | None = None  #: leaving the mission (a Depart event)
        self._out: list[Effect] = []  #: effects of the step under way

    # -- views -----------------------------------------------------------------------------
    @property
    def phase(self) -> Phase:
        """optimising, converged, trading (our offer pending) or in_doubt (prepared)."""
        return self.shared.phase

    @property
    def machine(self) -> TradeMachine:
        """The ledger: the trade state machine (tests and diagnostics read it)."""
        return self.shared.machine

    @property
    def waiting(self) -> bool:
        """Whether the tick waits for an answer (to an ask, or a computation's result)."""
        return self._tick is not None

    def _owned(self) -> Landmarks:
        """Our landmarks (column layout), rebuilt only when the ledger changed."""
        if self._owned_rev != (s := self.shared).ledger_rev:
            self._owned_lm = s.geo.subset(s.geo.rows(s.machine.owned_arrays()[0]))
            self._owned_rev = s.ledger_rev
        return self._owned_lm

    def vision(self) -> float:
        """Eq. 3.4: this agent's vision of its owned landmarks at its current pose (with
        occlusion, of those the structure does not hide)."""
        (p, v, _), lm = self.pose.current(), self._owned()
        if lm.m == 0:
            return 0.0
        each = per_landmark_cols(p, v, lm, self.shared.geo.term)
        return float(self.planning.structure.seen_vision(each, np.asarray(p), lm).sum())

    def standing(self, seen: bool) -> Standing:
        """This agent now (``seen``: what it sees too), one snapshot (:mod:`.standing`)."""
        done, ad = self.completion, self.adoption
        return standing(self.shared, self.members, self.pose, self.planning.inspecting,
                        self.vision() if seen else None, self.rejects.total, done.complete,
                        done.completed_at, ad.rounds, ad.final_word.gave_up)

    def take_unpersisted(self) -> list[Effect]:
        """The records and actions made outside a step (start-up, a hand-over), in order."""
        return list(self.shared.take_outbox())

    # -- the one entry -----------------------------------------------------------------------
    def step(self, event: Event) -> list[Effect]:
        """Take ``event``; the effects to carry out, in order (see :mod:`agent.runtime.core.events`;
        every record to persist comes before the message that depends on it)."""
        self.shared.advance(event.now)
        # a departure after the journal failed: nothing more to persist, still say it
        failed = isinstance(event, Depart) and self.shared.failed is not None
        self._out = [] if failed else self.take_unpersisted()
        if isinstance(event, Tick | Start):
            self.pose.fix = event.fix
        if (ins := self.planning.inspecting) is not None:  # camera, evidence of captures
            inspection_event(ins.judge, ins.caps, event)
        if isinstance(event, Tick):
            if self._tick is not None:
                raise RuntimeError(f"agent {self.id}: tick stepped while one waits for an answer")
            self._resume(self._ticking(event.now), None)
        elif isinstance(event, Answer):
            if self._tick is None:
                raise RuntimeError(f"agent {self.id}: an answer stepped with nothing waiting")
            self._resume(self._tick, event)
        elif isinstance(event, Query):
            reply = self.server.on_query(event)
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
        elif isinstance(event, Depart):
            self._depart(event)
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
        if (s := self.shared).failed is not None:  # a query hit a journal failure: leave
            raise s.failed
        yield from self.joining.tick(now)
        yield from self.adoption.tick(now)
        if self.departing is not None:
            self._departure_step(now)
        if s.machine.fenced_out is not None and self.started:
            self.started = False
            self._out.append(Leave())  # lost to the team: it leaves the mission
        # frozen by a fence round, fenced out, not admitted yet: no trade steps
        trades = not s.machine.frozen and s.machine.fenced_out is None and self.joining.admitted
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

    # -- leaving -----------------------------------------------------------------------------
    def _depart(self, event: Depart) -> None:
        """Start leaving (:mod:`agent.runtime.core.departing`): at once, or after handing the work
        over in the next ticks."""
        if self.departing is None:
            handing = event.hand_over_s > 0.0
            self.departing = Departing(
                self.shared, event, self._put, self.planning.inspecting if handing else None,
                HandOver(self.shared, self.members, self.moves, self.pose) if handing else None)
        self._departure_step(event.now)

    def _departure_step(self, now: float) -> None:
        """Step the departure under way (its records, then its messages)."""
        assert self.departing is not None
        self._flush()
        if (done := self.departing.step(now)) is not None:
            self._out.append(done)

    def completion_blocker(self, now: float) -> str:
        """Why the mission is not complete in this agent's view (diagnostics)."""
        return self.completion.blocker(now, self.members)

    # -- publications ------------------------------------------------------------------------
    def state_message(self) -> AgentState:
        """This agent's state now."""
        self._seq += 1
        ins = self.planning.inspecting
        return agent_state(self.shared, self._seq, self.pose, self.vision(), self.rejects.total,
                           self.completion.complete, self.adoption.claims,
                           {**self.driver.published(), **({} if ins is None else ins.published())})

    def _publish(self, now: float, force: bool = False) -> None:
        """Our pose (while it moves or with the state), state (changed or due) and status (on
        completion) as :class:`Publish` effects; the pose journaled once a period."""
        if not self.started:
            return
        s, m = self.shared, self.cfg.mission
        status: MissionStatus | None = None
        state: AgentState | None = None
        due = force or now >= self._next_state or (s.dirty and now >= self._next_soon)
        moving = s.phase == "optimising"
        if now >= self._next_pose_rec:
            p, v, t = self.pose.current()
            s.persist([PoseRec(p=vec3(p), v=vec3(v), t=float(t))], sync=False)
            self._next_pose_rec = now + self.cfg.pose_journal_period_s
        if due:
            s.take_publish_soon()
            state = self.state_message()
            self._next_state = now + self.cfg.state_period_s
            self._next_soon = now + self.cfg.state_gap_s
            done = self.completion
            if done.announce or (done.complete and force):
                done.announce = False
                status = MissionStatus(
                    sender=self.id, t=now, complete=done.complete,
                    coverage=self.members.coverage_estimate(self.vision()),
                    agents=sorted(self.members.live | {self.id}))
        self._flush()
        if (peers := self.interest.update(self.pose.current()[0], now)) is not None:
            self._out.append(Listen(peers))  # the neighbours' pose streams
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
        (c := self.shared.counters).published += 1
        c.bytes_out += len(payload)
