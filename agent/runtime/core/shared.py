"""What the parts of one agent core share: the ledger (the trade state machine and the records
it still has to persist), the partner list of section 4.5, the one offer in flight, the
optimisation flag, the completion stage, counters, and the landmark geometry
(:mod:`agent.runtime.core.geometry`). No lock and no I/O: the core
(:class:`~agent.runtime.core.agent_core.AgentCore`) is stepped by one caller at a time.

The parts are :class:`~agent.runtime.ends.trade_client.TradeClient`,
:class:`~agent.runtime.ends.trade_server.TradeServer`,
:class:`~agent.runtime.ends.membership.Membership`,
:class:`~agent.runtime.ends.completion.Completion` and the strategy's parts;
:class:`~agent.runtime.core.agent_core.AgentCore` owns them. They read :class:`Shared`'s attributes
but
change them only through its named methods (``publish_soon``, ``begin_offer``,
``end_offer``, ``converge``, ``enter_stage``, ``journal``...; ``tests/test_layers.py`` checks
that no other module assigns one), so every change of the shared state is found here. Every
ledger change goes through :meth:`Shared.journal`, which queues its records; the core hands
them out as a :class:`~agent.runtime.core.events.Persist` effect ahead of any message that depends
on them, and the runtime persists them (fsynced when durable) before it sends that message.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass, field, replace
from typing import Any, ClassVar, Final, Literal, Protocol

import numpy as np
from numpy.typing import NDArray

from agent.config.scenario import Scenario
from agent.core.coverage_moves import Goal
from agent.core.trading import PartnerList
from agent.protocol.machine import Outcome, Step, TradeMachine
from agent.protocol.records import CaptureRec, GenesisRec, Record
from agent.runtime.core.events import Hold, Persist, Trigger
from agent.runtime.core.geometry import Geometry
from agent.strategy.potential import MAX_RELOCATIONS, REGROUPS_PER_MEMBER, TEAM_MOVES, TRIPLES
from agent.wire.peer import pack_arrays
from agent.wire.signing import SigningKeys
from agent.world.inputs import World

Array = NDArray[np.float64]
IntArray = NDArray[np.int64]
Phase = Literal["optimising", "converged", "trading", "in_doubt"]


#: peers whose periodic states a drone hears at the full state rate (5 Hz); in larger teams
#: the state period stretches (:meth:`AgentConfig.for_team`)
STATE_PEERS: Final = 4


@dataclass
class AgentConfig:
    """Runtime constants (mission seconds unless stated)."""

    mission: str = "default"
    #: real seconds a query waits for its reply: the largest retransmission timeout (RTO) of
    #: a trade query, measured from round trips (agent.runtime.ends.trade_client), and the RTO
    #: until one is measured
    request_timeout_s: float = 0.3
    rto_min_s: float = 0.01  #: smallest RTO [real s] of a trade query
    #: copies of a trade query per try, one hedge delay apart (0: one query per try, waiting
    #: request_timeout_s, retried after the back-off: the legacy timing)
    request_copies: int = 6
    max_offer_tries: int = 8  #: tries of one Offer to a partner not seen alive
    max_offer_tries_live: int = 30  #: tries when the partner's liveliness token is present
    backoff_s: float = 0.05  #: first retry delay, doubled per try
    backoff_cap_s: float = 0.4  #: largest retry delay
    busy_retries: int = 30  #: Busy("trading") answers tolerated per partner
    #: after a Busy("trading") answer make no offer for this many times the measured length
    #: of our offers (jittered; 0: offer again at once), so that we can accept theirs
    busy_pause: float = 1.0
    doubt_delay_s: float = 0.2  #: wait before a prepared responder asks the initiator
    state_period_s: float = 0.2  #: state publication period (5 Hz at real time)
    #: shortest time between two states (0: a change is published at the next tick)
    state_gap_s: float = 0.0
    pose_journal_period_s: float = 1.0  #: how often the pose goes to the journal
    fresh_periods: float = 10.0  #: a state older than this many periods is stale
    complete_hold_periods: float = 3.0  #: completion must hold this long before reported
    require_all: bool = True  #: completion needs every scenario agent seen alive once
    departure_grace_periods: float = 10.0  #: no completion this long after a departure
    exit_linger_periods: float = 6.0  #: an exiting agent stays this long after completion
    final_repeats: int = 10  #: copies of the final state sent on exit (lossy links)
    freeze_s: float = 5.0  #: a fence-round voter stays frozen this long at most
    #: the longest wait for the team's final word (the router's fence record) before the
    #: mission may be reported complete (0: not asked, the in-memory missions;
    #: agent.runtime.fencing.final_word)
    final_word_s: float = 0.0
    #: a peer whose liveliness token is present but that published no state for this long
    #: counts as gone (a forged or stuck token holds nothing up for ever; agent.runtime.
    #: membership)
    silent_s: float = 10.0
    #: how far the pose in an offer may be from the initiator's freshest published pose (or
    #: the ground station's mocap of it) [m], and its camera direction [rad]
    #: (agent.runtime.ends.pose_check)
    pose_tolerance_m: float = 0.5
    pose_tolerance_rad: float = 0.35
    #: strategy "potential": flights to a better viewpoint per agent, and re-splits an
    #: agent may initiate per team member (bounds that make every run terminate)
    max_relocations: int = MAX_RELOCATIONS
    regroups_per_member: int = REGROUPS_PER_MEMBER
    #: when no pair re-split helps, try 3-member ones (agent.runtime.moves.coverage)
    triples: bool = TRIPLES
    team_moves: int = TEAM_MOVES  #: whole-team re-split rounds after the pair moves (teams of ≥ 4)
    seed: int = 0  #: seeds the backoff jitter
    #: mission seconds per real second of the clock the runtime steps the core by (set by
    #: :meth:`scaled`; the real-time bounds the core keeps, e.g. a mocap sample's age)
    time_scale: float = 1.0
    #: this agent's trade-signing key and the team's public keys (None: unsigned, open lab)
    signing: SigningKeys | None = None

    #: Periods that are real-time behaviour: scaled into mission seconds by :meth:`scaled`.
    REAL_TIME_PERIODS: ClassVar[tuple[str, ...]] = (
        "backoff_s", "backoff_cap_s", "doubt_delay_s", "state_period_s", "state_gap_s",
        "pose_journal_period_s", "freeze_s", "final_word_s", "silent_s")

    def for_team(self, n: int) -> AgentConfig:
        """This configuration in a team of ``n`` drones: once more than :data:`STATE_PEERS`
        peers publish, the state period stretched by k = (n - 1) / STATE_PEERS (every window
        counted in state periods stretches with it) and states, changes included, at least
        half a stretched period apart, so that a drone hears at most 2·STATE_PEERS states per
        unstretched period whatever the team."""
        k = max(1.0, (n - 1) / STATE_PEERS)
        return self if k == 1.0 else replace(self, state_period_s=self.state_period_s * k,
                                             state_gap_s=self.state_period_s * k / 2.0)

    def scaled(self, time_scale: float) -> AgentConfig:
        """The same real-time behaviour on a clock running ``time_scale`` times faster: every
        period of :attr:`REAL_TIME_PERIODS` multiplied by ``time_scale`` (mission seconds)."""
        return replace(self, time_scale=time_scale,
                       **{name: getattr(self, name) * time_scale
                          for name in self.REAL_TIME_PERIODS})


class JournalLike(Protocol):
    """What the runtime needs of :class:`agent.storage.journal.Journal`."""

    def replay(self) -> list[Record]: ...

    def append(self, records: Iterable[object], sync: bool | None = None) -> None: ...


#: How an offer of ours ended: the machine's outcome (:data:`Outcome`), or the runtime gave it
#: up: ``"timeout"`` (no answer after its tries) or ``"yield"`` (both offered to each other
#: and our id is the larger).
AttemptEnd = Outcome | Literal["timeout", "yield"]


@dataclass
class RuntimeCounters:
    """Counters of one agent process (the ones in :class:`agent.wire.peer.Counters` plus
    details)."""

    busy: int = 0
    timeouts: int = 0
    requests: int = 0
    bytes_out: int = 0
    published: int = 0
    offers_sent: int = 0
    outcomes: dict[str, int] = field(default_factory=dict)

    #: offers to us answered Busy because their set disagreed with the published ledgers,
    #: by reason (:meth:`agent.runtime.ends.trade_server.TradeServer._check_ledger`)
    unconfirmed: dict[str, int] = field(default_factory=dict)
    #: entries evicted from the bounded per-sender tables a peer can grow (the seal's replay
    #: memory); published in :attr:`agent.wire.peer.Counters.evicted`
    evicted: int = 0

    def count(self, outcome: AttemptEnd) -> None:
        """One more trade outcome ``outcome``."""
        self.outcomes[outcome] = self.outcomes.get(outcome, 0) + 1

    def unconfirmed_offer(self, why: str) -> None:
        """One more offer whose set the published ledgers did not confirm (``why``)."""
        self.unconfirmed[why] = self.unconfirmed.get(why, 0) + 1


@dataclass
class Attempt:
    """This agent's offer in flight: trade id, partner, encoded Offer, tries, next due time."""

    trade_id: str
    partner: str
    payload: bytes
    tries: int = 0
    due: float = 0.0
    regroup: bool = False  #: a re-split or one of its legs (agent.runtime.moves.coverage)
    outcome: AttemptEnd = ""  #: how it ended (not yet: "")


class Shared:
    """State shared by the parts of one agent core (see the module docstring)."""

    def __init__(self, agent_id: str, scenario: Scenario, config: AgentConfig,
                 world: World) -> None:
        self.id = agent_id
        self.sc = scenario
        self.cfg = config
        #: mission time [s] of the event being stepped (the core's only time)
        self.now = 0.0
        #: records to persist and actions made and not yet handed out as effects, in order
        self.outbox: list[Persist | Hold | Trigger] = []
        self.world = world  #: the mission's structure, prepared outside the core
        self.geo = Geometry(scenario, world.model)
        self.order = [a.id for a in scenario.agents]
        self.machine = TradeMachine(agent_id, self.geo.ids)
        # A scenario with trading = false runs pose optimisation only: no partners; nor does
        # an inspection mission trade by vision (Algorithm 7): its drones capture tours.
        self.vision_trades = scenario.trading and scenario.inspection is None
        self.partners = PartnerList(agent_id, tuple(self.order) if self.vision_trades else ())
        self.optimising = True
        self.attempt: Attempt | None = None
        self.counters = RuntimeCounters()
        self.dirty = True  #: the state must be published at the next tick
        self.ledger_rev = 0  #: bumped at every journaled ledger change
        #: called after a successful trade, e.g. to clear retry back-offs
        self.on_success: list[Callable[[], None]] = []
        #: called after every ledger change, for test probes
        self.on_change: Callable[[], None] | None = None
        #: the journal failed (disk full, I/O error): answer nothing more, leave the mission
        self.failed: Exception | None = None
        #: the completion stage (published; completion holds within one stage): 2 once the
        #: thesis stage completed and coverage moves are on (strategy "potential"), one more
        #: per whole-team re-split round (agent.runtime.moves.coverage owns the stages)
        self.stage = 1
        #: our pose after each pending pair re-split (trade id -> goal), and the goal of a
        #: committed one for the planner to fly to
        self.regroup_goals: dict[str, Goal] = {}
        self.next_goal: Goal | None = None

    @property
    def phase(self) -> Phase:
        """optimising, converged, trading (our offer pending) or in_doubt (prepared)."""
        if self.machine.prepared:
            return "in_doubt"
        if self.attempt is not None or self.machine.offering:
            return "trading"
        return "optimising" if self.optimising else "converged"

    # -- how the parts change the shared state (tests/test_layers.py: nothing else assigns) --
    def advance(self, now: float) -> None:
        """The event being stepped happens at mission time ``now`` [s] (never earlier than the
        last one: a sample read before a tick may be stepped after it)."""
        self.now = max(self.now, now)

    def publish_soon(self) -> None:
        """What our state says changed: publish it at this tick, not at the next period."""
        self.dirty = True

    def take_publish_soon(self) -> bool:
        """Whether :meth:`publish_soon` was called since the last publication (cleared)."""
        due, self.dirty = self.dirty, False
        return due

    def watch_changes(self, probe: Callable[[], None] | None) -> None:
        """Call ``probe`` after every ledger change (test probes, invariant checks)."""
        self.on_change = probe

    def fail(self, error: Exception) -> None:
        """The journal failed (disk full, I/O error): answer nothing more, leave."""
        self.failed = error

    def converge(self) -> None:
        """The planner step moved nothing (figure 4.1b): converged, published."""
        self.optimising = False
        self.publish_soon()

    def optimise_again(self) -> None:
        """Optimise the pose again (new landmarks, a new pose to improve), published."""
        self.optimising = True
        self.publish_soon()

    def begin_offer(self, attempt: Attempt) -> None:
        """``attempt`` is our one offer in flight (a trade, a re-split leg or a pull), driven
        by the trade client until it ends."""
        self.attempt = attempt

    def end_offer(self) -> None:
        """Our offer in flight ended (or was given up): none now."""
        self.attempt = None

    def expect_goal(self, trade_id: str, goal: Goal) -> None:
        """If trade ``trade_id`` (a re-split leg) commits, fly to ``goal``."""
        self.regroup_goals[trade_id] = goal

    def forget_goal(self, trade_id: str) -> None:
        """Trade ``trade_id`` ended without committing: no flight for it."""
        self.regroup_goals.pop(trade_id, None)

    def fly_to(self, goal: Goal) -> None:
        """The planner's next transit goal, taken by :meth:`take_goal`."""
        self.next_goal = goal

    def take_goal(self) -> Goal | None:
        """The planner's next transit goal, if any (cleared)."""
        goal, self.next_goal = self.next_goal, None
        return goal

    def enter_stage(self, stage: int) -> None:
        """Strategy stages (agent.runtime.moves.coverage): we are in ``stage`` now, published."""
        self.stage = stage
        self.publish_soon()

    def journal(self, step: Step) -> None:
        """Queue the records of a machine step (if any) to be persisted and mark the state
        changed."""
        if step.records:
            self.persist(step.records)
            self.ledger_rev += 1
            self.publish_soon()

    def persist(self, records: Iterable[object], sync: bool | None = None) -> None:
        """Queue ``records`` to be persisted before the next message this core sends."""
        self.outbox.append(Persist(tuple(records), sync))

    def act(self, effect: Hold | Trigger) -> None:
        """Queue an action on the vehicle, carried out after every record queued before it."""
        self.outbox.append(effect)

    def take_outbox(self) -> list[Persist | Hold | Trigger]:
        """The records and actions queued so far, in order (cleared)."""
        out, self.outbox = self.outbox, []
        return out

    def owned_rows(self) -> NDArray[np.intp]:
        """Rows (into the scenario's landmarks) of what this agent owns now."""
        return self.geo.rows(self.machine.owned_arrays()[0])

    def record_capture(self, rec: CaptureRec) -> None:
        """Our new captures, persisted (fsynced) before any state names them."""
        self.persist([rec], sync=True)
        self.machine.apply(rec)
        self.publish_soon()

    def changed(self) -> None:
        """Tell the probe that the ledger changed."""
        if self.on_change is not None:
            self.on_change()

    def committed(self, trade_id: str) -> None:
        """A trade of ours committed: if it was a pair re-split, fly to our pose in it."""
        goal = self.regroup_goals.pop(trade_id, None)
        if goal is not None:
            self.next_goal = goal

    def after_success(self, hook: Callable[[], None]) -> None:
        """Call ``hook`` after every successful trade of ours (a move's own bookkeeping)."""
        self.on_success.append(hook)

    def success(self) -> None:
        """Section 4.5: after a successful trade reset the list and optimise again."""
        self.partners.reset()
        self.optimising = True
        for hook in self.on_success:
            hook()

    def open_ledger(self, replayed: Iterable[Record], rows: NDArray[np.intp],
                    wall: float = 0.0) -> None:
        """Durable state at start-up (Unix time ``wall`` [s]): apply the journal's ``replayed``
        records; on a first start the genesis (the landmarks at scenario ``rows``, version 0);
        then a new incarnation (both queued to be persisted, fsynced)."""
        for rec in replayed:
            self.machine.apply(rec)
        if not self.machine.genesis:
            lids = np.sort(self.geo.ids[rows])
            gen = GenesisRec(agent=self.id,
                             owned=pack_arrays(lids, np.zeros(lids.size, dtype=np.int64)))
            self.machine.apply(gen)
            self.persist([gen], sync=True)
        self.persist(self.machine.recover(wall), sync=True)

    def crash_loop(self, window_s: float = 300.0, starts: int = 3) -> str | None:
        """One line if this agent started ``starts`` times or more within ``window_s`` [s]
        (its journal's start records): a crash loop to report, not to hide."""
        walls = [w for w in self.machine.start_walls if w > 0.0]
        recent = [w for w in walls if walls[-1] - w <= window_s]
        if len(recent) < starts:
            return None
        return (f"started {len(recent)} times within {walls[-1] - recent[0]:.0f} s "
                f"(incarnation {self.machine.incarnation}): it keeps failing, see its log; the "
                "team adopts its landmarks if it stays away longer than lost_after")

    def quiet(self) -> bool:
        """Converged, nobody left to try, nothing pending: this agent's part of completion."""
        return self.phase == "converged" and not self.partners.pending \
            and not self.machine.pending_ids


def vec3(a: Any) -> tuple[float, float, float]:
    """A 3-vector as a tuple of floats (wire form)."""
    return (float(a[0]), float(a[1]), float(a[2]))


def unit_ok(v: tuple[float, float, float]) -> bool:
    """Whether a direction received from the network is (nearly) unit length."""
    n: float = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]) ** 0.5  # of a sum of squares: real
    return 0.9 < n < 1.1
