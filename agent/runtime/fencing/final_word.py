"""The team's final word: before it reports the mission complete, an agent hears the fence
record the router keeps (:mod:`agent.net.keeper`, :mod:`agent.wire.record`).

Why: fences live in the peers' states. A drone that comes back after its team finished and
left hears no peer at all; without this it would find itself alone, converged, and report the
mission complete with landmarks the team fenced it out of and adopted (two journals claiming
each). The router outlives the agents, so it can tell a late comer what the team decided.

* The record is asked for at the first tick (a drone that was fenced learns it at once) and
  again whenever the completion condition starts to hold (:class:`~agent.runtime.ends.completion.
  Completion` reports complete only once a record was heard after that moment).
* Its proofs go through :meth:`~agent.runtime.fencing.fence_claims.FenceClaims.learn`, checked like
any
  proof (the router is trusted with nothing): a valid proof fencing this agent drops its
  ledger and it leaves. Only an agent restarted from its journal (incarnation > 1) takes
  them: the router keeps a mission's record across runs of it, and a first start (a fresh
  journal: a new run on a long-running router) hears the fences of its own run from its live
  peers (a fresh journal while the team is mid-mission is refused at start,
  :mod:`agent.runners.recovery`).
* **A comeback on a new journal.** A drone killed before its journal's first write (so its
  team may never have heard it) and started again after its team fenced it out, adopted its
  landmarks and finished, starts on a fresh journal from the scenario's sets: the adopted
  landmarks. Its record's proofs are of an earlier run *or* of its own, and at its start the
  two look alike. So an agent on its first life whose record holds a valid proof fencing it
  while no other agent of the mission is live (on the router's clock) waits up to
  ``final_word_s`` for one, asking again: a new run's team (started fresh, holding no proof)
  lets it take part; the old team's members tell it with their proofs; nobody: it takes the
  proof and leaves fenced out, holding nothing (``told by fence-record``). A new run on a
  long-running router whose team starts more than ``final_word_s`` after it therefore goes
  on without it (fenced: its landmarks are adopted); the router's record can be cleared by
  starting it without ``--state-dir`` (or a fresh one) between runs.
* The wait is bounded (``AgentConfig.final_word_s``): past ``NOTICE_S`` of waiting one line
  says what the agent waits for; past the bound :attr:`FinalWord.gave_up` says why it cannot
  report complete, and the process leaves the mission incomplete (exit 3).
* Off (``final_word_s = 0``, the in-memory missions of the tests): nothing is asked.

The query is an ask of the core's tick, like a trade request, and waits at most
``request_timeout_s``.
"""

from __future__ import annotations

import logging
from typing import Final

from agent.runtime.core.events import Asking, ask_once
from agent.runtime.core.shared import Shared
from agent.runtime.ends.completion import Completion
from agent.runtime.fencing.fence_claims import FenceClaims
from agent.wire import keys
from agent.wire.record import RECORD_CODEC, FenceRecord

_log = logging.getLogger(f"viscover.{__name__}")

#: Who the record's proofs are said to come from (journaled with a fence learned from it).
BY_ROUTER: Final = "fence-record"
#: Real seconds of waiting after which the agent says what it waits for (once).
NOTICE_S: Final = 1.0
#: Real seconds between two asks while no record is heard (first), then doubling to 2 s.
ASK_GAP_S: Final = 0.25


class FinalWord:
    """The fence record of one agent (see the module docstring)."""

    def __init__(self, shared: Shared, claims: FenceClaims, completion: Completion) -> None:
        self.s = shared
        self.claims = claims
        self.completion = completion
        self.required = shared.cfg.final_word_s > 0.0
        self.record: FenceRecord | None = None  #: the last record heard
        self.heard_at: float | None = None  #: mission time it was heard [s]
        self.asks = 0  #: queries sent
        self.gave_up: str | None = None  #: why the agent cannot report complete (bound hit)
        self._next_ask = 0.0
        self._gap = ASK_GAP_S
        self._wait_since: float | None = None
        self._noticed = False
        #: mission time a first-life agent started waiting for a live peer while its record
        #: proves it fenced (module docstring; None: not waiting)
        self.comeback_since: float | None = None

    def _wanted(self, now: float) -> bool:
        """Whether a record must be heard now."""
        if self.heard_at is None or self.comeback_since is not None:
            return True
        since = self.completion.since
        return since is not None and self.heard_at < since

    def tick(self, now: float) -> Asking[None]:
        """Ask for the record if one is wanted and due."""
        s = self.s
        if not self.required or s.machine.fenced_out is not None or self.gave_up \
                or not self._wanted(now):
            self._wait_since = None
            return
        if self.completion.since is not None:
            self._bound(now)
        if now < self._next_ask:
            return
        self.asks += 1
        raw = yield from ask_once(keys.fences_key(s.cfg.mission), b"", s.cfg.request_timeout_s,
                                  "fences")
        rec = RECORD_CODEC.decode(raw, keys.fences_key(s.cfg.mission)) \
            if isinstance(raw, bytes) else None
        scale = s.cfg.time_scale
        if rec is None or rec.mission != s.cfg.mission:
            self._next_ask = s.now + self._gap * scale
            self._gap = min(2.0, 2 * self._gap)
            return
        self._gap = ASK_GAP_S
        self.record, self.heard_at = rec, now
        if s.machine.incarnation > 1:  # a restart: the record is of this run
            for proof in rec.proofs:
                self.claims.learn(proof, BY_ROUTER)
        else:
            self._comeback(rec, now)
        s.publish_soon()
        s.changed()

    def _comeback(self, rec: FenceRecord, now: float) -> None:
        """A first life whose record proves it fenced: wait for a live member, else take
        the proof at the bound (module docstring)."""
        s = self.s
        mine = [p for p in rec.proofs if s.id in p.fenced]
        others_live = set(rec.alive_for) - {s.id}
        if not mine or others_live or s.machine.fenced_out is not None:
            self.comeback_since = None
            return
        if self.comeback_since is None:
            self.comeback_since = now
            self._next_ask = now + ASK_GAP_S * s.cfg.time_scale  # asked again meanwhile
            _log.warning("agent %s: the router's fence record proves the team fenced this "
                         "drone out (round %d) and no team member is live: waiting up to %g s "
                         "for a team of a new run before leaving", s.id, mine[-1].epoch,
                         s.cfg.final_word_s / s.cfg.time_scale)
            return
        self._next_ask = now + 4 * ASK_GAP_S * s.cfg.time_scale
        if now - self.comeback_since >= s.cfg.final_word_s:
            for proof in mine:
                self.claims.learn(proof, BY_ROUTER)
            self.comeback_since = None

    def _bound(self, now: float) -> None:
        """The completion condition holds and no record was heard since: say so once, give
        up at the bound."""
        s = self.s
        if self._wait_since is None:
            self._wait_since = now
        waited = (now - self._wait_since) / s.cfg.time_scale
        if waited >= NOTICE_S and not self._noticed:
            self._noticed = True
            _log.warning("agent %s: waiting up to %g s for the team's final word (the fence "
                         "record the router keeps on %s) before reporting the mission complete",
                         s.id, s.cfg.final_word_s / s.cfg.time_scale,
                         keys.fences_key(s.cfg.mission))
        if now - self._wait_since >= s.cfg.final_word_s:
            self.gave_up = (
                f"no fence record from the router on {keys.fences_key(s.cfg.mission)} within "
                f"{s.cfg.final_word_s / s.cfg.time_scale:g} s (is the router a `viscover "
                "router`?): without the team's final word it does not report the mission "
                "complete (the team may have fenced it out and adopted its landmarks)")

    def heard_complete(self) -> set[str]:
        """The agents the last record heard report the mission complete, taken only by an
        agent restarted from its journal, as its proofs are."""
        if self.record is None or self.s.machine.incarnation <= 1:
            return set()
        return set(self.record.complete)

    def waiting(self, now: float) -> str | None:
        """Why completion must wait for the record (None: it need not)."""
        if not self.required or not self._wanted(now):
            return None
        return (f"the team's final word (the fence record on "
                f"{keys.fences_key(self.s.cfg.mission)}, kept by the router) not heard since "
                "the mission looked complete")
