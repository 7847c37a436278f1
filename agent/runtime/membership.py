"""Who takes part in the mission, as one agent sees it: the adapter around the pure
:class:`~agent.protocol.peers.PeerBook` (liveliness tokens, the peers' latest states and
positions, who is live). It checks every peer publication, feeds the book with the mission
time, and acts on the book's events: a peer that came is a partner to try again (section
4.5), a peer gone leaves every partner list, and one gone while busy restarts completion's
hold.

Publications are stepped into the core as samples (:class:`agent.runtime.events.Sample`). A payload
that does not decode, names another sender than its key, or carries impossible values is
rejected and counted (never raised). A token held without speaking for ``silent_s`` is said
in one line: the team then treats that peer as any absent agent (fenced after
``lost_after``, its landmarks adopted) until it speaks again.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import TypeVar

from agent.protocol.peers import Came, PeerBook, PeerEvent
from agent.runtime.shared import Array, Shared, unit_ok
from agent.wire import keys
from agent.wire.codec import Codec
from agent.wire.peer import AgentState, Pose, Publication, unpack

REASON_SENDER = "sender"
REASON_UNKNOWN_AGENT = "unknown_agent"
REASON_IMPOSSIBLE = "impossible"

P = TypeVar("P", Pose, AgentState)

_log = logging.getLogger(f"viscover.{__name__}")


class Membership:
    """Peers' liveliness, states and positions [m; world ENU] (see the module docstring)."""

    def __init__(self, shared: Shared, codec: Codec[Publication],
                 restart_completion: Callable[[], None]) -> None:
        self.s = shared
        self.codec = codec
        #: something happened that may need more trades: completion's hold starts again
        #: (:meth:`agent.runtime.completion.Completion.restart`)
        self.restart_completion = restart_completion
        cfg = shared.cfg
        self.book = PeerBook(shared.id, {a.id: a.p0 for a in shared.sc.agents},
                             cfg.fresh_periods * cfg.state_period_s, cfg.silent_s)
        #: called with the id of a peer that left
        self.left_hooks: list[Callable[[str], None]] = []
        #: called with every new state of a peer
        self.state_hooks: list[Callable[[AgentState], None]] = []
        #: whether we may trade with a live peer (a joiner: only with those that admitted it)
        self.may_trade: Callable[[str], bool] = \
            lambda aid: aid in shared.order or aid in shared.machine.members

    # -- the book's views ------------------------------------------------
    @property
    def others_pos(self) -> dict[str, Array]:
        """Last known position of every other known agent [m; world ENU]."""
        return self.book.others_pos

    @property
    def states(self) -> dict[str, tuple[AgentState, float]]:
        """Each peer's latest state and the mission time it arrived [s]."""
        return self.book.states

    @property
    def live(self) -> set[str]:
        """Peers whose liveliness token is present and that speak."""
        return self.book.live

    @property
    def poses(self) -> dict[str, tuple[Array, Array, float]]:
        """Each peer's freshest pose: position [m; world ENU], unit direction, mission time
        heard [s] (the pose check of offers, :mod:`agent.runtime.pose_check`)."""
        return self.book.poses

    @property
    def ever_seen(self) -> set[str]:
        """Peers seen alive at least once."""
        return self.book.ever_seen

    @property
    def last_departure(self) -> float | None:
        """Mission time [s] a peer last left while busy (None: never)."""
        return self.book.last_departure

    def coverage_estimate(self, own_vision: float) -> float:
        """Eq. 3.10 as this agent knows it: its own vision plus the live peers' last ones."""
        return self.book.coverage_estimate(own_vision)

    def team_order(self) -> list[str]:
        """The scenario's agents in order, then the admitted joiners (ids ascending)."""
        s = self.s
        return [*s.order, *sorted(s.machine.members - set(s.order) - {s.id})]

    def admit(self, aid: str, p: tuple[float, float, float] | None) -> None:
        """A joiner was admitted (``p`` its position [m; world ENU] if known):
        known from now on, a partner if live."""
        for ev in self.book.admit(aid, p, self.s.now):
            self.partner_joined(ev.aid)

    def partner_joined(self, aid: str) -> None:
        """``aid`` is live and we may trade with it: a partner to try (section 4.5)."""
        s = self.s
        if aid in s.machine.fenced or s.machine.fenced_out is not None or not s.vision_trades:
            return  # a lost agent back: not a partner any more (or we are the lost one)
        if aid not in s.partners.everyone:
            present = set(s.partners.everyone) | {aid}
            s.partners.everyone = tuple(a for a in self.team_order() if a in present)
        if aid not in s.partners.pending:
            s.partners.pending.append(aid)
            self.restart_completion()
        s.publish_soon()

    def knows(self, agent_id: str) -> bool:
        """Whether ``agent_id`` is this agent, one of the scenario's other agents or an
        admitted joiner."""
        return agent_id in self.others_pos or agent_id == self.s.id \
            or agent_id in self.s.machine.members

    def _check_sender(self, key: str, sender: str) -> bool:
        agent = keys.try_agent_of(key)
        if agent is None or agent != sender:
            self.codec.reject(REASON_SENDER, key, f"sender {sender!r} on {key}")
            return False
        if not self.knows(sender):
            self.codec.reject(REASON_UNKNOWN_AGENT, key, f"unknown agent {sender!r}")
            return False
        return True

    def peer_publication(self, key: str, payload: bytes, kind: type[P], what: str) -> P | None:
        """Decode a peer's publication of type ``kind`` on ``key``; None (counted) if bad,
        None (silently) if it is our own."""
        msg = self.codec.decode(payload, key)
        if msg is None:
            return None
        if not isinstance(msg, kind):
            self.codec.reject(REASON_IMPOSSIBLE, key, f"{type(msg).__name__} on a {what} key")
            return None
        if not self._check_sender(key, msg.sender) or msg.sender == self.s.id:
            return None
        return msg

    def on_pose(self, key: str, payload: bytes) -> None:
        """A peer's pose: remember its position (an obstacle of section 4.3)."""
        msg = self.peer_publication(key, payload, Pose, "pose")
        if msg is None:
            return
        if not unit_ok(msg.v):
            self.codec.reject(REASON_IMPOSSIBLE, key, "direction not unit")
            return
        self._apply(self.book.pose(msg.sender, msg.p, msg.v, self.s.now))

    def on_state(self, key: str, payload: bytes) -> None:
        """A peer's state: keep the newest (by incarnation, then sequence number)."""
        msg = self.peer_publication(key, payload, AgentState, "state")
        if msg is None:
            return
        owned, held = unpack(msg.owned), unpack(msg.held)
        machine = self.s.machine
        if not (unit_ok(msg.v) and owned is not None and held is not None
                and machine.knows(owned[0]) and machine.knows(held[0])):
            self.codec.reject(REASON_IMPOSSIBLE, key, "state with impossible values")
            return
        latest, events = self.book.state(msg, self.s.now)
        self._apply(events)
        if not latest:
            return  # older, repeated, or another stream while the current one speaks
        for hook in self.state_hooks:
            hook(msg)

    def on_join(self, key: str) -> None:
        """A liveliness token appeared: a partner to try again (section 4.5)."""
        s = self.s
        aid = keys.try_agent_of(key)
        if aid is None:
            return
        known = aid in s.order or aid in s.machine.members
        self._apply(self.book.token_appeared(aid, known, s.now))

    def on_leave(self, key: str) -> None:
        """A liveliness token vanished: the peer leaves every partner list; if it left in the
        middle of its work (a crash?) completion waits a grace period for it to come back."""
        aid = keys.try_agent_of(key)
        if aid is None:
            return
        self._apply(self.book.token_vanished(aid, self.s.now))

    def sweep(self, now: float) -> None:
        """Peers whose token is present but that have not spoken for ``silent_s`` count as
        gone, each said in one line (every tick)."""
        self._apply(self.book.sweep(now))

    def _apply(self, events: list[PeerEvent]) -> None:
        """Act on the book's events."""
        s = self.s
        for ev in events:
            if isinstance(ev, Came):
                if ev.again:
                    _log.warning("agent %s: %s speaks again: live", s.id, ev.aid)
                if self.may_trade(ev.aid):
                    self.partner_joined(ev.aid)
            else:
                if ev.silent_s is not None:
                    _log.warning("agent %s: %s holds a liveliness token but published "
                                 "nothing for %.1f s: counted as gone (its landmarks are "
                                 "adopted after lost_after unless it speaks)", s.id, ev.aid,
                                 ev.silent_s / s.cfg.time_scale)
                if ev.busy:
                    self.restart_completion()
                s.partners.forget(ev.aid)
                for hook in self.left_hooks:
                    hook(ev.aid)
            s.publish_soon()
