"""Fault rehearsals of a whole mission in memory (``viscover simulate --drop P --dup P
--jitter S --lose ID@T --fault-seed N``, and :func:`viscover.api.simulate`): the faults, read
and checked, and the invariants of the run.

:class:`MissionFaults` is the fault model of one rehearsal: every message of every agent is
lost with probability ``drop``, delivered twice with probability ``dup``, each copy delayed by
a uniform random time in [0, ``jitter``) [s] (so messages overtake each other), all seeded by
``seed`` (:class:`~agent.net.faults.FaultInjector`, one stream per agent); and drones lost for
good at given mission times (``losses``: crashed, never restarted; the team fences them out
after the scenario's ``lost_after`` and adopts their landmarks). The same scenario, seed and
faults give the same run, message for message: the in-memory mission is single-threaded on
virtual time.

:class:`Rehearsal` watches such a run as a process mission is watched: an
:class:`~agent.mission.observer.Observer` on the in-memory network reads every published state
(ownership invariants, fences, adoption, completion, an inspection's end), and the mission's
ledgers are checked on every change (:class:`~agent.testing.memsim.MemoryMission`: a
consistent cut, which only an in-memory run has), and again at completion.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterable
from dataclasses import dataclass

from agent.config.scenario import Scenario
from agent.errors import UsageError
from agent.mission.observer import Observer, ObserverReport
from agent.net.faults import FaultConfig
from agent.testing.memsim import MemoryMission

#: Mission seconds a completed rehearsal steps on for the observer to hear the last states.
GRACE_S = 10.0


@dataclass(frozen=True)
class MissionFaults:
    """The faults of one rehearsal (module docstring): ``drop`` and ``dup`` probabilities in
    [0, 1] per message, ``jitter`` [s] (≥ 0) of delivery, ``losses`` ((drone id, mission time
    [s]) each drone lost for good from then on), ``seed`` of every random draw (≥ 0)."""

    drop: float = 0.0
    dup: float = 0.0
    jitter: float = 0.0
    losses: tuple[tuple[str, float], ...] = ()
    seed: int = 0

    def __post_init__(self) -> None:
        for name, p in (("drop", self.drop), ("dup", self.dup)):
            if not (math.isfinite(p) and 0.0 <= p <= 1.0):
                raise UsageError(f"--{name} {p:g}: must be a probability in [0, 1]")
        if not (math.isfinite(self.jitter) and self.jitter >= 0.0):
            raise UsageError(f"--jitter {self.jitter:g}: must be a non-negative number of "
                             "seconds")
        if self.seed < 0:
            raise UsageError(f"--fault-seed {self.seed}: must be a non-negative integer")
        seen: set[str] = set()
        for aid, t in self.losses:
            if not (math.isfinite(t) and t >= 0.0):
                raise UsageError(f"--lose {aid}@{t:g}: the time must be a non-negative number "
                                 "of mission seconds")
            if aid in seen:
                raise UsageError(f"--lose {aid}: given twice (a drone is lost once)")
            seen.add(aid)

    @property
    def any(self) -> bool:
        """Any fault at all (else the run is the lossless one)."""
        return bool(self.drop or self.dup or self.jitter or self.losses)

    def network(self) -> FaultConfig | None:
        """The message faults as the transports' :class:`FaultConfig` (None: none)."""
        if not (self.drop or self.dup or self.jitter):
            return None
        return FaultConfig(drop_default=self.drop, duplicate=self.dup, jitter_s=self.jitter)

    def check(self, sc: Scenario) -> None:
        """A :class:`UsageError` for a lost drone that is not one of ``sc``'s."""
        ids = [a.id for a in sc.agents]
        for aid, _t in self.losses:
            if aid not in ids:
                raise UsageError(f"--lose {aid}: not a drone of {sc.name} (drones: "
                                 f"{', '.join(ids)})")

    def scenario(self, sc: Scenario) -> Scenario:
        """``sc`` as rehearsed: with a drone lost, its ``duration`` [s] longer by
        ``lost_after`` (the team waits that long before it fences a lost drone out and adopts
        its landmarks)."""
        if not self.losses or sc.lost_after <= 0.0:
            return sc
        return dataclasses.replace(sc, duration=sc.duration + sc.lost_after)

    def describe(self) -> str:
        """The faults in words: ``drop 0.3, dup 0.1, jitter 0.05 s, B lost at t = 20 s, fault
        seed 7`` (``no faults`` when there are none)."""
        parts = [f"{name} {x:g}" for name, x in (("drop", self.drop), ("dup", self.dup))
                 if x]
        if self.jitter:
            parts.append(f"jitter {self.jitter:g} s")
        parts += [f"{aid} lost at t = {t:g} s" for aid, t in self.losses]
        return (", ".join(parts) + f", fault seed {self.seed}") if parts else "no faults"


def _number(text: str, option: str) -> float:
    try:
        x = float(text)
    except ValueError:
        raise UsageError(f"{option} {text}: not a number") from None
    if not math.isfinite(x):
        raise UsageError(f"{option} {text}: not a finite number")
    return x


def parse_loss(text: str) -> tuple[str, float]:
    """``ID@T`` (drone ``ID`` lost at mission time ``T`` [s]) as (ID, T); a
    :class:`UsageError` in one line otherwise."""
    aid, at, t = text.partition("@")
    if not at or not aid.strip() or not t.strip():
        raise UsageError(f"--lose {text}: write ID@T, e.g. --lose B@20 (drone B lost for good "
                         "at mission time 20 s)")
    return aid.strip(), _number(t.strip(), f"--lose {aid.strip()}@")


def faults_of(drop: str | float = 0.0, dup: str | float = 0.0, jitter: str | float = 0.0,
              lose: Iterable[str] = (), seed: str | int = 0) -> MissionFaults:
    """:class:`MissionFaults` from option values as typed (strings) or numbers; every bad
    value a :class:`UsageError` naming its option, in one line."""
    def num(x: str | float, option: str) -> float:
        return _number(x, option) if isinstance(x, str) else float(x)

    if isinstance(seed, str):
        try:
            seed = int(seed)
        except ValueError:
            raise UsageError(f"--fault-seed {seed}: not an integer") from None
    return MissionFaults(drop=num(drop, "--drop"), dup=num(dup, "--dup"),
                         jitter=num(jitter, "--jitter"),
                         losses=tuple(parse_loss(x) for x in lose), seed=int(seed))


@dataclass
class Outcome:
    """The invariants and end of a rehearsal: the ``observer``'s report (as ``viscover
    observe`` prints it; its ``complete_at_s`` is mission time here), every violation (the
    observer's and the ledgers'), the drones ``lost`` (id → mission time [s] it went)."""

    report: ObserverReport
    violations: list[str]
    lost: dict[str, float]
    complete: bool

    @property
    def ok(self) -> bool:
        """No invariant violated."""
        return not self.violations


class Rehearsal:
    """Faults applied to a :class:`MemoryMission` as it runs, watched by an observer: call
    :meth:`tick` before each step, :meth:`outcome` at the end (module docstring)."""

    def __init__(self, mm: MemoryMission, faults: MissionFaults, mission: str) -> None:
        self.mm, self.faults = mm, faults
        sc = mm.sc
        self.observer = Observer(mm.net.transport("observer"), mission,
                                 [a.id for a in sc.agents], list(sc.landmark_ids),
                                 now=lambda: float(mm.net.now), initial=sc.initial_sets())
        self._due = sorted(faults.losses, key=lambda x: (x[1], x[0]))
        self.lost: dict[str, float] = {}
        self._complete_at: float | None = None

    def tick(self) -> None:
        """Lose the drones whose time has come (before the mission steps at that time)."""
        now = float(self.mm.net.now)
        while self._due and self._due[0][1] <= now + 1e-9:
            aid, _t = self._due.pop(0)
            self.mm.crash(aid)
            self.lost[aid] = round(now, 9)

    def done(self, complete: bool) -> None:
        """The mission's completion as its driver judged it now (for the time it says)."""
        if complete and self._complete_at is None:
            self._complete_at = float(self.mm.net.now)

    def outcome(self, grace: float = GRACE_S) -> Outcome:
        """The observer's report (mission times), every violation, the lost drones. A mission
        the agents completed steps on (unrecorded) up to ``grace`` mission seconds until the
        observer has heard every agent's last state, as a process mission's observer does
        while the agents linger before they exit."""
        mm = self.mm
        end = float(mm.net.now) + grace
        while mm.complete and not self.observer.done.is_set() and mm.net.now < end:
            mm.step()
        rep = dataclasses.replace(self.observer.snapshot())
        if rep.complete:
            rep.complete_at_s = self._complete_at if self._complete_at is not None \
                else float(self.mm.net.now)
        violations = list(rep.violations) + list(self.mm.violations)
        if self.mm.complete:
            violations += self.mm.final_violations()
        return Outcome(rep, list(dict.fromkeys(violations)), dict(self.lost), rep.complete)

    def close(self) -> None:
        """Undeclare the observer's subscriptions."""
        self.observer.close()


def lost_line(lost: dict[str, float], report: ObserverReport) -> str:
    """``lost: B at t = 20 s (fenced out, round 1)``, or ``never fenced out`` (no strict
    majority of the team left to fence it, ``lost_after`` 0, or the time ran out first);
    empty without losses."""
    parts = []
    for aid, t in sorted(lost.items(), key=lambda x: (x[1], x[0])):
        f = report.fenced.get(aid)
        how = f"fenced out, round {f['epoch']}" if f else (
            "never fenced out: no strict majority of the team left to fence it, lost_after "
            "0, or the time ran out first")
        parts.append(f"{aid} at t = {t:g} s ({how})")
    return ("lost: " + "; ".join(parts)) if parts else ""

