"""Several agent cores (:class:`~agent.runtime.core.AgentCore`) stepped by hand over a model
network: no transport, no thread, no journal file. What a runtime does, done here in a few
lines so that a test chooses every message's fate: an ask's query may be lost, its reply lost,
the query duplicated; a publication lost or duplicated; any query or publication ever sent
delivered again later; an agent killed and restarted from its records (a process crash keeps
every record persisted; a power loss drops those after the last fsync).

Journals are lists of records; a :class:`~agent.runtime.events.Persist` with ``sync`` (or,
``None``, holding a durable record) marks everything up to it durable, as
:meth:`agent.storage.journal.Journal.append` fsyncs.
"""

from __future__ import annotations

import random
from collections.abc import Callable
from dataclasses import dataclass, field

from agent.clock import ManualClock
from agent.config.scenario import Scenario
from agent.mission.invariants import Claims, VersionHistory, snapshot_violations
from agent.protocol.records import DURABLE, Record
from agent.runtime.core import AgentCore, MotionFn
from agent.runtime.events import (
    Answer,
    Ask,
    AskHedged,
    Compute,
    Effect,
    Event,
    Liveliness,
    Persist,
    Publish,
    Query,
    Reply,
    Sample,
    Start,
    Tick,
)
from agent.runtime.pose import KinematicPoseSource
from agent.runtime.shared import AgentConfig
from agent.wire import keys


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


@dataclass(frozen=True)
class Fate:
    """How the network treats the messages of one step: a random source and the chances of
    a message lost and a message duplicated."""

    rng: random.Random
    loss: float = 0.0
    dup: float = 0.0

    def lost(self) -> bool:
        """Whether the next message is lost."""
        return self.loss > 0.0 and self.rng.random() < self.loss

    def copies(self) -> int:
        """How many copies of the next message arrive (0: lost)."""
        if self.lost():
            return 0
        return 2 if self.dup > 0.0 and self.rng.random() < self.dup else 1


LOSSLESS = Fate(random.Random(0))


class CoreNet:
    """The cores of scenario ``sc`` on a model network (see the module docstring).

    Args:
        sc: the mission.
        config: every core's constants.
        motion: planner replacement per agent id (None: the planner).
    """

    def __init__(self, sc: Scenario, config: AgentConfig,
                 motion: Callable[[str], MotionFn] | None = None) -> None:
        self.sc, self.cfg, self.motion = sc, config, motion
        self.clock = ManualClock()
        self.disks = {a.id: Disk() for a in sc.agents}
        self.cores: dict[str, AgentCore] = {}
        self.queries: list[tuple[str, Query]] = []  #: every query sent (target, query)
        self.samples: list[Sample] = []  #: every publication sent
        self.history = VersionHistory()
        self.history_violations: list[str] = []  #: (landmark, version) pairs claimed twice
        self._forgotten: set[str] = set()
        #: steps whose effects put a record to persist after a message
        self.order_violations: list[str] = []
        for a in sc.agents:
            self.boot(a.id)

    # -- agents ------------------------------------------------------------------------------
    def boot(self, aid: str) -> None:
        """Start ``aid`` from its journal; it and its peers see each other's tokens."""
        spec = next(a for a in self.sc.agents if a.id == aid)
        pose = KinematicPoseSource(spec.p0, spec.v0, self.clock, self.sc.space)
        core = AgentCore(aid, self.sc, list(self.disks[aid].records), self.clock, pose, self.cfg,
                         motion=None if self.motion is None else self.motion(aid))
        self.cores[aid] = core
        self.carry(aid, core.take_unpersisted(), LOSSLESS)
        self.step(aid, Start(self.clock.now()), LOSSLESS)
        alive = keys.alive_key(self.cfg.mission, aid)
        for other in self.cores:
            if other != aid:
                self.step(aid, Liveliness(keys.alive_key(self.cfg.mission, other), True),
                          LOSSLESS)
                self.step(other, Liveliness(alive, True), LOSSLESS)

    def crash(self, aid: str, power: bool = False) -> None:
        """Kill ``aid`` (``power``: a power loss) and start it again from its journal."""
        del self.cores[aid]
        alive = keys.alive_key(self.cfg.mission, aid)
        for other in self.cores:
            self.step(other, Liveliness(alive, False), LOSSLESS)
        if power:
            self.disks[aid].power_loss()
        self.boot(aid)

    # -- stepping ----------------------------------------------------------------------------
    def tick(self, aid: str, fate: Fate = LOSSLESS) -> None:
        """One tick of ``aid`` at the clock's time, its asks sent by ``fate``."""
        self.step(aid, Tick(self.clock.now()), fate)

    def step(self, aid: str, event: Event, fate: Fate) -> bytes | None:
        """Step ``event`` into ``aid``'s core and carry the effects out (asks answered at
        once, as the in-memory transport does); the reply to a query."""
        core = self.cores.get(aid)
        if core is None:
            return None
        out = self.carry(aid, core.step(event), fate)
        while isinstance(out, Ask | AskHedged | Compute):
            got = out.fn() if isinstance(out, Compute) else self.ask(out, fate)
            out = self.carry(aid, core.step(Answer(got)), fate)
        return out if isinstance(out, bytes) else None

    def carry(self, aid: str, effects: list[Effect], fate: Fate
              ) -> Ask | AskHedged | Compute | bytes | None:
        """Persist, publish (by ``fate``); the reply or what the tick waits for that the
        effects end with."""
        out: Ask | AskHedged | Compute | bytes | None = None
        sent = False
        for e in effects:
            if isinstance(e, Persist):
                if sent:
                    self.order_violations.append(f"{aid}: {effects}")
                self.disks[aid].persist(e)
                continue
            if isinstance(e, Compute):  # not a message
                out = e
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
        query = Query(payload, ask.key)
        self.queries.append((target, query))
        got: bytes | None = None
        for _ in range(fate.copies()):
            reply = self.step(target, query, fate)
            if got is None and reply is not None and not fate.lost():
                got = reply
        return got

    def publish(self, sender: str, pub: Publish, fate: Fate) -> None:
        """Deliver ``pub`` to every other core by ``fate`` (pose and state only)."""
        kind = keys.kind_of(pub.key)
        if kind not in ("pose", "state"):
            return
        sample = Sample("pose" if kind == "pose" else "state", pub.key, pub.payload)
        self.samples.append(sample)
        for aid in list(self.cores):
            if aid != sender:
                for _ in range(fate.copies()):
                    self.step(aid, sample, fate)

    def replay_query(self, index: int) -> None:
        """Deliver query ``index`` (modulo those sent) again; its reply is lost."""
        if self.queries:
            target, query = self.queries[index % len(self.queries)]
            self.step(target, query, LOSSLESS)

    def replay_sample(self, index: int) -> None:
        """Deliver publication ``index`` (modulo those sent) again to every core."""
        if self.samples:
            sample = self.samples[index % len(self.samples)]
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
        """Every core's ledger (consistent: nothing runs between steps), fenced ones aside."""
        fenced = self.fenced()
        return {aid: (dict(c.shared.machine.owned),
                      {k: v for k, (v, _t) in c.shared.machine.held.items()})
                for aid, c in self.cores.items() if aid not in fenced}

    def check_history(self) -> None:
        """Feed every ledger to the version history (its violations are kept); a fenced
        agent's claims are void (its landmarks were adopted at new versions)."""
        for aid in self.fenced() - self._forgotten:
            self.history.forget(aid)
            self._forgotten.add(aid)
        for aid, (owned, held) in self.claims().items():
            self.history_violations.extend(self.history.add(aid, owned, held))

    def violations(self) -> list[str]:
        """The ownership invariants now (snapshot and history)."""
        found = snapshot_violations(self.claims(), self.sc.landmark_ids)
        if self.fenced():  # orphans wait for adoption
            found = [v for v in found if not v.endswith("no claim (lost)")]
        return found + self.history_violations + self.order_violations
