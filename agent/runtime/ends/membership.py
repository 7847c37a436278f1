"""Who takes part in the mission, as one agent sees it: the adapter around the pure
:class:`~agent.protocol.peers.PeerBook` (liveliness tokens, the peers' latest states and
positions, who is live). It checks every peer publication, feeds the book with the mission
time, and acts on the book's events: a peer that came is a partner to try again (section
4.5), a peer gone leaves every partner list, and one gone while busy restarts completion's
hold.

Publications are stepped into the core as samples (:class:`agent.runtime.core.events.Sample`). A
payload
that does not decode, names another sender than its key, or carries impossible values is
rejected and counted (never raised). A token held without speaking for ``silent_s`` is said
in one line: the team then treats that peer as any absent agent (fenced after
``lost_after``, its landmarks adopted) until it speaks again.

**Whose pose is it.** On the secured profile only a peer's certificate may publish on its
``pose`` key, but a thief holding that certificate can publish a made-up pose there while the
real drone publishes its own. Each peer's pose samples are followed as *runs* (consecutive
samples within ``pose_tolerance_m`` of each other): a sample that jumps farther starts a new
run, and one that jumps while its sequence number goes back (a second publisher on the key)
marks the peer's pose *contested* for ``fresh_periods`` state periods
(:class:`PoseRuns`). Offers are judged against the first run heard, or a later one at least
one state period old, and never while contested (:mod:`agent.runtime.ends.pose_check`).
Where the ground station publishes the peer's mocap (``witness``), a published pose sample
farther than ``pose_tolerance_m`` from it is refused (reject reason ``pose_off_mocap``) and
not used.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import TypeVar

import numpy as np

from agent.protocol.peers import Came, PeerBook, PeerEvent
from agent.runtime.core.shared import Array, Shared, unit_ok
from agent.wire import keys
from agent.wire.codec import Codec
from agent.wire.peer import AgentState, Pose, Publication, unpack

REASON_SENDER = "sender"
REASON_UNKNOWN_AGENT = "unknown_agent"
REASON_IMPOSSIBLE = "impossible"
#: Reject reason of a published pose off the ground station's mocap of its sender.
REASON_OFF_MOCAP = "pose_off_mocap"

P = TypeVar("P", Pose, AgentState)

_log = logging.getLogger(f"viscover.{__name__}")


@dataclass
class _Run:
    """One peer's current run of pose samples (see the module docstring)."""

    seq: int  #: sequence number of its last pose sample (-1: none yet)
    p: Array  #: its last position [m; world ENU]
    since: float  #: mission time the run began [s]
    contested_until: float = -1.0  #: mission time [s] the pose stays contested until


class PoseRuns:
    """Each known peer's run of consistent pose samples and whether a second publisher
    contests it (module docstring). One entry per known peer (bounded by the team)."""

    def __init__(self, tolerance_m: float, contest_s: float) -> None:
        self.tol = tolerance_m
        self.contest_s = contest_s
        self.runs: dict[str, _Run] = {}
        self.contests = 0  #: samples that showed a second publisher

    def heard(self, aid: str, p: Array, seq: int | None, now: float) -> None:
        """A sample of ``aid`` at ``p`` [m] (``seq``: a pose's sequence number; None: a
        state's position) heard at mission time ``now`` [s]."""
        run = self.runs.get(aid)
        if run is None:  # the first run heard: trusted from its first sample
            self.runs[aid] = _Run(-1 if seq is None else seq, p, -math.inf)
            return
        with np.errstate(over="ignore", invalid="ignore"):
            jump = not bool(np.linalg.norm(p - run.p) <= self.tol)
        if jump:
            if seq is not None and 0 <= seq <= run.seq:  # an older stream speaks far away
                run.contested_until = now + self.contest_s
                self.contests += 1
            run.since = now
        run.p = p
        if seq is not None:
            run.seq = seq

    def contested(self, aid: str, now: float) -> bool:
        """Whether two publishers were heard on ``aid``'s pose lately."""
        run = self.runs.get(aid)
        return run is not None and now < run.contested_until

    def age(self, aid: str, now: float) -> float:
        """How long ``aid``'s current run has lasted [mission s] (-1: no sample)."""
        run = self.runs.get(aid)
        return -1.0 if run is None else now - run.since


class Membership:
    """Peers' liveliness, states and positions [m; world ENU] (see the module docstring)."""

    def __init__(self, shared: Shared, codec: Codec[Publication],
                 restart_completion: Callable[[], None]) -> None:
        self.s = shared
        self.codec = codec
        #: something happened that may need more trades: completion's hold starts again
        #: (:meth:`agent.runtime.ends.completion.Completion.restart`)
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
        #: each peer's runs of pose samples (who publishes on its pose key)
        self.runs = PoseRuns(cfg.pose_tolerance_m, cfg.fresh_periods * cfg.state_period_s)
        #: the independent witness of a peer's position: the ground station's fresh mocap of
        #: it [m; world ENU] or None (set by :class:`~agent.runtime.ends.pose_check.PoseCheck`)
        self.witness: Callable[[str], Array | None] = lambda _aid: None

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
        heard [s] (the pose check of offers, :mod:`agent.runtime.ends.pose_check`)."""
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
        if not self.knows(sender):  # counted under the key's kind: anyone may name any id
            self.codec.reject(REASON_UNKNOWN_AGENT, key.rsplit("/", 1)[0] + "/*",
                              f"unknown agent {sender!r}")
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
        if not self._witnessed(key, msg.sender, msg.p):
            return
        self.runs.heard(msg.sender, np.asarray(msg.p, dtype=np.float64), msg.seq, self.s.now)
        self._apply(self.book.pose(msg.sender, msg.p, msg.v, self.s.now))

    def _witnessed(self, key: str, sender: str, p: tuple[float, float, float]) -> bool:
        """False (counted) if the ground station's fresh mocap of ``sender`` puts it farther
        than the tolerance from the published position ``p`` [m]."""
        seen = self.witness(sender)
        if seen is None:
            return True
        with np.errstate(over="ignore", invalid="ignore"):
            d = float(np.linalg.norm(np.asarray(p, dtype=np.float64) - seen))
        if d <= self.s.cfg.pose_tolerance_m:
            return True
        self.codec.reject(REASON_OFF_MOCAP, key,
                          f"{sender} publishes a pose {d:.2f} m off the ground station's mocap")
        return False

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
        self.runs.heard(msg.sender, np.asarray(msg.p, dtype=np.float64), None, self.s.now)
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
