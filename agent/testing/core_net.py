"""Several agent cores (:class:`~agent.runtime.core.agent_core.AgentCore`) stepped by hand over a
model
network: no transport, no thread, no journal file. What a runtime does, done here in a few
lines so that a test chooses every message's fate: an ask's query may be lost, its reply lost,
the query duplicated; a publication lost or duplicated; any query or publication ever sent
delivered again later; an agent killed and restarted from its records (a process crash keeps
every record persisted; a power loss drops those after the last fsync).

Journals are lists of records; a :class:`~agent.runtime.core.events.Persist` with ``sync`` (or,
``None``, holding a durable record) marks everything up to it durable, as
:meth:`agent.storage.journal.Journal.append` fsyncs.

By default a tick's waits are answered at once (an ask's query delivered to its target, a
computation run, a command flown), as the in-memory transport does. With ``park`` they are
parked instead (:mod:`agent.testing.core_waits`): the core stays waiting, stepped every other
event meanwhile, until the test answers its wait (:meth:`CoreNet.answer`), late and in any
order across agents. An agent may also go away for good (:meth:`CoreNet.go_away`: its token
vanishes, it is stepped nothing more) and come back later from its journal; one that learns
the team fenced it out leaves once its tick ends, as the agent process does.
"""

from __future__ import annotations

import random
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np

from agent.clock import ManualClock
from agent.config.scenario import Scenario
from agent.mission.invariants import Claims, VersionHistory, snapshot_violations
from agent.protocol.records import DURABLE, Record
from agent.runtime.core.agent_core import AgentCore, MotionFn
from agent.runtime.core.events import (
    Answer,
    Ask,
    AskHedged,
    Command,
    Compute,
    Effect,
    Event,
    Leave,
    Listen,
    Liveliness,
    Persist,
    Publish,
    Query,
    Reply,
    Sample,
    Start,
    Tick,
    Trigger,
    Wait,
)
from agent.runtime.core.shared import AgentConfig
from agent.runtime.shell.pose import KinematicPoseSource, PoseSource, carry_out, fix_of
from agent.testing.core_waits import NOT_YET, Fate, How, Parked, WaitStats, hedged
from agent.wire import keys
from agent.world.prepare import prepare_world


@dataclass
class Disk:
    """One agent's journal: its records in order, the first ``durable`` of them fsynced."""

    records: list[Record] = field(default_factory=list)
    durable: int = 0

    def persist(self, effect: Persist) -> None:
        """Append ``effect``'s records (fsynced as the journal would)."""
        recs = [r for r in effect.records if isinstance(r, Record)]
        self.records += recs
        sync = effect.sync if effect.sync is not None else \
            any(isinstance(r, DURABLE) for r in recs)
        if sync:
            self.durable = len(self.records)

    def power_loss(self) -> None:
        """What a power loss leaves: the fsynced records."""
        del self.records[self.durable:]


LOSSLESS = Fate(random.Random(0))


class CoreNet:
    """The cores of scenario ``sc`` on a model network (see the module docstring).

    Args:
        sc: the mission.
        config: every core's constants.
        motion: planner replacement per agent id (None: the planner).
        park: park the ticks' waits until :meth:`answer` (False: answer them at once).
        hedging: the cores send trade queries as several copies (answered by the first).
    """

    def __init__(self, sc: Scenario, config: AgentConfig,
                 motion: Callable[[str], MotionFn] | None = None, *, park: bool = False,
                 hedging: bool = False) -> None:
        self.sc, self.cfg, self.motion = sc, config, motion
        self.park, self.hedging = park, hedging
        self.world = prepare_world(sc)  #: prepared once, shared by every core
        self.clock = ManualClock()
        self.disks = {a.id: Disk() for a in sc.agents}
        self.cores: dict[str, AgentCore] = {}
        self.vehicles: dict[str, PoseSource] = {}  #: each agent's kinematic vehicle
        self.triggers: list[tuple[str, tuple[int, ...]]] = []  #: camera triggers, in order
        self.queries: list[tuple[str, Query]] = []  #: every query sent (target, query)
        self.samples: list[Sample] = []  #: every publication sent
        self.history = VersionHistory()
        self.history_violations: list[str] = []  #: (landmark, version) pairs claimed twice
        self._forgotten: set[str] = set()
        #: steps whose effects put a record to persist after a message
        self.order_violations: list[str] = []
        self.parked: dict[str, Parked] = {}  #: each waiting agent's wait (``park``)
        self.stats = WaitStats()
        self.steps = 0  #: events stepped so far
        #: agents gone (token vanished, stepped nothing), their cores as they were
        self.away: dict[str, AgentCore] = {}
        self.left: set[str] = set()  #: agents that left the mission fenced out
        #: whose pose streams each core listens to (its last Listen)
        self.listening: dict[str, frozenset[str]] = {}
        self._leaving: set[str] = set()  #: agents whose tick under way said Leave
        self._seq = 0
        for a in sc.agents:
            self.boot(a.id)

    # -- agents ------------------------------------------------------------------------------
    def boot(self, aid: str) -> None:
        """Start ``aid`` from its journal; it and its peers see each other's tokens."""
        spec = next(a for a in self.sc.agents if a.id == aid)
        pose = KinematicPoseSource(spec.p0, spec.v0, self.clock, self.sc.space)
        core = AgentCore(aid, self.sc, list(self.disks[aid].records), self.cfg, self.world,
                         hedging=self.hedging,
                         motion=None if self.motion is None else self.motion(aid))
        self.away.pop(aid, None)
        self.left.discard(aid)
        self.listening.pop(aid, None)  # a new core: no pose stream until it asks
        resumed = core.shared.machine.last_pose
        if resumed is not None:
            pose.p, pose.v = np.array(resumed.p), np.array(resumed.v)
        self.cores[aid], self.vehicles[aid] = core, pose
        self.carry(aid, core.take_unpersisted(), LOSSLESS)
        self.step(aid, Start(self.clock.now(), fix_of(pose)), LOSSLESS)
        alive = keys.alive_key(self.cfg.mission, aid)
        now = self.clock.now()
        for other in self.cores:
            if other != aid:
                self.step(aid, Liveliness(keys.alive_key(self.cfg.mission, other), True, now),
                          LOSSLESS)
                self.step(other, Liveliness(alive, True, now), LOSSLESS)

    def crash(self, aid: str, power: bool = False) -> None:
        """Kill ``aid`` (``power``: a power loss) and start it again from its journal."""
        self.vanish(aid)
        if power:
            self.disks[aid].power_loss()
        self.boot(aid)

    def vanish(self, aid: str) -> AgentCore:
        """``aid``'s process ends: its wait dropped, its token gone for the others; its
        core."""
        core = self.cores.pop(aid)
        if self.parked.pop(aid, None) is not None:
            self.stats.dropped += 1
        self._leaving.discard(aid)
        alive = keys.alive_key(self.cfg.mission, aid)
        for other in list(self.cores):
            self.step(other, Liveliness(alive, False, self.clock.now()), LOSSLESS)
        return core

    def go_away(self, aid: str) -> None:
        """``aid`` goes away (a drone lost, a partition that does not heal): its token
        vanishes, it is stepped nothing more; its ledger stays its claims (in
        :attr:`away`) until the team fences it."""
        self.away[aid] = self.vanish(aid)

    def come_back(self, aid: str, power: bool = False) -> None:
        """``aid`` (away, or gone fenced out) starts again from its journal (``power``: what
        a power loss left of it)."""
        if power:
            self.disks[aid].power_loss()
        self.boot(aid)

    def depart(self, aid: str) -> None:
        """``aid`` learned that the team fenced it out: it leaves the mission (its process
        ends, :mod:`agent.runners.process`)."""
        self.vanish(aid)
        self.left.add(aid)

    # -- stepping ----------------------------------------------------------------------------
    def tick(self, aid: str, fate: Fate = LOSSLESS) -> None:
        """One tick of ``aid`` at the clock's time, its asks sent by ``fate``."""
        self.step(aid, Tick(self.clock.now(), fix_of(self.vehicles[aid])), fate)

    def step(self, aid: str, event: Event, fate: Fate) -> bytes | None:
        """Step ``event`` into ``aid``'s core and carry the effects out (a wait answered at
        once, as the in-memory transport does, or parked); the reply to a query."""
        core = self.cores.get(aid)
        if core is None:
            return None
        self.steps += 1
        out = self.carry(aid, core.step(event), fate)
        while isinstance(out, Ask | AskHedged | Compute | Command):
            if self.park:
                self._seq += 1
                self.parked[aid] = Parked(out, fate, self._seq, self.clock.now(), self.steps)
                st = self.stats
                st.parked += 1
                st.computes += isinstance(out, Compute)
                st.commands += isinstance(out, Command)
                return None
            got = self.resolve(aid, out, fate)
            out = self.carry(aid, core.step(Answer(got, self.clock.now())), fate)
        if isinstance(event, Tick | Answer) and (
                aid in self._leaving or core.shared.machine.fenced_out is not None):
            self.depart(aid)  # the tick ended: fenced out, it leaves
        return out if isinstance(out, bytes) else None

    def resolve(self, aid: str, wait: Wait, fate: Fate, how: How = "reply",
                early: object = NOT_YET) -> object:
        """The answer to ``aid``'s ``wait`` now: the reply to an ask (by ``fate`` and
        ``how``), a computation's result (``early`` if it ran before), the vehicle's fix
        after a command."""
        if isinstance(wait, Compute):
            return wait.fn() if early is NOT_YET else early
        if isinstance(wait, Command):
            return carry_out(self.vehicles[aid], wait)
        got = None if how == "timeout" else self.ask(wait, fate)
        if how == "late":
            got = None
        return hedged(wait, got) if isinstance(wait, AskHedged) else got

    # -- parked waits ------------------------------------------------------------------------
    def waiting(self, aid: str) -> bool:
        """Whether ``aid``'s tick waits for an answer (it must not be ticked)."""
        core = self.cores.get(aid)
        return core is not None and core.waiting

    def in_order(self) -> list[str]:
        """The agents whose waits are parked, the oldest wait first."""
        return sorted(self.parked, key=lambda a: self.parked[a].seq)

    def answer(self, aid: str, how: How = "reply") -> None:
        """Answer ``aid``'s parked wait now (see :data:`agent.testing.core_waits.How`); the
        rest of its tick runs to its next wait (parked again) or its end."""
        oldest = self.in_order()[0]
        p = self.parked.pop(aid)
        st = self.stats
        st.answered += 1
        st.out_of_order += oldest != aid
        st.late += self.steps > p.steps or self.clock.now() > p.at
        if isinstance(p.wait, Ask | AskHedged):
            st.timeouts += how == "timeout"
            st.late_replies += how == "late"
        elif isinstance(p.wait, Compute):
            st.stale += p.early is not NOT_YET
        got = self.resolve(aid, p.wait, p.fate, how, p.early)
        self.step(aid, Answer(got, self.clock.now()), p.fate)

    def compute_early(self, aid: str) -> bool:
        """Run ``aid``'s parked computation now (a worker finished it), its result delivered
        when answered; whether there was one to run."""
        p = self.parked.get(aid)
        if p is None or not isinstance(p.wait, Compute) or p.early is not NOT_YET:
            return False
        p.early = p.wait.fn()
        return True

    def heal(self) -> None:
        """Waits are answered at once from now on; those parked answered, oldest first."""
        self.park = False
        for aid in self.in_order():
            if aid in self.parked:
                self.answer(aid)

    def carry(self, aid: str, effects: list[Effect], fate: Fate
              ) -> Ask | AskHedged | Compute | Command | bytes | None:
        """Persist, publish (by ``fate``); the reply or what the tick waits for that the
        effects end with."""
        out: Ask | AskHedged | Compute | Command | bytes | None = None
        sent = False
        for e in effects:
            if isinstance(e, Persist):
                if sent:
                    self.order_violations.append(f"{aid}: {effects}")
                self.disks[aid].persist(e)
                continue
            if isinstance(e, Compute | Command):  # not a message
                out = e
                continue
            if isinstance(e, Trigger):  # the camera: after its record (checked above)
                self.triggers.append((aid, e.ids))
                continue
            if isinstance(e, Leave):  # fenced out: it leaves once its tick ends
                self._leaving.add(aid)
                continue
            if isinstance(e, Listen):  # whose pose streams the router forwards to it
                self.listening[aid] = e.peers
                continue
            if not isinstance(e, Publish | Reply | Ask | AskHedged):  # a hold: no message
                continue
            sent = True
            if isinstance(e, Publish):
                self.publish(aid, e, fate)
            elif isinstance(e, Reply):
                out = e.payload
            elif isinstance(e, Ask | AskHedged):
                out = e
        self.check_history()
        return out

    def ask(self, ask: Ask | AskHedged, fate: Fate) -> bytes | None:
        """The reply to ``ask``: its query delivered (lost, once or twice) and the first reply
        that is not lost."""
        target = keys.try_agent_of(ask.key)
        payload = ask.payload if isinstance(ask, Ask) else ask.copies[0]
        if target is None or target not in self.cores:
            return None
        query = Query(payload, ask.key, self.clock.now())
        self.queries.append((target, query))
        got: bytes | None = None
        for _ in range(fate.copies()):
            reply = self.step(target, query, fate)
            if got is None and reply is not None and not fate.lost():
                got = reply
        return got

    def publish(self, sender: str, pub: Publish, fate: Fate) -> None:
        """Deliver ``pub`` to every other core by ``fate`` (pose and state only; a pose only
        to the cores that listen to the sender's stream, as a router would)."""
        kind = keys.kind_of(pub.key)
        if kind not in ("pose", "state"):
            return
        sample = Sample("pose" if kind == "pose" else "state", pub.key, pub.payload,
                        self.clock.now())
        self.samples.append(sample)
        for aid in list(self.cores):
            if aid != sender and (kind == "state" or sender in self.listening.get(aid, ())):
                for _ in range(fate.copies()):
                    self.step(aid, sample, fate)

    def replay_query(self, index: int) -> None:
        """Deliver query ``index`` (modulo those sent) again; its reply is lost."""
        if self.queries:
            target, query = self.queries[index % len(self.queries)]
            self.step(target, replace(query, now=self.clock.now()), LOSSLESS)

    def replay_sample(self, index: int) -> None:
        """Deliver publication ``index`` (modulo those sent) again to every core."""
        if self.samples:
            sample = replace(self.samples[index % len(self.samples)], now=self.clock.now())
            for aid in list(self.cores):
                self.step(aid, sample, LOSSLESS)

    # -- invariants --------------------------------------------------------------------------
    def fenced(self) -> set[str]:
        """Agents some core knows fenced out of the team."""
        out: set[str] = set()
        for core in self.cores.values():
            out |= core.shared.machine.fenced
        return out

    def claims(self) -> Claims:
        """Every core's ledger (consistent: nothing runs between steps) and those of the
        agents away, fenced ones aside."""
        fenced = self.fenced()
        return {aid: (dict(c.shared.machine.owned),
                      {k: v for k, (v, _t) in c.shared.machine.held.items()})
                for aid, c in [*self.cores.items(), *self.away.items()] if aid not in fenced}

    def check_history(self) -> None:
        """Feed every ledger to the version history (its violations are kept); a fenced
        agent's claims are void (its landmarks were adopted at new versions)."""
        fenced = self.fenced()
        for aid in fenced - self._forgotten:
            self.history.forget(aid)
        self._forgotten = fenced  # a fence lifted (a round abandoned): its claims count again
        for aid, (owned, held) in self.claims().items():
            self.history_violations.extend(self.history.add(aid, owned, held))

    def violations(self) -> list[str]:
        """The ownership invariants now (snapshot and history)."""
        found = snapshot_violations(self.claims(), self.sc.landmark_ids)
        if self.fenced():  # orphans wait for adoption
            found = [v for v in found if not v.endswith("no claim (lost)")]
        return found + self.history_violations + self.order_violations
