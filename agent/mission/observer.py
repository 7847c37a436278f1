"""The mission observer: it checks the ownership invariants on every published state.

The pure checks are in :mod:`agent.mission.invariants`; besides them:

* :class:`~agent.mission.identity.IdentityWatch`: one agent id, one process (two streams
  of states under one id heard together for long are two processes).

Fenced agents (declared lost by the team, :mod:`agent.protocol.fencing`) are learned from
the fence proofs in the agents' states, each checked (:mod:`agent.protocol.fence_proof`: a
strict majority of the team voted; on the secured profile, given the team's public keys, each
ballot signed by its voter); their claims are void from then on
(:meth:`VersionHistory.forget`), and completion and the final check are over the other agents.
A state naming an agent fenced (or its sender fenced out) without a valid proof voids
nothing: the claim is reported as unproven (``unproven``: suspicious, not a violation of
ownership).

An agent's latest state is chosen as the agents choose it (:class:`~agent.wire.streams.
LatestStates`): one forged state with a huge incarnation holds the agent's place only until
its genuine stream has spoken twice after ``QUIET_S`` of silence, so it cannot stop the
observer from seeing completion nor make it report landmarks lost that are not.

**Doubled ownership.** A landmark owned by two agents not fenced out in their latest states,
at any versions, for longer than ``LandmarkWatch.lost_s`` (5 s: longer than a lossy link
delays a state) is a violation (``doubled``, :class:`DoubleWatch`): a transfer bumps the
version, so two owners at versions n and n + 1 are as doubled as two at n, and at completion
every landmark must have one owner (:func:`~agent.mission.invariants.final_violations`). A
(landmark, version) pair claimed by two agents in *some* states
(:class:`~agent.mission.invariants.VersionHistory`) is reported as suspicious
(``conflicting``), not as a violation: on the open profile anyone can publish a state under
any id, and on the secured one whoever holds a drone's certificate can, so one forged state
claiming a peer's landmarks is not doubled ownership (it gives way to the genuine stream,
above; the drones' journals hold nothing doubled). What no observer can tell: a forger that
keeps publishing a drone's state with its claims looks exactly like the doubling it claims,
and is reported as one.

Published states from different agents do not form a consistent cut (a state may be late or
lost), so the observer applies the snapshot rule only at completion and counts landmarks
without a claim in between as "in flight" rather than as violations. (Over 400 lines,
not split: the report and the judgement of the mission's end are one contract,
``observer.json``.)

An inspection mission (its agents publish ``capturable`` with their states) is complete only
with every capturable landmark captured: when the team ends (every agent says so) the observer
judges it from the latest states (captured and given-up sets merged,
:func:`~agent.protocol.inspection_end.inspection_end`); ``ended`` says the team ended,
``complete`` that it ended complete, ``inspection`` how (:meth:`Observer.inspection_end` also
judges it before the team ended: a timeout).
"""

from __future__ import annotations

import json
import logging
import math
import sys
import threading
import time
from collections import Counter
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, TextIO

import numpy as np

from agent.errors import UsageError
from agent.mission.identity import IdentityWatch
from agent.mission.invariants import (
    Claim,
    LandmarkWatch,
    VersionHistory,
    final_violations,
)
from agent.net.contract import Transport
from agent.net.rejects import LockedRejectCounter, rate_limited_log
from agent.net.security import team_dir
from agent.protocol.captures import agreed_bits
from agent.protocol.fence_proof import ProofBook, ballot_checker
from agent.protocol.inspection_end import (
    InspectionEnd,
    given_up_codes,
    inspection_end,
    merge_given_up,
)
from agent.wire import keys
from agent.wire.codec import Codec
from agent.wire.peer import AgentState, MissionStatus, Publication, unpack, unpack_bits
from agent.wire.signed import parse_team
from agent.wire.streams import LatestStates

if TYPE_CHECKING:  # cryptography is loaded where used (start-up time)
    from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PublicKey

_log = logging.getLogger(f"viscover.{__name__}")

#: Seconds an agent's current state stream must be silent before another stream of it may
#: take its place (ten state periods, as the agents judge freshness).
QUIET_S = 2.0
#: Drones not in the scenario the observer follows at most (its per-sender tables are
#: bounded; the open profile lets anyone publish under any id).
MAX_JOINERS = 256


def fence_keys(tls_dir: str | Path | None) -> dict[str, Ed25519PublicKey] | None:
    """The drones' signing public keys of the secured profile's team directory (``tls_dir``,
    else ``$VISCOVER_TLS_DIR``; its ``team.json``), to check fence ballots; None: the open
    profile. A :class:`UsageError` naming the file if it is missing or not a team file."""
    team = team_dir(tls_dir)
    if team is None:
        return None
    team.require(team.team_file)
    try:
        return parse_team(team.team_file.read_text(encoding="utf-8"))
    except (OSError, ValueError) as e:
        raise UsageError(f"--tls-dir {team.path}: team.json: {e}") from None


def coverage_of(states: Mapping[str, AgentState]) -> float:
    """Coverage score (eq. 3.10) as the sum of the agents' published visions."""
    return float(sum(st.vision for st in states.values()))


@dataclass
class ObserverReport:
    """What the observer saw."""

    violations: list[str] = field(default_factory=list)
    states_seen: int = 0
    rejected: int = 0
    #: the mission ended complete (an inspection: with every capturable landmark captured)
    complete: bool = False
    complete_at_s: float | None = None
    ended: bool = False  #: every agent said the mission is over (complete or not)
    #: an inspection's end: {"captured", "capturable" (counts), "given_up" {id: reason},
    #: "verdict"} (None: a coverage mission, or not ended)
    inspection: dict[str, Any] | None = None
    coverage: float = 0.0
    coverage_initial: float | None = None
    #: the coverage when the mission completed, and the drones' mission time then (the
    #: latest published t) [s]; ``coverage`` goes on with the flight home
    coverage_complete: float | None = None
    complete_t: float | None = None
    in_flight_max: int = 0
    agents: dict[str, dict[str, Any]] = field(default_factory=dict)
    owners: dict[int, str] = field(default_factory=dict)
    #: agents the team fenced out: {agent: {"epoch": round, "by": first agent that said so,
    #: "at_s": seconds since the observer started}}
    fenced: dict[str, dict[str, Any]] = field(default_factory=dict)
    joiners: list[str] = field(default_factory=list)  #: drones not in the scenario heard
    #: landmarks a fenced agent held that nobody claims yet: {id: seconds unclaimed}
    orphaned: dict[str, float] = field(default_factory=dict)
    #: landmarks in a fenced agent's last ledger since owned by another agent at a higher
    #: version: {id: the first such owner heard (the adopter)}
    adopted: dict[str, str] = field(default_factory=dict)
    #: strategy "potential": the team's score when its thesis stage ended (Σ of the published
    #: stage-1 visions, eq. 3.10; None if unknown or not that strategy), and whether the agents
    #: reverted to it because the coverage moves ended below it
    thesis_stage_coverage: float | None = None
    reverted: bool = False
    #: fence claims without a valid proof, ignored (suspicious): "<sender>: <agent>"
    unproven: list[str] = field(default_factory=list)
    #: (landmark, version) pairs claimed by two agents in some states, not (yet) doubled in
    #: their latest ones (suspicious: a forged state looks like this; at most 256)
    conflicting: list[str] = field(default_factory=list)

    def to_json(self) -> dict[str, Any]:
        """A JSON-able dict."""
        return {
            "violations": self.violations,
            "states_seen": self.states_seen,
            "rejected": self.rejected,
            "complete": self.complete,
            "complete_at_s": self.complete_at_s,
            "ended": self.ended,
            "inspection": self.inspection,
            "coverage": self.coverage,
            "coverage_initial": self.coverage_initial,
            "coverage_complete": self.coverage_complete,
            "complete_t": self.complete_t,
            "in_flight_max": self.in_flight_max,
            "agents": self.agents,
            "owners": {str(k): v for k, v in sorted(self.owners.items())},
            "fenced": self.fenced,
            "joiners": self.joiners,
            "orphaned": self.orphaned,
            "adopted": self.adopted,
            "thesis_stage_coverage": self.thesis_stage_coverage,
            "reverted": self.reverted,
            "unproven_fences": self.unproven,
            "conflicting": self.conflicting,
        }


class DoubleWatch:
    """Landmarks owned by two or more agents in their latest claims, at any versions; a
    violation once that lasts longer than ``lost_s`` [s] (module docstring)."""

    def __init__(self, lost_s: float = 5.0) -> None:
        self.lost_s = lost_s
        self.since: dict[int, float] = {}  #: landmark owned twice -> since when [s]
        self._reported: set[int] = set()

    def update(self, claims: Mapping[str, Claim], now: float) -> list[str]:
        """The latest claims of every agent not fenced out at time ``now`` [s]; returns new
        violations."""
        parts = [np.fromiter(owned.keys(), dtype=np.int64, count=len(owned))
                 for owned, _held in claims.values()]
        ids = np.concatenate(parts) if parts else np.zeros(0, dtype=np.int64)
        uniq, counts = np.unique(ids, return_counts=True)
        twice = uniq[counts > 1].tolist()
        self.since = {lid: self.since.get(lid, now) for lid in twice}
        out = []
        for lid in twice:  # normally none
            if lid in self._reported or now - self.since[lid] <= self.lost_s:
                continue
            self._reported.add(lid)
            who = ", ".join(f"{a} v{owned[lid]}" for a, (owned, _h) in sorted(claims.items())
                            if lid in owned)
            out.append(f"landmark {lid}: owned by {who} for {now - self.since[lid]:.1f} s: "
                       "doubled")
        return out


class Observer:
    """Subscribes to every agent's state and status, checks the invariants on each state.

    Completion: every scenario agent's latest state has ``complete`` set, with nothing pending
    and consistent per-pair trade counts; then :func:`final_violations` is applied, and an
    inspection's end judged (module docstring).
    """

    def __init__(self, transport: Transport, mission: str, agent_ids: list[str],
                 landmark_ids: list[int], *, now: Callable[[], float] = time.monotonic,
                 on_state: Iterable[Callable[[AgentState, Claim, bool], None]] = (),
                 on_status: Iterable[Callable[[MissionStatus], None]] = (),
                 initial: Mapping[str, Iterable[int]] | None = None,
                 fence_keys: Mapping[str, Ed25519PublicKey] | None = None) -> None:
        self.tp = transport
        #: each agent's landmarks at the start (the scenario's sets, version 0): the ledger of
        #: an agent fenced out before any of its states was heard
        self.initial = {a: [int(x) for x in ids] for a, ids in (initial or {}).items()}
        self.mission = mission
        self.agent_ids = list(agent_ids)
        self.all_ids = [int(x) for x in landmark_ids]
        self._known = np.unique(np.asarray(self.all_ids, dtype=np.int64))
        self.rejects = LockedRejectCounter()
        self.codec: Codec[Publication] = Codec(
            Publication, counter=self.rejects, log=rate_limited_log(_log))
        self.latest: dict[str, AgentState] = {}
        self._streams = LatestStates(QUIET_S)
        self.latest_claims: dict[str, tuple[dict[int, int], dict[int, int]]] = {}
        self.history = VersionHistory()
        self.watch = LandmarkWatch(self.all_ids)
        self.doubles = DoubleWatch(self.watch.lost_s)
        #: landmark -> version of fenced agents' last ledgers, until adopted (report.adopted)
        self._lost_ledger: dict[int, int] = {}
        self.identity = IdentityWatch()
        self.report = ObserverReport()
        #: fence proofs accepted: ballots checked against ``fence_keys`` (None: open profile)
        self.book = ProofBook(self.agent_ids, None if fence_keys is None
                              else ballot_checker(fence_keys, mission))
        self._now = now
        #: called with (state, (owned, held), newest so far) after each accepted state, on the
        #: transport's thread, outside the lock (:class:`~agent.mission.watch.MissionWatch`)
        self.on_state: list[Callable[[AgentState, Claim, bool], None]] = list(on_state)
        #: called with each mission status received
        self.on_status: list[Callable[[MissionStatus], None]] = list(on_status)
        self._lock = threading.Lock()
        self._t0 = now()
        self.done = threading.Event()
        self._end: InspectionEnd | None = None  #: an inspection's end, once the team ended
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
        if keys.try_agent_of(key) != st.sender:
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
            if msg.sender not in self.agent_ids and msg.sender not in rep.joiners:
                if len(rep.joiners) >= MAX_JOINERS:  # per-sender tables stay bounded
                    self.codec.reject("too_many_senders", key, f"sender {msg.sender!r}")
                    return
                rep.joiners = sorted([*rep.joiners, msg.sender])  # joined the mission
            self._learn_fences(msg)
            if msg.sender in rep.fenced:  # a lost agent's claims are void
                return
            pairs = self.history.add(msg.sender, *claims)  # suspicious (module docstring)
            rep.conflicting.extend(p for p in pairs if p not in rep.conflicting[-64:])
            del rep.conflicting[:-256]  # bounded: a forger may say anything
            rep.violations.extend(self.identity.add(msg.sender, msg.incarnation, msg.seq,
                                                    msg.t, self._now()))
            newer = self._streams.offer(msg.sender, msg.incarnation, msg.seq, self._now())
            if newer:
                self._accept(msg, claims)
        for fn in self.on_state:
            fn(msg, claims, newer)

    def _learn_fences(self, msg: AgentState) -> None:
        """Agents proven fenced out by the proofs ``msg`` carries: forget their claims; fence
        claims without a valid proof: reported as unproven (under the lock)."""
        rep = self.report
        for proof in msg.fence_proofs:
            if self.book.accept(proof):
                for f in proof.fenced:
                    self._void(f, proof.epoch, msg.sender)
        if msg.sender in rep.fenced:
            return
        # An agent that learned it was fenced out says so (its ledger is dropped), with the
        # proof it learned it from.
        for f in sorted({*msg.fenced, *([msg.sender] if msg.fenced_out else [])}):
            said = f"{msg.sender}: {f}"
            if f not in rep.fenced and said not in rep.unproven:
                rep.unproven.append(said)
                _log.warning("agent %s names %s fenced out without a valid proof: ignored",
                             msg.sender, f)

    def _void(self, f: str, epoch: int, by: str) -> None:
        """Agent ``f`` is proven fenced out (round ``epoch``, ``by`` told): its claims are
        void from now on, its last ledger is what the team adopts (under the lock)."""
        rep = self.report
        if f not in rep.fenced:
            rep.fenced[f] = {"epoch": epoch, "by": by, "at_s": round(self._now() - self._t0, 3)}
            self.watch.fenced_touched |= self.history.forget(f)
            self.latest.pop(f, None)
            start: tuple[dict[int, int], dict[int, int]] = (
                {lid: 0 for lid in self.initial.get(f, [])}, {})
            for held in self.latest_claims.pop(f, start):
                for lid, ver in held.items():
                    self._lost_ledger[lid] = max(ver, self._lost_ledger.get(lid, -1))

    def _accept(self, msg: AgentState, claims: tuple[dict[int, int], dict[int, int]]) -> None:
        """Make ``msg`` the sender's latest state (under the lock): coverage, completion."""
        rep = self.report
        self.latest[msg.sender] = msg
        self.latest_claims[msg.sender] = claims
        for lid in self._lost_ledger.keys() & claims[0].keys():  # few: a lost agent's ledger
            if claims[0][lid] > self._lost_ledger[lid]:
                del self._lost_ledger[lid]
                rep.adopted[str(lid)] = msg.sender
        now = self._now() - self._t0
        rep.violations.extend(self.watch.update(self.latest_claims.values(), now, self.history))
        rep.violations.extend(self.doubles.update(self.latest_claims, now))
        rep.in_flight_max = max(rep.in_flight_max, len(self.watch.since))
        rep.orphaned = {str(k): v for k, v in sorted(self.watch.orphaned(now).items())}
        rep.coverage = coverage_of(self.latest)
        if rep.coverage_initial is None and len(self.latest) == len(self._team()):
            rep.coverage_initial = rep.coverage
        self._check_complete()

    def _team(self) -> set[str]:
        """The agents and joiners not fenced out."""
        return (set(self.agent_ids) | set(self.report.joiners)) - set(self.report.fenced)

    def _check_complete(self) -> None:
        if self.report.complete or set(self.latest) != self._team():
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
        got = self._inspection_end(max(st.t for st in sts.values()))
        rep.ended = True
        rep.complete = got is None or got[0].complete
        self._end, rep.inspection = (None, None) if got is None else got
        rep.complete_at_s = time.monotonic() - self._t0
        rep.coverage_complete = rep.coverage
        rep.complete_t = max(st.t for st in sts.values())
        rep.owners = {lid: a for a, (owned, _h) in claims.items() for lid in owned}
        rep.agents = {
            a: {"vision": st.vision, "owned": sorted(claims[a][0]), "ok": st.counters.ok,
                "failed": st.counters.failed, "busy": st.counters.busy,
                "timeouts": st.counters.timeouts, "rejected": st.counters.rejected,
                "evicted": st.counters.evicted,
                "p": list(st.p), "v": list(st.v), "stage": st.stage,
                "refused_claims": st.refused_claims}
            for a, st in sorted(sts.items())
        }
        firsts = [st.stage1_vision for st in sts.values()]
        if all(math.isfinite(x) and x >= 0.0 for x in firsts) and any(
                st.stage > 1 for st in sts.values()):
            rep.thesis_stage_coverage = float(sum(firsts))
        rep.reverted = any(st.reverting for st in sts.values())
        self.done.set()

    def _inspection_end(self, t: float | None) -> tuple[InspectionEnd, dict[str, Any]] | None:
        """An inspection's end from the latest states (under the lock): complete at mission
        time ``t`` [s], or what was given up, and :attr:`ObserverReport.inspection` of it;
        None for a coverage mission (no state names the capturable landmarks)."""
        m = len(self.all_ids)
        sts = list(self.latest.values())
        if not any(st.capturable and unpack_bits(st.capturable, m) is not None for st in sts):
            return None
        # a landmark counts captured (or capturable) when a strict majority of the drones'
        # published sets name it: one drone's word is not enough (agent.protocol.captures)
        capturable = agreed_bits((st.capturable for st in sts if st.capturable), m)
        codes = np.zeros(m, dtype=np.int8)
        for st in sts:  # one state per drone
            got = given_up_codes(st.given_up, m)
            if got is not None:
                codes = merge_given_up(codes, got)
        captured = agreed_bits((st.captured for a, st in self.latest.items()
                                if a not in self.report.fenced), m)  # a fenced one's is void
        end = inspection_end(np.asarray(self.all_ids, dtype=np.int64), capturable, captured,
                             codes, t)
        return end, {"captured": int(captured.sum()),
                     "capturable": int((capturable | captured).sum()),
                     "given_up": {str(k): v for k, v in end.given_up.items()},
                     "verdict": end.verdict()}

    def inspection_end(self) -> InspectionEnd | None:
        """An inspection's end as the latest states show it: its verdict once the team ended,
        else what the mission leaves if it stops now (the time ran out: what nobody captured
        or gave up is given up for ``time``); None for a coverage mission."""
        with self._lock:
            if self._end is not None:
                return self._end
            got = self._inspection_end(None)
            return None if got is None else got[0]

    def unfinished(self) -> str:
        """``; INCOMPLETE: G given up (...)`` when an inspection that stops now is incomplete
        (:meth:`inspection_end`), else empty."""
        end = self.inspection_end()
        return "" if end is None or end.complete else f"; {end.verdict()}"

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
    if rep.inspection is not None:  # an inspection: complete at t = X s, or INCOMPLETE: ...
        done = f"{rep.inspection['verdict']} (after {rep.complete_at_s:.1f} s)"
    print(f"states {rep.states_seen}, rejected {rep.rejected}, coverage {init} -> "
          f"{rep.coverage:.4g}, {done}, violations {len(rep.violations)}", file=out)
    if rep.thesis_stage_coverage is not None:
        print(f"coverage when the thesis stage ended {rep.thesis_stage_coverage:.4g}; "
              + ("the coverage moves ended below it: reverted to it" if rep.reverted else
                 f"with the coverage moves {rep.coverage:.4g}"), file=out)
    if rep.owners:
        print("final partition: " + json.dumps(
            {a: d["owned"] for a, d in rep.agents.items()}), file=out)
    if rep.unproven:
        print("fence claims without a valid proof, ignored (suspicious): "
              + ", ".join(rep.unproven), file=out)
    if rep.fenced:
        lost = ", ".join(f"{a} (round {f['epoch']}, told by {f['by']})"
                         for a, f in sorted(rep.fenced.items()))
        by = Counter(rep.adopted.values())
        print(f"lost (fenced out): {lost}; landmarks adopted {len(rep.adopted)} ("
              + ", ".join(f"{a} {n}" for a, n in sorted(by.items())) + "), orphaned "
              f"{len(rep.orphaned)}", file=out)
