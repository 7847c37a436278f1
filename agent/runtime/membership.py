"""Who takes part in the mission, as one agent sees it: liveliness tokens (join / leave), the
peers' latest states and positions, and the checks every peer publication must pass.

Publications arrive on transport threads; every handler takes the shared lock. A payload
that does not decode, names another sender than its key, or carries impossible values is
rejected and counted (never raised).

Nothing a single unverified message says holds the mission up for ever (the open profile is
unauthenticated by design):

* a peer's latest state is chosen by :class:`~agent.wire.streams.LatestStates`: a forged
  state with a huge incarnation is the latest only until the genuine stream has spoken twice
  after a silence of ``fresh_periods`` state periods;
* a peer counts as *live* while its liveliness token is present **and** it speaks (a state or
  a pose at least every ``silent_s``); a token without states (forged, or a stuck process)
  counts as gone after ``silent_s``, and said so in one line: the team then treats it as any
  absent agent (fenced after ``lost_after``, its landmarks adopted). It is live again as soon
  as it speaks.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import TYPE_CHECKING, TypeVar

import numpy as np

from agent.runtime.shared import Array, Shared, unit_ok
from agent.storage.journal import JournalFailed
from agent.wire import keys
from agent.wire.codec import Codec
from agent.wire.peer import AgentState, Pose, Publication, unpack
from agent.wire.streams import LatestStates

if TYPE_CHECKING:
    from agent.runtime.completion import Completion

REASON_SENDER = "sender"
REASON_UNKNOWN_AGENT = "unknown_agent"
REASON_IMPOSSIBLE = "impossible"

P = TypeVar("P", Pose, AgentState)

_log = logging.getLogger(f"viscover.{__name__}")


class Membership:
    """Peers' liveliness, states and positions [m; world ENU] (see the module docstring)."""

    def __init__(self, shared: Shared, codec: Codec[Publication], completion: Completion) -> None:
        self.s = shared
        self.codec = codec
        self.completion = completion
        me = shared.id
        #: last known position of every other scenario agent (initially its start position)
        self.others_pos: dict[str, Array] = {
            a.id: a.p0.astype(np.float64) for a in shared.sc.agents if a.id != me
        }
        #: latest state of each peer and the mission time it arrived
        self.states: dict[str, tuple[AgentState, float]] = {}
        self.live: set[str] = set()  #: peers whose liveliness token is present, speaking
        self.tokens: set[str] = set()  #: peers whose liveliness token is present
        #: mission time each peer last spoke (a state or pose) or its token appeared
        self.heard: dict[str, float] = {}
        #: each peer's freshest pose: position [m; world ENU], unit direction, mission time
        #: heard [s] (the pose check of offers, agent.runtime.pose_check)
        self.poses: dict[str, tuple[Array, Array, float]] = {}
        cfg = shared.cfg
        self.latest = LatestStates(cfg.fresh_periods * cfg.state_period_s)
        self.ever_seen: set[str] = set()  #: peers seen alive at least once
        self.last_departure: float | None = None  #: when a busy peer last left
        #: called (under the lock) with the id of a peer that left
        self.left_hooks: list[Callable[[str], None]] = []
        #: called (under the lock) with every new state of a peer
        self.state_hooks: list[Callable[[AgentState], None]] = []
        #: whether we may trade with a live peer (a joiner: only with those that admitted it)
        self.may_trade: Callable[[str], bool] = \
            lambda aid: aid in shared.order or aid in shared.machine.members
        self._unknown_live: set[str] = set()  #: tokens of drones not (yet) admitted

    def team_order(self) -> list[str]:
        """The scenario's agents in order, then the admitted joiners (ids ascending)."""
        s = self.s
        return [*s.order, *sorted(s.machine.members - set(s.order) - {s.id})]

    def admit(self, aid: str, p: tuple[float, float, float] | None) -> None:
        """A joiner was admitted (under the lock; ``p`` its position [m; world ENU] if known):
        known from now on, a partner if live."""
        if p is not None and aid not in self.others_pos:
            self.others_pos[aid] = np.asarray(p, dtype=np.float64)
        if aid in self._unknown_live:
            self._unknown_live.discard(aid)
            self.tokens.add(aid)
            self.heard[aid] = max(self.heard.get(aid, -np.inf), self.s.clock.now())
            self.live.add(aid)
            self.ever_seen.add(aid)
            self.partner_joined(aid)

    def partner_joined(self, aid: str) -> None:
        """``aid`` is live and we may trade with it: a partner to try (section 4.5; under the
        lock)."""
        s = self.s
        if aid in s.machine.fenced or s.machine.fenced_out is not None or not s.vision_trades:
            return  # a lost agent back: not a partner any more (or we are the lost one)
        if aid not in s.partners.everyone:
            present = set(s.partners.everyone) | {aid}
            s.partners.everyone = tuple(a for a in self.team_order() if a in present)
        if aid not in s.partners.pending:
            s.partners.pending.append(aid)
            self.completion.restart()
        s.dirty = True

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
        with self.s.lock:
            if msg.sender in self.others_pos:
                self.others_pos[msg.sender] = np.asarray(msg.p, dtype=np.float64)
            self._spoke(msg.sender, msg.p, msg.v)

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
        with self.s.lock:
            now = self.s.clock.now()
            if not self.latest.offer(msg.sender, msg.incarnation, msg.seq, now):
                self.heard[msg.sender] = now  # it speaks, but this state is not its latest
                return  # older, repeated, or another stream while the current one speaks
            self._spoke(msg.sender, msg.p, msg.v)
            self.states[msg.sender] = (msg, now)
            # Liveliness is the authority on who is alive now, but a join event can be missed
            # (token declared while our watcher was being set up): a state proves the agent
            # has started.
            self.ever_seen.add(msg.sender)
            self.others_pos[msg.sender] = np.asarray(msg.p, dtype=np.float64)
            try:
                for hook in self.state_hooks:
                    hook(msg)
            except JournalFailed as e:  # a fence learned could not be journaled: leave
                self.s.failed = e

    def on_join(self, key: str) -> None:
        """A liveliness token appeared: a partner to try again (section 4.5)."""
        s = self.s
        aid = keys.try_agent_of(key)
        if aid is None or aid == s.id:
            return
        with s.lock:
            if aid not in s.order and aid not in s.machine.members:
                self._unknown_live.add(aid)  # a joiner not admitted (yet)
                return
            self.tokens.add(aid)
            self.heard[aid] = max(self.heard.get(aid, -np.inf), s.clock.now())
            self._come(aid)

    def _come(self, aid: str) -> None:
        """``aid`` is live (token present, speaking): a partner to try (under the lock)."""
        s = self.s
        self.live.add(aid)
        self.ever_seen.add(aid)
        if self.may_trade(aid):
            self.partner_joined(aid)
        s.dirty = True

    def _spoke(self, aid: str, p: tuple[float, float, float],
               v: tuple[float, float, float]) -> None:
        """``aid`` published a valid state or pose at pose (p, v) (under the lock)."""
        now = self.s.clock.now()
        self.heard[aid] = now
        self.poses[aid] = (np.asarray(p, dtype=np.float64), np.asarray(v, dtype=np.float64), now)
        if aid in self.tokens and aid not in self.live:
            _log.warning("agent %s: %s speaks again: live", self.s.id, aid)
            self._come(aid)

    def sweep(self, now: float) -> None:
        """Peers whose token is present but that have not spoken for ``silent_s`` count as
        gone, each said in one line (under the lock; every tick)."""
        quiet = self.s.cfg.silent_s
        for aid in sorted(self.live):
            if now - self.heard.get(aid, now) > quiet:
                _log.warning("agent %s: %s holds a liveliness token but published nothing for "
                             "%.1f s: counted as gone (its landmarks are adopted after "
                             "lost_after unless it speaks)", self.s.id, aid,
                             (now - self.heard[aid]) / self.s.clock.time_scale)
                self._gone(aid)

    def on_leave(self, key: str) -> None:
        """A liveliness token vanished: the peer leaves every partner list; if it left in the
        middle of its work (a crash?) completion waits a grace period for it to come back."""
        s = self.s
        aid = keys.try_agent_of(key)
        if aid is None or aid == s.id:
            return
        with s.lock:
            self.tokens.discard(aid)
            self._unknown_live.discard(aid)
            self._gone(aid)

    def _gone(self, aid: str) -> None:
        """``aid`` left (its token vanished, or it fell silent): out of every partner list
        (under the lock)."""
        s = self.s
        self.live.discard(aid)
        last = self.states.get(aid)
        if last is None or not quiet_state(last[0]):
            self.last_departure = s.clock.now()
            self.completion.restart()
        s.partners.forget(aid)
        for hook in self.left_hooks:
            hook(aid)
        s.dirty = True

    def coverage_estimate(self, own_vision: float) -> float:
        """Eq. 3.10 as this agent knows it: its own vision plus the live peers' last ones."""
        return own_vision + sum(st.vision for aid, (st, _t) in self.states.items()
                                if aid in self.live)


def quiet_state(st: AgentState) -> bool:
    """Converged, empty partner list, nothing pending."""
    return st.phase == "converged" and not st.partners and not st.pending
