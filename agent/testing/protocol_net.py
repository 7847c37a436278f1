"""A model network of :class:`~agent.protocol.machine.TradeMachine` s for protocol tests: the
machines alone, no runtime, no clock, every fault a test step (the hypothesis state machine
``tests/test_protocol_state_machine.py`` drives it).

(Over 400 lines, not split: the scene, the nodes, the network and its invariants are one
model of the runtime, read side by side with ``trade_client`` and ``trade_server``.)

Each :class:`Node` is one agent process as the runtime drives its machine
(:mod:`agent.runtime.ends.trade_client`, :mod:`agent.runtime.ends.trade_server`): one offer attempt
at a
time, re-sent while it waits and given up after its tries; Commit re-sent until acknowledged
and StatusQuery until decided, for as long as the trade is pending; Busy("optimising") from an
agent that is not converged, Busy("trading") from one with a pending offer; the larger id
yields when two agents offer to each other. Every step's records are appended to the node's
:class:`MemJournal` before its message is sent (fsynced if one is
:data:`~agent.protocol.records.DURABLE`, as :class:`agent.storage.journal.Journal` does), and
a crash rebuilds the machine from the journal and calls
:meth:`~agent.protocol.machine.TradeMachine.recover`, as a restarted agent does. A crash may
strike between a step and its persistence (the step's message is then never sent), and a power
loss drops the records not fsynced yet.

:class:`ProtocolNet` holds the messages in flight as encoded bytes (msgpack, as on the wire);
a test delivers any of them (reordering), loses, duplicates or replays one (any message ever
sent), and checks the ownership invariants (:meth:`ProtocolNet.violations`) and, at the end,
that everything resolves (:meth:`ProtocolNet.drain`, :meth:`ProtocolNet.final_violations`).
Replies are routed to the handler of the request they answer (an Offer's reply to
``on_offer_reply``, a Commit's to ``on_commit_reply``, a StatusQuery's to ``on_decision``), as
a query's reply is; an old reply is fed to the machine even when the runtime would have
dropped it, which only makes the model more adversarial.

Not modelled: fence rounds and joiners (:mod:`agent.protocol.fencing`), and the pose check of
offers beyond its two answers (Busy while the pose is unknown, Refused when wrong).
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Literal

import msgspec
import numpy as np

from agent.core.coverage_moves import Goal
from agent.core.trading import trade_landmarks
from agent.mission.invariants import VersionHistory, final_violations, snapshot_violations
from agent.protocol.machine import DecideFn, IntArray, Mask, Step, TradeMachine
from agent.protocol.records import DURABLE, GenesisRec, Rec, Vec3
from agent.protocol.regroup import (
    leg_terms,
    nothing_moves,
    pull_decision,
    pull_terms,
    regroup_decision,
)
from agent.wire.peer import (
    Busy,
    Commit,
    Offer,
    Refused,
    Regroup,
    Reply,
    Request,
    StatusQuery,
    pack_arrays,
    parse_trade_id,
)

# -- the scene: landmarks on a cube's faces, viewpoints around it ------------------------------

#: Landmark ids of the model mission (not contiguous, not starting at 0: ranks are exercised).
LANDMARK_IDS: tuple[int, ...] = tuple(7 * k + 3 for k in range(12))

_FACES = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]],
                  dtype=np.float64)
_OFFSETS = np.array([[0.3, 0.2, -0.1], [-0.2, -0.3, 0.25]], dtype=np.float64)
#: positions q (m, 3) [m] and outward unit normals u (m, 3): two landmarks per face
LANDMARK_Q = np.array([f + o - (o @ f) * f for f in _FACES for o in _OFFSETS])
LANDMARK_U = np.repeat(_FACES, 2, axis=0)


def _viewpoint(p: Sequence[float]) -> tuple[Vec3, Vec3]:
    """A camera at ``p`` [m] looking at the cube's centre."""
    q = np.asarray(p, dtype=np.float64)
    v = -q / np.linalg.norm(q)
    return (float(q[0]), float(q[1]), float(q[2])), (float(v[0]), float(v[1]), float(v[2]))


#: Poses (p [m], unit v) an agent may be at: one in front of each face, two off-axis.
VIEWPOINTS: tuple[tuple[Vec3, Vec3], ...] = tuple(_viewpoint(p) for p in (
    (3, 0, 0), (-3, 0, 0), (0, 3, 0), (0, -3, 0), (0, 0, 3), (0, 0, -3), (2, 2, 1), (-2, 1, -2)))

#: Optimal viewing distance [m] of the model's Algorithm 7.
D_OPT = 2.0

_ROW = {lid: r for r, lid in enumerate(LANDMARK_IDS)}


def algorithm7(p_i: Vec3, v_i: Vec3, ids_i: IntArray, p_r: Vec3, v_r: Vec3,
               ids_r: IntArray) -> tuple[Mask, Mask]:
    """Algorithm 7 on the model scene (:func:`agent.core.trading.trade_landmarks`): every
    landmark goes to the agent that sees it strictly better."""
    ri = [_ROW[int(x)] for x in ids_i]
    rr = [_ROW[int(x)] for x in ids_r]
    out = trade_landmarks(np.asarray(p_i), np.asarray(v_i), LANDMARK_Q[ri], LANDMARK_U[ri],
                          np.asarray(p_r), np.asarray(v_r), LANDMARK_Q[rr], LANDMARK_U[rr], D_OPT)
    return out.a_to_b, out.b_to_a


def subset_decision(ids: Sequence[int]) -> DecideFn:
    """Arbitrary valid terms: every landmark of ``ids`` that either side owns moves."""
    chosen = np.asarray(sorted(ids), dtype=np.int64)

    def decide(_p_i: Vec3, _v_i: Vec3, ids_i: IntArray, _p_r: Vec3, _v_r: Vec3,
               ids_r: IntArray) -> tuple[Mask, Mask]:
        return np.isin(ids_i, chosen), np.isin(ids_r, chosen)

    return decide


TermsKind = Literal["alg7", "subset", "regroup", "pull"]


@dataclass(frozen=True)
class Terms:
    """How the responder decides an offer: ``alg7`` (Algorithm 7 at both poses), ``subset``
    (``ids`` move, whoever owns them), ``regroup`` (a pair re-split that gives the responder
    exactly ``ids`` of the pair's union; :mod:`agent.protocol.regroup`) or ``pull`` (a revert
    pull of the responder's landmarks among ``ids``)."""

    kind: TermsKind = "alg7"
    ids: tuple[int, ...] = ()


# -- journal and nodes --------------------------------------------------------------------------


class MemJournal:
    """An agent's journal in memory: records in order, ``synced`` of them fsynced (a record
    is fsynced with the first durable one after it, as the file is)."""

    def __init__(self) -> None:
        self.records: list[Rec] = []
        self.synced = 0

    def append(self, recs: Sequence[Rec], sync: bool | None = None) -> None:
        """Append ``recs``; fsync if ``sync``, or (None) if one of them is durable."""
        self.records.extend(recs)
        if sync or (sync is None and any(isinstance(r, DURABLE) for r in recs)):
            self.synced = len(self.records)

    def power_loss(self) -> int:
        """Drop the records not fsynced (the machine lost power); returns how many."""
        lost = len(self.records) - self.synced
        del self.records[self.synced:]
        return lost


@dataclass
class Attempt:
    """The runtime's pending offer (:class:`agent.runtime.core.shared.Attempt`)."""

    trade_id: str
    partner: str
    payload: bytes  #: the encoded Offer, re-sent as is by every try
    tries: int = 1


@dataclass
class Node:
    """One agent process: its journal (survives crashes), its machine and the runtime's
    volatile state (lost by a crash). ``shadow`` is the machine its journal rebuilds (every
    journaled record applied to it as it is appended): the live one must not differ."""

    me: str
    ids: tuple[int, ...]
    journal: MemJournal
    machine: TradeMachine
    shadow: TradeMachine
    pose: int = 0  #: index into :data:`VIEWPOINTS`
    optimising: bool = False
    attempt: Attempt | None = None
    starts: int = 1

    @classmethod
    def genesis(cls, me: str, ids: Sequence[int], owned: Sequence[int], pose: int) -> Node:
        """A first start owning ``owned`` at version 0 (``open_ledger``)."""
        own = np.asarray(sorted(owned), dtype=np.int64)
        j = MemJournal()
        j.append([GenesisRec(agent=me, owned=pack_arrays(own, np.zeros_like(own)))], sync=True)
        m = TradeMachine(me, list(ids))
        node = cls(me, tuple(ids), j, m, m, pose)
        node.start()
        return node

    def replay(self) -> TradeMachine:
        """A machine rebuilt from the journal."""
        m = TradeMachine(self.me, list(self.ids))
        for rec in self.journal.records:
            m.apply(rec)
        return m

    def start(self) -> None:
        """Start from the journal as a new incarnation (its start-up records journaled,
        fsynced: ``open_ledger``)."""
        self.machine, self.shadow = self.replay(), self.replay()
        self.persist(self.machine.recover(), sync=True)

    def persist(self, recs: Sequence[Rec], sync: bool | None = None) -> None:
        """Journal ``recs`` (the runtime's ``Shared.journal``)."""
        self.journal.append(recs, sync)
        for rec in recs:
            self.shadow.apply(rec)

    def crash(self, power_loss: bool = False) -> None:
        """Kill the process (with ``power_loss`` the unsynced records are gone too) and start
        it again from its journal."""
        if power_loss:
            self.journal.power_loss()
        self.start()
        self.attempt = None
        self.optimising = True  # a restarted agent plans before it trades again
        self.starts += 1

    @property
    def p(self) -> Vec3:
        return VIEWPOINTS[self.pose][0]

    @property
    def v(self) -> Vec3:
        return VIEWPOINTS[self.pose][1]

    def busy(self) -> str | None:
        """What the trade server passes as ``busy`` (its phase; None: converged)."""
        m = self.machine
        if m.prepared or self.attempt is not None or m.offering:
            return "trading"
        return "optimising" if self.optimising else None

    def success(self) -> None:
        """A trade of ours committed: optimise again (``Shared.success``)."""
        self.optimising = True


def durable_view(m: TradeMachine) -> tuple[object, ...]:
    """Everything of a machine's state that its journal must rebuild."""
    return (
        m.owned, m.held, {t: (tr.partner, tr.state, tr.i_to_r, tr.r_to_i)
                          for t, tr in m.initiated.items()},
        {t: (pt.partner, pt.i_to_r, pt.r_to_i) for t, pt in m.prepared.items()},
        dict(m.decided), sorted(m.r_committed), sorted(m.r_restored), m.incarnation, m.counter,
        dict(m.trades_with), m.ok, m.failed,
    )


# -- the network --------------------------------------------------------------------------------

ReplyTo = tuple[Literal["offer", "commit", "status"], str]

#: What the trade server does with an offer before the machine sees it: ``runtime`` (as the
#: runtime: yield, busy from its phase), ``eager`` (busy None, no yield: only the machine's own
#: rules), ``pose_unknown`` (Busy "trading", the initiator's pose not known yet) or
#: ``pose_refused`` (Refused, its pose is wrong).
Variant = Literal["runtime", "eager", "pose_unknown", "pose_refused"]

_ENC = msgspec.msgpack.Encoder()
_DEC_REQ = msgspec.msgpack.Decoder(Request)
_DEC_REP = msgspec.msgpack.Decoder(Reply)


@dataclass(frozen=True)
class Envelope:
    """A message in flight: a request (``reply_to`` None) or the reply to one."""

    n: int  #: sequence number of the original send
    src: str
    dst: str
    data: bytes
    reply_to: ReplyTo | None = None

    def describe(self) -> str:
        msg = _DEC_REQ.decode(self.data) if self.reply_to is None else _DEC_REP.decode(self.data)
        tid = getattr(msg, "trade_id", "")
        return f"#{self.n} {self.src}->{self.dst} {type(msg).__name__} {tid}"


@dataclass
class ProtocolNet:
    """Trade machines of ``agents`` exchanging messages through an adversarial network.

    Args:
        agents: agent ids.
        owners: landmark id -> the agent owning it at genesis (version 0).
        poses: agent id -> initial viewpoint index.
    """

    agents: Sequence[str]
    owners: Mapping[int, str]
    poses: Mapping[str, int] = field(default_factory=dict)
    nodes: dict[str, Node] = field(init=False)
    pending: list[Envelope] = field(init=False, default_factory=list)
    sent: list[Envelope] = field(init=False, default_factory=list)
    terms: dict[str, Terms] = field(init=False, default_factory=dict)
    history: VersionHistory = field(init=False, default_factory=VersionHistory)
    top: dict[int, int] = field(init=False, default_factory=dict)
    log: list[str] = field(init=False, default_factory=list)
    #: how often each handler outcome happened (``"<kind> <outcome>"``, e.g. ``"offer
    #: prepared"`` at a responder, ``"reply to status restored"`` at one in doubt)
    outcomes: Counter[str] = field(init=False, default_factory=Counter)

    def __post_init__(self) -> None:
        ids = sorted(self.owners)
        self.nodes = {a: Node.genesis(a, ids, [x for x in ids if self.owners[x] == a],
                                      self.poses.get(a, 0)) for a in self.agents}

    # -- sending and the faults of the network ---------------------------------------------
    def _send(self, src: str, dst: str, data: bytes, reply_to: ReplyTo | None = None) -> None:
        env = Envelope(len(self.sent), src, dst, data, reply_to)
        self.sent.append(env)
        self.pending.append(env)

    def lose(self, k: int) -> None:
        """Message ``k`` (of the pending ones, modulo) is lost."""
        if self.pending:
            env = self.pending.pop(k % len(self.pending))
            self.log.append(f"lose {env.describe()}")

    def duplicate(self, k: int) -> None:
        """Message ``k`` is duplicated (the copy goes last)."""
        if self.pending:
            env = self.pending[k % len(self.pending)]
            self.pending.append(env)
            self.log.append(f"duplicate {env.describe()}")

    def replay(self, k: int) -> None:
        """A message sent earlier (``k``-th ever, modulo) arrives once more."""
        if self.sent:
            env = self.sent[k % len(self.sent)]
            self.pending.append(env)
            self.log.append(f"replay {env.describe()}")

    def replay_request(self, k: int, variant: Variant = "runtime") -> None:
        """The ``k``-th newest request ever sent (modulo) arrives again and is handled."""
        requests = [e for e in self.sent if e.reply_to is None]
        if requests:
            self.pending.append(requests[-1 - k % len(requests)])
            self.log.append("replay (at once):")
            self.deliver(len(self.pending) - 1, variant)

    # -- what a node's runtime does ----------------------------------------------------------
    def _persist(self, node: Node, recs: Sequence[Rec], keep: int | None) -> bool:
        """Journal ``recs`` (all, or with ``keep`` only the first ``keep`` and then crash):
        True if the node goes on (and may send what depends on them)."""
        if keep is None:
            node.persist(recs)
            return True
        node.persist(recs[:keep])
        node.crash()
        return False

    def start_offer(self, i: str, j: str, terms: Terms) -> str | None:
        """``i`` offers to ``j`` (``maybe_offer``); the trade id, or None if ``i`` cannot offer
        now (a pending offer already, or ``i == j``)."""
        node = self.nodes[i]
        if i == j or node.attempt is not None:
            return None
        regroup = self._regroup(node, self.nodes[j], terms)
        step = node.machine.new_offer(j, node.p, node.v, regroup)
        assert step.trade_id is not None and isinstance(step.message, Offer)
        self.terms[step.trade_id] = terms
        self.log.append(f"{i} offers {step.trade_id} to {j} ({terms.kind} {list(terms.ids)})")
        node.persist(step.records)
        payload = _ENC.encode(step.message)
        node.attempt = Attempt(step.trade_id, j, payload)
        self._send(i, j, payload)
        return step.trade_id

    def _regroup(self, node: Node, peer: Node, terms: Terms) -> Regroup | None:
        """The Regroup ``node`` proposes to ``peer`` (from the peer's ledger as published now)
        for re-split and pull terms."""
        own_ids, own_vers = node.machine.owned_arrays()
        peer_ids, peer_vers = peer.machine.owned_arrays()
        want = np.asarray(terms.ids, dtype=np.int64)
        if terms.kind == "regroup":
            goal = Goal(np.asarray(peer.p), np.asarray(peer.v), 0.0)
            r = leg_terms(want, goal, own_ids, own_vers, peer_ids, peer_vers)
            return r if r is not None else leg_terms(peer_ids, goal, own_ids, own_vers,
                                                     peer_ids[:0], peer_vers[:0])
        if terms.kind == "pull":
            take = np.isin(peer_ids, want)
            return pull_terms(peer_ids[take], peer_vers[take], peer_ids, peer_vers)
        return None

    def _decide(self, offer: Offer) -> DecideFn:
        terms = self.terms.get(offer.trade_id, Terms())
        if offer.regroup is not None:
            if terms.kind == "pull":
                return pull_decision(offer.regroup)
            return regroup_decision(offer.regroup)
        if terms.kind == "subset":
            return subset_decision(terms.ids)
        if terms.kind == "alg7":
            return algorithm7
        return nothing_moves

    def requests_due(self) -> list[tuple[str, str, bytes, ReplyTo]]:
        """Every request a retry timer may send again, oldest agent first: (agent, partner,
        payload, what it asks): its offer, a Commit not acknowledged, a StatusQuery of a trade
        in doubt (``attempt_offer`` and ``service_pending``)."""
        out: list[tuple[str, str, bytes, ReplyTo]] = []
        for a, node in self.nodes.items():
            m = node.machine
            if node.attempt is not None:
                out.append((a, node.attempt.partner, node.attempt.payload,
                            ("offer", node.attempt.trade_id)))
            out += [(a, p, _ENC.encode(Commit(sender=a, trade_id=t)), ("commit", t))
                    for t, p in m.unacked_commits()]
            out += [(a, p, _ENC.encode(StatusQuery(sender=a, trade_id=t)), ("status", t))
                    for t, p in m.doubts()]
        return out

    def timers(self, i: str) -> None:
        """``i``'s retry timers fire: its offer, every Commit not acknowledged and every
        StatusQuery of a trade in doubt go out again (``attempt_offer`` and
        ``service_pending``)."""
        for a, dst, data, (kind, tid) in self.requests_due():
            if a != i:
                continue
            node = self.nodes[a]
            if kind == "offer" and node.attempt is not None:
                node.attempt.tries += 1
            self._send(a, dst, data)
            self.log.append(f"{a} retries {kind} {tid}")

    def give_up(self, i: str) -> None:
        """``i``'s offer got no reply after its tries: abort it (``_no_reply``)."""
        node = self.nodes[i]
        att = node.attempt
        if att is None:
            return
        step = node.machine.abort_offer(att.trade_id, "timeout")
        self.log.append(f"{i} gives up {att.trade_id}")
        node.attempt = None
        node.persist(step.records)

    def converge(self, i: str, pose: int) -> None:
        """``i`` ends its optimisation at viewpoint ``pose``."""
        node = self.nodes[i]
        node.pose = pose % len(VIEWPOINTS)
        node.optimising = False

    def crash(self, i: str, power_loss: bool) -> None:
        """``i`` is killed (with ``power_loss``: loses its unsynced records) and restarts."""
        lost = len(self.nodes[i].journal.records) - self.nodes[i].journal.synced
        self.nodes[i].crash(power_loss)
        self.log.append(f"crash {i}" + (f" (power loss: {lost} records)" if power_loss else ""))

    def deliver(self, k: int, variant: Variant = "runtime", keep: int | None = None) -> None:
        """Message ``k`` (of the pending ones, modulo: -1 is the newest) arrives and is
        handled; with ``keep`` its receiver crashes after journaling only the first ``keep``
        records of the step (its answer is never sent) and restarts."""
        if not self.pending:
            return
        env = self.pending.pop(k % len(self.pending))
        node = self.nodes[env.dst]
        self.log.append(f"deliver {env.describe()}" + ("" if variant == "runtime" else
                                                       f" [{variant}]")
                        + ("" if keep is None else f" [crash after {keep} records]"))
        if env.reply_to is None:
            self._serve(node, env, _DEC_REQ.decode(env.data), variant, keep)
        else:
            self._on_reply(node, env.reply_to, _DEC_REP.decode(env.data), keep)

    def _serve(self, node: Node, env: Envelope, req: Request, variant: Variant,
               keep: int | None) -> None:
        """The trade server of ``node`` answers ``req`` (:class:`TradeServer`)."""
        m = node.machine
        recs: list[Rec] = []
        reply: Reply | None
        kind: Literal["offer", "commit", "status"]
        if isinstance(req, Offer):
            kind = "offer"
            gated = req.regroup is None and req.trade_id not in m.prepared
            if variant == "pose_unknown" and gated:
                reply = Busy(sender=node.me, trade_id=req.trade_id, reason="trading")
            elif variant == "pose_refused" and gated:
                reply = Refused(sender=node.me, trade_id=req.trade_id, reason="pose")
            else:
                busy = None
                if variant != "eager":
                    att = node.attempt
                    if att is not None and att.partner == req.sender and node.me > req.sender \
                            and not m.prepared:
                        recs += m.abort_offer(att.trade_id, "yield").records
                        node.attempt = None
                    busy = node.busy()
                    if req.regroup is not None and busy == "optimising":
                        busy = None
                step = m.on_offer(req, node.p, node.v, busy, self._decide(req))
                recs += step.records
                reply = step.reply()
        elif isinstance(req, Commit):
            kind = "commit"
            step = m.on_commit(req)
            recs += step.records
            reply = step.reply()
            if step.outcome == "committed":
                node.success()
        elif isinstance(req, StatusQuery):
            kind = "status"
            step = m.on_status_query(req)
            reply = step.reply()
        else:  # pragma: no cover - only trade requests are sent
            raise TypeError(f"unexpected request {req!r}")
        label = getattr(reply, "status", None) or getattr(reply, "reason", None) \
            or type(reply).__name__
        self.outcomes[f"{kind} {label}"] += 1
        if self._persist(node, recs, keep) and reply is not None:
            self._send(node.me, env.src, _ENC.encode(reply), (kind, req.trade_id))

    def _on_reply(self, node: Node, reply_to: ReplyTo, reply: Reply, keep: int | None) -> None:
        """``node`` gets the reply to its request ``reply_to`` (trade client)."""
        kind, tid = reply_to
        m = node.machine
        step: Step
        if kind == "offer":
            step = m.on_offer_reply(tid, reply)
            att = node.attempt
            if att is not None and att.trade_id == tid and step.outcome != "ignored":
                node.attempt = None
            if step.outcome == "commit":
                node.success()
        elif kind == "commit":
            step = m.on_commit_reply(tid, reply)
        else:
            step = m.on_decision(tid, reply)
            if step.outcome == "committed":
                node.success()
        self.outcomes[f"reply to {kind} {step.outcome}"] += 1
        if step.outcome != "ignored":
            self.log.append(f"  {node.me}: {step.outcome}")
        if self._persist(node, step.records, keep) and isinstance(step.message, Commit):
            tr = m.initiated.get(tid)
            assert tr is not None
            self._send(node.me, tr.partner, _ENC.encode(step.message))

    # -- invariants -----------------------------------------------------------------------
    def claims(self) -> dict[str, tuple[dict[int, int], dict[int, int]]]:
        """Every agent's (owned, held) ledger ({landmark id: version})."""
        return {a: (n.machine.owned, {k: v for k, (v, _t) in n.machine.held.items()})
                for a, n in self.nodes.items()}

    def violations(self) -> list[str]:
        """The ownership invariants on the current (consistent) state of every agent:

        * :func:`~agent.mission.invariants.snapshot_violations`: every landmark claimed
          (owned or held), by one agent at its highest version, owned by one agent at most;
        * the owner of a landmark owns it at its highest version (nobody holds it newer);
        * a (landmark, version) pair is claimed by one agent ever
          (:class:`~agent.mission.invariants.VersionHistory`), the highest version of a
          landmark among the claims never decreases;
        * a held landmark is held for a pending trade of its holder (a committed one it
          initiated, or one it prepared), so it will be resolved;
        * the two sides of a trade agree: a responder committed only what its initiator
          committed, restored only what it did not, and an initiator committed only what its
          responder prepared;
        * every machine is what its journal rebuilds (nothing changes state without a record
          handed to the runtime).
        """
        out: list[str] = []
        claims = self.claims()
        out += snapshot_violations(claims, self.owners)
        tops: dict[int, int] = {}
        for a, (owned, held) in claims.items():
            out += self.history.add(a, owned, held)
            for d in (owned, held):
                for lid, ver in d.items():
                    tops[lid] = max(tops.get(lid, -1), ver)
        for a, (owned, _held) in claims.items():
            out += [f"landmark {lid}: {a} owns version {ver} below its top {tops[lid]}"
                    for lid, ver in owned.items() if ver != tops[lid]]
        for lid, ver in tops.items():
            if ver < self.top.get(lid, -1):
                out.append(f"landmark {lid}: highest version went down from "
                           f"{self.top[lid]} to {ver}")
            self.top[lid] = max(ver, self.top.get(lid, -1))
        for a, n in self.nodes.items():
            m = n.machine
            for lid, (_ver, tid) in m.held.items():
                tr = m.initiated.get(tid)
                if not ((tr is not None and tr.state == "committed") or tid in m.prepared):
                    out.append(f"landmark {lid}: {a} holds it for {tid}, which is not pending")
            out += self._agreement(a, m)
            if durable_view(m) != durable_view(n.shadow):
                out.append(f"agent {a}: its state differs from what its journal rebuilds")
        return out

    def _agreement(self, a: str, m: TradeMachine) -> list[str]:
        out: list[str] = []
        for tid in sorted(m.r_committed | m.r_restored):
            parsed = parse_trade_id(tid)
            assert parsed is not None
            init = self.nodes[parsed[0]].machine
            committed = init.decided.get(tid) == "committed"
            if tid in m.r_committed and not committed:
                out.append(f"trade {tid}: {a} committed, its initiator did not")
            if tid in m.r_restored and committed:
                out.append(f"trade {tid}: {a} restored, its initiator committed")
        for tid, tr in m.initiated.items():
            if tr.state != "committed":
                continue
            r = self.nodes[tr.partner].machine
            if tid not in r.prepared and tid not in r.r_committed:
                out.append(f"trade {tid}: {a} committed, {tr.partner} has not prepared it")
        return out

    # -- the end ----------------------------------------------------------------------------
    def quiet(self) -> bool:
        """Nothing in flight, no offer waiting, no trade pending anywhere."""
        return not self.pending and all(
            n.attempt is None and not n.machine.pending_ids for n in self.nodes.values())

    def drain(self, rounds: int = 50) -> bool:
        """Heal the network and let the runtimes finish: deliver everything in order, fire
        every retry timer, again, until :meth:`quiet` (True) or ``rounds`` rounds (False).
        Checks the invariants after every delivery (AssertionError)."""
        for _ in range(rounds):
            for _d in range(10_000):
                if not self.pending:
                    break
                self.deliver(0)
                found = self.violations()
                assert not found, "\n".join([*found, "-- last steps:", *self.log[-25:]])
            if self.quiet():
                return True
            for a in self.nodes:
                self.timers(a)
        return self.quiet()

    def final_violations(self) -> list[str]:
        """At the end (after :meth:`drain`): every landmark owned by exactly one agent, at its
        highest version ever claimed, nothing held."""
        return final_violations(self.claims(), self.owners, self.history.highest)
