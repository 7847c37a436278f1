"""The initiator's side of the trade protocol (section 4.5 over Zenoh queries): offer to the
next partner of the list, retry lost messages, and drive every pending trade to its end (Commit
until acknowledged; a prepared responder's StatusQuery until decided).

Loss costs little time. The trade's requests (Offer, Commit, StatusQuery; the machine
answers a repeated one as the first) are timed by measured round trips
(:class:`agent.net.rtt.RttEstimator`): a try sends up to ``request_copies`` copies one hedge
delay apart (two or three at a time while many copies go unanswered) and takes the first reply
of any copy, a late reply to an earlier copy too (:class:`~agent.net.contract.HedgingTransport`);
a try without a reply is tried again after about a hedge delay with half the copies and
doubled delays. Until a round trip is measured a try waits ``request_timeout_s`` (three
copies); on a transport that cannot send copies (the in-memory one) a try is one query waiting
that long, retried after the mission-time back-off (``backoff_s`` doubling up to
``backoff_cap_s``, as a Busy partner is on every transport). A converged agent with partners
to try is nearly always "trading" (its offer in flight) and answers offers with Busy, the more
so the longer offers last (loss): after a Busy("trading") answer it pauses its offers for
about as long as they last (``busy_pause``) and takes the others' meanwhile.

The decisions are the :class:`~agent.protocol.machine.TradeMachine`'s; this module sends its
messages as the core's asks (:mod:`agent.runtime.core.events`) and takes the replies the runtime
steps back in.

With a signing key (``AgentConfig.signing``, the secured profile) the runtime seals every
request (:mod:`agent.wire.signed`; the seal reads a clock and draws randomness, so it is not
the core's) and accepts a reply only if the partner signed it for that very request; a forged
or replayed reply comes back refused and is rejected here, counted and logged like an
undecodable one.
"""

from __future__ import annotations

import random
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Final, Literal

from agent.net.rtt import RttEstimator
from agent.protocol.machine import Outcome, Step
from agent.runtime.core.events import Asking, ask_hedged, ask_once
from agent.runtime.core.shared import Attempt, Shared, vec3
from agent.runtime.ends.membership import Membership
from agent.wire import keys
from agent.wire.codec import Codec
from agent.wire.peer import Commit, Reply, Request, StatusQuery
from agent.wire.signing import REASON_FORGED, REASON_STALE, Refusal

#: A partner's answer that our request named another incarnation of it (see
#: :mod:`agent.wire.signed`): its current one is learned, the request is sent again at once.
Stale = Literal["stale"]
STALE: Final[Stale] = "stale"

#: Supplies the current pose: (position [m; world ENU], unit camera direction, time [s]).
PoseNow = Callable[[], tuple[object, object, float]]


@dataclass
class _Retry:
    due: float
    tries: int = 0
    lost: int = 0  #: consecutive tries without a reply


@dataclass
class RequestStats:
    """What the hedged trade requests of one agent did (diagnostics and tests)."""

    calls: int = 0  #: tries (one per :meth:`TradeClient.trade_request`)
    copies: int = 0  #: copies sent in all
    unanswered: int = 0  #: tries no copy of which got a (valid) reply
    answered_by: Counter[int] = field(default_factory=Counter)  #: answered tries per copy


class TradeClient:
    """Offers, retries and pending-trade resolution of one agent."""

    def __init__(self, shared: Shared, hedging: bool, members: Membership,
                 c_req: Codec[Request], c_rep: Codec[Reply], pose_now: PoseNow) -> None:
        self.s = shared
        self.members = members
        self.c_req, self.c_rep = c_req, c_rep
        self.pose_now = pose_now
        #: the secured profile: the runtime seals our requests and opens the replies
        self.signed = shared.cfg.signing is not None
        self._rng = random.Random(f"{shared.cfg.seed}:{shared.id}")
        cfg = shared.cfg
        #: round trips of our trade requests (one estimator: every partner is on one mesh)
        self.rtt = RttEstimator(cfg.request_timeout_s, min(cfg.rto_min_s, cfg.request_timeout_s),
                                cfg.request_timeout_s)
        self.stats = RequestStats()
        #: copies per try, if the transport can send them (else one query per try)
        self.hedging = hedging and cfg.request_copies >= 1
        self._retries: dict[str, _Retry] = {}
        #: called with (partner, was a re-split) when an offer got NoTrade
        self.on_no_trade: list[Callable[[str, bool], None]] = []
        self._busy_tries: dict[str, int] = {}
        self._not_before: dict[str, float] = {}
        #: smoothed real time [s] our offers keep us "trading" (None: none measured yet)
        self.offer_time_s: float | None = None
        #: how long the last hedged try waited [real s] (answered copy's offset + round trip)
        self.last_wait_s = 0.0
        self._pause_until = 0.0  #: no offer before this mission time (after a Busy)
        shared.on_success.append(self._clear_backoffs)
        members.left_hooks.append(self._forget_partner)

    def _clear_backoffs(self) -> None:
        self._busy_tries.clear()
        self._not_before.clear()
        self._pause_until = 0.0

    def _forget_partner(self, agent_id: str) -> None:
        self._not_before.pop(agent_id, None)

    def forget(self, trade_id: str) -> None:
        """Stop retrying requests of ``trade_id`` (the trade ended)."""
        self._retries.pop(trade_id, None)

    def backoff(self, tries: int) -> float:
        """Retry delay [mission s] after ``tries`` failed tries: doubling, capped, jittered."""
        cfg = self.s.cfg
        base: float = min(cfg.backoff_cap_s, cfg.backoff_s * (2 ** max(0, tries - 1)))
        return base * self._rng.uniform(0.5, 1.5)

    def retry_gap(self, tries: int) -> float:
        """Delay [mission s] before the next try of a request whose ``tries``-th try got no
        reply: about one hedge delay with round trips measured, else :meth:`backoff`."""
        if not self.hedging:
            return self.backoff(tries)
        return self.s.cfg.time_scale * self.rtt.hedge * self._rng.uniform(0.5, 1.5)

    def busy_pause(self) -> float:
        """How long [mission s] to make no offer after a Busy("trading") answer: about as
        long as our offers last (measured, jittered; ``busy_pause``), see the module
        docstring."""
        d = self.offer_time_s
        if d is None or self.s.cfg.busy_pause <= 0.0:
            return 0.0
        return self.s.cfg.time_scale * self.s.cfg.busy_pause * d * self._rng.uniform(0.5, 1.5)

    # -- offers ----------------------------------------------------------------------------
    def maybe_offer(self, now: float) -> None:
        """A converged agent offers to the first partner not waiting out a back-off."""
        s = self.s
        if s.phase != "converged":
            return
        if now < self._pause_until:
            return
        partner = next(
            (x for x in s.partners.pending if self._not_before.get(x, 0.0) <= now), None
        )
        if partner is None:
            return
        p, v, _ = self.pose_now()
        step = s.machine.new_offer(partner, vec3(p), vec3(v))
        s.journal(step)
        assert step.trade_id is not None
        s.begin_offer(Attempt(step.trade_id, partner, self.c_req.encode(step.request()),
                              due=now))
        s.counters.offers_sent += 1

    def request(self, partner: str, payload: bytes) -> Asking[Reply | None]:
        """Query ``partner``'s trade queryable once (one copy, waiting ``request_timeout_s``;
        once more at once if the partner answered that it is another incarnation than the
        request was made for: first contact or restart); the decoded reply, or None (lost,
        timeout). Any request; the trade's own requests go through :meth:`trade_request`."""
        key = keys.trade_key(self.s.cfg.mission, partner)
        for _ in range(2):
            c = self.s.counters
            c.requests += 1
            c.bytes_out += len(payload)
            raw = yield from ask_once(key, payload, self.s.cfg.request_timeout_s, "trade")
            reply = self._reply(partner, key, raw)
            if not isinstance(reply, str):  # else STALE
                return reply
        return None

    def trade_request(self, partner: str, payload: bytes, tries: int = 0
                      ) -> Asking[Reply | None]:
        """One try of an idempotent trade request (Offer, Commit, StatusQuery; ``tries``
        earlier tries of it got no reply) to ``partner``: up to ``request_copies`` copies one
        hedge delay apart (see the module docstring), the first valid reply decoded, or None
        (no reply within the try, or a rejected one). Counted
        as one request; every copy's bytes count. Signed copies are sealed one by one (a
        repeated envelope would be refused as a replay) and a reply must be bound to the copy
        it answers; a stale answer (the partner is another incarnation than we knew) is
        followed at once by a second try."""
        if not self.hedging:
            return (yield from self.request(partner, payload))
        for _ in range(2):
            reply = yield from self._hedged_try(partner, payload, tries)
            if not isinstance(reply, str):  # else STALE
                return reply
        return None

    def _hedged_try(self, partner: str, payload: bytes, tries: int
                    ) -> Asking[Reply | Stale | None]:
        """One hedged try of :meth:`trade_request` (every copy that may be sent sealed on its
        own, see :meth:`trade_request`)."""
        cfg = self.s.cfg
        key = keys.trade_key(cfg.mission, partner)
        offsets, timeout = self.rtt.schedule(cfg.request_copies, tries)
        sent = [off for off in offsets if off < timeout]
        got, refusal = yield from ask_hedged(key, (payload,) * len(sent), tuple(sent), timeout,
                                             "trade")
        c, st = self.s.counters, self.stats
        c.requests += 1
        c.bytes_out += got.bytes_out
        st.calls += 1
        st.copies += got.sent
        self.last_wait_s = timeout if got.payload is None or got.rtt_s is None \
            else offsets[got.copy] + got.rtt_s
        reply = self._reply(partner, key, got.payload if refusal is None else refusal)
        if isinstance(reply, str):  # STALE
            return reply
        self.rtt.copies_lost(got.sent, None if reply is None else got.copy)
        if reply is None:
            st.unanswered += 1
            return None
        st.answered_by[got.copy] += 1
        if got.rtt_s is not None:
            self.rtt.sample(got.rtt_s)
        return reply

    def _reply(self, partner: str, key: str, raw: bytes | Refusal | None
               ) -> Reply | Stale | None:
        """The reply ``raw`` of ``partner`` to our request (opened by the runtime on the
        signed profile), decoded and checked; None if absent, or rejected (counted and
        logged); :data:`STALE` if the partner answered with its current incarnation (learned
        by the runtime's seal: ask again)."""
        if raw is None:
            return None
        if isinstance(raw, Refusal):
            if raw.reason == REASON_STALE:
                return STALE
            self.c_rep.reject(raw.reason, key, raw.detail)
            return None
        reply = self.c_rep.decode(raw, key)
        if reply is not None and self.signed and reply.sender != partner:
            self.c_rep.reject(REASON_FORGED, key, f"reply names {reply.sender!r}")
            return None
        return reply

    def attempt_offer(self, now: float) -> Asking[None]:
        """Send the pending offer once (if due) and act on the reply."""
        s = self.s
        att = s.attempt
        if att is None or now < att.due:
            return
        reply = yield from self.trade_request(att.partner, att.payload, att.tries)
        if self.hedging:
            d = self.last_wait_s
            self.offer_time_s = d if self.offer_time_s is None else \
                self.offer_time_s + 0.125 * (d - self.offer_time_s)
        if s.attempt is not att:
            return
        if reply is None or getattr(reply, "trade_id", None) != att.trade_id:
            self._no_reply(att)
        else:
            self._on_reply(att, reply, now)
        s.changed()

    def _no_reply(self, att: Attempt) -> None:
        s, cfg = self.s, self.s.cfg
        s.counters.timeouts += 1
        att.tries += 1
        limit = cfg.max_offer_tries_live if att.partner in self.members.live \
            else cfg.max_offer_tries
        if att.tries < limit:
            att.due = s.now + self.retry_gap(att.tries)
            return
        s.journal(s.machine.abort_offer(att.trade_id, "timeout"))
        att.outcome = "timeout"
        s.forget_goal(att.trade_id)
        s.partners.drop(att.partner)
        s.end_offer()
        s.counters.count("timeout")
        s.publish_soon()

    def _on_reply(self, att: Attempt, reply: Reply, now: float) -> None:
        s = self.s
        step = s.machine.on_offer_reply(att.trade_id, reply)
        s.journal(step)
        s.counters.count(step.outcome)
        if step.outcome == "ignored":
            return  # an answer that does not belong to this offer: keep waiting
        att.outcome = step.outcome
        s.end_offer()
        if step.outcome != "commit":
            s.forget_goal(att.trade_id)
        if step.outcome == "commit":
            self._retries[att.trade_id] = _Retry(due=now)
            s.committed(att.trade_id)
            s.success()
        elif step.outcome == "retry_later":
            s.counters.busy += 1
            n = self._busy_tries.get(att.partner, 0) + 1
            self._busy_tries[att.partner] = n
            if n > s.cfg.busy_retries:
                s.partners.drop(att.partner)
            else:
                self._not_before[att.partner] = now + self.backoff(n)
                self._pause_until = s.now + self.busy_pause()
                if att.partner in s.partners.pending:
                    s.partners.pending.remove(att.partner)
                    s.partners.pending.append(att.partner)
        else:  # drop, drop_both
            if step.outcome == "drop":
                s.counters.busy += 1
            s.partners.drop(att.partner)
            if step.outcome == "drop_both":
                for hook in self.on_no_trade:
                    hook(att.partner, att.regroup)
        s.publish_soon()

    # -- pending trades --------------------------------------------------------------------
    def service_pending(self, now: float) -> Asking[None]:
        """Send Commit for unacknowledged commits and StatusQuery for trades in doubt."""
        s = self.s
        commits = s.machine.unacked_commits()
        doubts = s.machine.doubts()
        live = {t for t, _ in commits} | {t for t, _ in doubts}
        for t in list(self._retries):
            if t not in live:
                del self._retries[t]
        for tid, partner in commits:
            yield from self._resolve(now, tid, partner, Commit(sender=s.id, trade_id=tid), now,
                                     s.machine.on_commit_reply, {"done"})
        for tid, partner in doubts:
            yield from self._resolve(now, tid, partner, StatusQuery(sender=s.id, trade_id=tid),
                                     now + s.cfg.doubt_delay_s, s.machine.on_decision,
                                     {"committed", "restored"})

    def _resolve(self, now: float, tid: str, partner: str, request: Request, first_due: float,
                 handle: Callable[[str, Reply], Step], final: set[Outcome]) -> Asking[None]:
        """One due try of a pending trade's request (Commit or StatusQuery) to ``partner``:
        ``handle`` the reply; unless its outcome is ``final``, retry later with back-off."""
        s = self.s
        r = self._retries.setdefault(tid, _Retry(due=first_due))
        if now < r.due:
            return
        reply = yield from self.trade_request(partner, self.c_req.encode(request), r.lost)
        step = handle(tid, reply) if reply is not None else Step()
        s.journal(step)
        if step.outcome == "committed":  # R learned the decision: the trade succeeded
            s.committed(tid)
            s.success()
        elif step.outcome == "restored":
            s.forget_goal(tid)
        if step.outcome not in final:
            r.tries += 1
            if reply is None:
                s.counters.timeouts += 1
                r.lost += 1
                r.due = s.now + self.retry_gap(r.lost)
            else:  # answered, not decided yet (e.g. "pending"): back off
                r.lost = 0
                r.due = s.now + self.backoff(r.tries)
        if step.records:
            s.changed()
