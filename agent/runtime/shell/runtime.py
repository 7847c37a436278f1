"""The agent runtime: carries one :class:`~agent.runtime.core.agent_core.AgentCore`'s effects out
over a
:class:`~agent.net.transport.Transport` and a journal (raft's Ready loop: persist, then send,
then feed the replies back).

:class:`AgentRuntime` declares the agent's queryable, subscriptions and liveliness token and
steps what arrives into the core as events; it persists the records of every step (fsynced
when durable) before it publishes, replies or asks anything after them; it sends the core's
asks and steps the replies back in as answers. The core holds every decision and has no lock:
the runtime lets one thread step it at a time (``turn``, re-entrant) and never holds the turn
while an ask waits for its reply, so the core answers queries meanwhile and two agents
querying each other cannot deadlock.

Threading: :meth:`AgentRuntime.tick` runs on the caller's thread (the process loop of
:mod:`agent.runners.process`, or a test driving a :class:`~agent.net.memory.MemoryNetwork`);
queries, samples and liveliness changes are stepped on the transport's threads.

Times: ``clock.now()`` is mission time [s]; ``config.request_timeout_s`` is a real-time
transport timeout [s]; every other period in :class:`AgentConfig` is mission time.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import replace
from typing import TypeVar

import numpy as np

from agent.clock import Clock
from agent.config.scenario import AgentSpec, Scenario
from agent.net.contract import Declared, HedgingTransport, Transport
from agent.runtime.core.agent_core import AgentCore, MotionFn
from agent.runtime.core.events import (
    Answer,
    Ask,
    AskHedged,
    Asking,
    Command,
    Compute,
    Departed,
    Effect,
    Event,
    Farewell,
    Hold,
    ImageTaken,
    Leave,
    Listen,
    Liveliness,
    Persist,
    Publish,
    Reply,
    Sample,
    SampleKind,
    Start,
    Tick,
    Trigger,
    Wait,
)
from agent.runtime.core.shared import AgentConfig, JournalLike, Phase
from agent.runtime.core.standing import Standing
from agent.runtime.shell.pose import KinematicPoseSource, PoseSource, SettleTest, carry_out, fix_of
from agent.runtime.shell.sealing import ask_sealed, open_query, seal_reply, trade_seal
from agent.storage.journal import JournalFailed
from agent.wire import keys
from agent.wire.peer import AgentState
from agent.world.inputs import World
from agent.world.prepare import prepare_world

__all__ = ["AgentConfig", "AgentRuntime", "MotionFn", "SettleTest"]

_log = logging.getLogger(f"viscover.{__name__}")

T = TypeVar("T")


class AgentRuntime:
    """One agent process's runtime around its core (see the module docstring).

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
        on_change: called after every ledger change, for test probes.
        join: the spec of a drone not in the scenario joining a running mission.
        world: the mission's structure prepared for the core (None: prepared here,
            :func:`agent.world.prepare.prepare_world`).
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
        world: World | None = None,
    ) -> None:
        keys.validate_id(agent_id)
        specs = {a.id: a for a in scenario.agents}
        if join is not None and agent_id in specs:  # a drone not in the scenario joins
            raise ValueError(f"agent {agent_id!r} is in scenario {scenario.name!r}: it "
                             "takes part from the start, it cannot join")
        spec = join if join is not None else specs.get(agent_id)
        if spec is None:
            raise ValueError(f"agent {agent_id!r} is not in scenario {scenario.name!r}")
        self.id = agent_id
        self.sc = scenario
        self.tp = transport
        self.journal = journal
        self.clock = clock
        self.turn = threading.RLock()  #: held by whoever steps the core
        #: how the drone left the mission, once it has (a Depart event stepped in)
        self.departed: Departed | None = None
        #: the camera: told the landmark ids of each capture once its record is persisted
        #: (a flying inspection drone's, agent.runners.flying; None: no camera)
        self.on_trigger: Callable[[list[int]], object] | None = None
        #: the camera confirms each image (CAMERA_IMAGE_CAPTURED / CAMERA_FEEDBACK): captures
        #: count only once :meth:`image_taken` says so (set before :meth:`start`)
        self.camera_confirms = False
        replayed = journal.replay()
        self.pose: PoseSource = pose or KinematicPoseSource(spec.p0, spec.v0, clock,
                                                            scenario.space)
        cfg = replace(config or AgentConfig(), time_scale=clock.time_scale)
        self.core = core = AgentCore(
            agent_id, scenario, replayed, cfg, world or prepare_world(scenario),
            hedging=isinstance(transport, HedgingTransport), wall=time.time(), motion=motion,
            settle=settle, join=join)
        resumed = core.shared.machine.last_pose  # a restart: the kinematic vehicle is
        if resumed is not None and isinstance(self.pose, KinematicPoseSource):  # where it was
            self.pose.p, self.pose.v = np.array(resumed.p), np.array(resumed.v)
        self.cfg = core.cfg
        self.settle = settle
        #: seals our trade requests and replies, opens the peers' (None: open profile)
        self.seal = trade_seal(self.cfg, agent_id)
        self._carry_out(core.take_unpersisted())  # the genesis and this incarnation
        if (loop := core.shared.crash_loop()) is not None:
            _log.warning("agent %s: %s", agent_id, loop)
        if on_change is not None:
            core.shared.watch_changes(lambda: on_change(self))
        self._handles: list[Declared] = []
        #: one subscription per peer whose pose stream we hear (the core's :class:`Listen`),
        #: and the set last asked for, applied after the step (:meth:`_sync_poses`)
        self._pose_subs: dict[str, Declared] = {}
        self._listen: frozenset[str] | None = None
        self._subs_lock = threading.Lock()

    # -- views of the core (runners read standing(); tests read the core itself) ------------
    @property
    def phase(self) -> Phase:
        """optimising, converged, trading (our offer pending) or in_doubt (prepared)."""
        return self.core.phase

    @property
    def complete(self) -> bool:
        """Whether the mission is complete in this agent's view."""
        return self.core.completion.complete

    @property
    def completed_at(self) -> float | None:
        """Mission time completion was first reported [s]."""
        return self.core.completion.completed_at

    def vision(self) -> float:
        """Eq. 3.4: this agent's vision of its owned landmarks at its current pose."""
        with self.turn:
            return self.core.vision()

    def state_message(self) -> AgentState:
        """This agent's state now."""
        with self.turn:
            return self.core.state_message()

    def standing(self, seen: bool = False) -> Standing:
        """This agent now, as one snapshot (:mod:`agent.runtime.core.standing`; ``seen``: with
        what it sees, a vision evaluation): what the runners print and decide by."""
        with self.turn:
            return self.core.standing(seen)

    def completion_blocker(self, now: float) -> str:
        """Why the mission is not complete in this agent's view (diagnostics)."""
        with self.turn:
            return self.core.completion_blocker(now)

    # -- lifecycle -------------------------------------------------------------------------
    def start(self) -> None:
        """Declare the trade queryable, subscriptions and liveliness token; publish state."""
        m = self.cfg.mission
        tp = self.tp
        self._handles.append(tp.declare_queryable(keys.trade_key(m, self.id), self.on_query))
        # the peers' pose streams: the neighbours' only, as the core asks (Listen)
        self._handles.append(tp.subscribe(keys.all_agents(m, "state"), self._sampler("state")))
        self._handles.append(tp.watch_liveliness(keys.all_agents(m, "alive"), self._joined,
                                                 self._left))
        self._handles.append(tp.declare_liveliness(keys.alive_key(m, self.id)))
        if not isinstance(self.pose, KinematicPoseSource):  # flown: the mocap exists
            self._handles.append(tp.subscribe(keys.all_agents(m, "mocap"),
                                              self._sampler("mocap")))
        self.step(Start(self.clock.now(), fix_of(self.pose), camera=self.camera_confirms))

    def _sync_poses(self) -> None:
        """Hold a pose subscription for exactly the peers of the core's last :class:`Listen`
        (outside the turn: undeclaring may wait for a callback that waits for the turn)."""
        with self._subs_lock:
            want, self._listen = self._listen, None
            if want is None or not self._handles:  # nothing new, or stopped
                return
            for aid in set(self._pose_subs) - want:
                self._pose_subs.pop(aid).undeclare()
            for aid in sorted(want - set(self._pose_subs)):
                self._pose_subs[aid] = self.tp.subscribe(keys.pose_key(self.cfg.mission, aid),
                                                         self._sampler("pose"))

    def image_taken(self, ids: Sequence[int], ok: bool, reason: str = "") -> None:
        """The camera's word on the image asked for landmarks ``ids`` (a Trigger): taken or
        not (``reason``), stepped into the core (:class:`~agent.runtime.core.events.
        ImageTaken`), which journals a taken image's capture before it publishes it."""
        self.step(ImageTaken(self.clock.now(), tuple(int(i) for i in ids), ok, reason))

    def stop(self) -> None:
        """Undeclare everything (the transport and journal are closed by their owner)."""
        with self._subs_lock:  # no pose subscription is made after this
            handles = [*reversed(self._handles), *self._pose_subs.values()]
            self._handles.clear()
            self._pose_subs.clear()
        for h in handles:
            try:
                h.undeclare()
            except Exception:  # pragma: no cover - transport already closed
                _log.debug("undeclare failed", exc_info=True)
        with self.turn:
            self.core.started = False

    def _sampler(self, kind: SampleKind) -> Callable[[str, bytes], None]:
        def on_sample(key: str, payload: bytes) -> None:
            self.step(Sample(kind, key, payload, self.clock.now()))
        return on_sample

    def _joined(self, key: str) -> None:
        self.step(Liveliness(key, True, self.clock.now()))

    def _left(self, key: str) -> None:
        self.step(Liveliness(key, False, self.clock.now()))

    # -- carrying the core's effects out ----------------------------------------------------
    def step(self, event: Event) -> bytes | None:
        """Step ``event`` into the core and carry its effects out (an ask and the rest of a
        tick with it); the reply to a :class:`Query` (None: none). If the journal fails, the
        core answers nothing more: a tick raises the failure (the agent leaves), anything
        else is dropped unanswered (the record behind it is not durable)."""
        try:
            return self._step(event)
        except JournalFailed as e:
            with self.turn:
                self.core.fail(e)
            if isinstance(event, Tick | Start | Farewell):
                raise
            return None

    def _step(self, event: Event) -> bytes | None:
        with self.turn:
            reply, leave = self._carry_out(self.core.step(event))
        while isinstance(reply, Ask | AskHedged | Compute | Command):  # the tick waits:
            answer = self._ask(reply)  # without the turn
            with self.turn:
                reply, left = self._carry_out(self.core.step(answer))
            leave = leave or left
        if leave:  # fenced out: its token goes (undeclared without the turn)
            self.stop()
        elif isinstance(event, Tick | Start):  # a tick's publications: whose poses to hear
            self._sync_poses()
        return reply

    def on_query(self, payload: bytes, selector: str) -> bytes | None:
        """The reply to one trade query (the transport's query handler)."""
        query, to = open_query(self.seal, payload, selector, self.clock.now())
        return seal_reply(self.seal, self.step(query), to)

    def drive(self, part: Asking[T]) -> T:
        """Run one of the core's asking parts to its end outside a tick (a bench or test
        sending one request: ``rt.drive(rt.core.client.request(...))``), its asks sent as a tick's
        are and its records persisted before them."""
        answer: object = None
        while True:
            with self.turn:
                try:
                    ask = part.send(answer)
                except StopIteration as done:
                    self._carry_out(self.core.take_unpersisted())
                    result: T = done.value
                    return result
                self._carry_out(self.core.take_unpersisted())
            answer = self._ask(ask)

    def _carry_out(self, effects: list[Effect]) -> tuple[Wait | bytes | None, bool]:
        """Persist and publish ``effects``; the reply or what the tick waits for that ends
        them, and whether the agent leaves."""
        out: Wait | bytes | None = None
        leave = False
        for e in effects:
            if isinstance(e, Persist):
                self.journal.append(e.records, sync=e.sync)
            elif isinstance(e, Publish):
                try:
                    self.tp.publish(e.key, e.payload)
                except RuntimeError:  # transport closed under us (shutdown)
                    _log.debug("publish on closed transport ignored")
            elif isinstance(e, Listen):
                self._listen = e.peers
            elif isinstance(e, Reply):
                out = e.payload
            elif isinstance(e, Leave):
                leave = True
            elif isinstance(e, Hold):
                carry_out(self.pose, e)
            elif isinstance(e, Departed):
                self.departed = e
            elif isinstance(e, Trigger):
                if self.on_trigger is not None:
                    self.on_trigger(list(e.ids))
            else:
                out = e
        return out, leave

    def _ask(self, ask: Wait) -> Answer:
        """Send ``ask`` over the transport (sealed on the secured profile), run a
        :class:`Compute`, or fly a :class:`Command`; the answer to step back in."""
        if isinstance(ask, Compute):
            return Answer(ask.fn(), self.clock.now())
        if isinstance(ask, Command):
            return Answer(carry_out(self.pose, ask), self.clock.now())
        got = ask_sealed(self.seal, self.tp, ask, self.clock.now())
        return replace(got, now=self.clock.now())

    # -- main loop -------------------------------------------------------------------------
    def tick(self) -> None:
        """One planner period Δt (:class:`~agent.runtime.core.events.Tick`)."""
        self.step(Tick(self.clock.now(), fix_of(self.pose)))

    def exit_due(self, now: float) -> bool:
        """True once completion has held for ``exit_linger_periods`` state periods (peers and
        observers had time to hear it); the first time, the final state and mission status
        are sent ``final_repeats`` more times so that a lossy link still delivers one."""
        with self.turn:
            due, first = self.core.completion.exit_due(now)
        if first:
            self.step(Farewell(now))
        return due
