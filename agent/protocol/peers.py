"""Who takes part in the mission, as one agent sees it, as a pure state machine: liveliness
tokens, the peers' latest states, their freshest poses, and who counts as *live*.

No clock, no lock, no decoding: the runtime (:mod:`agent.runtime.ends.membership`) checks each
publication, then feeds it here with the mission time it arrived, and acts on the events
returned (:class:`Came`: a partner to try again; :class:`Gone`: out of every partner list).

Nothing a single unverified message says holds the mission up for ever:

* a peer's latest state is chosen by :class:`~agent.wire.streams.LatestStates`: a forged
  state with a huge incarnation is the latest only until the genuine stream has spoken twice
  after a silence of ``fresh_s``;
* a peer is *live* while its liveliness token is present **and** it speaks (a state or a pose
  at least every ``silent_s``); a token without states (forged, or a stuck process) is gone
  after ``silent_s`` (:meth:`PeerBook.sweep`) and live again as soon as it speaks.

A peer that leaves while it was not quiet (converged, nothing to try, nothing pending) may
have crashed in the middle of its work: :attr:`PeerBook.last_departure` says when, and
completion waits a grace period after it (:mod:`agent.protocol.completion`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from agent.wire.peer import AgentState
from agent.wire.streams import LatestStates

Array = NDArray[np.float64]
Vec = tuple[float, float, float]


@dataclass(frozen=True)
class Came:
    """Peer ``aid`` is live now (token present and speaking)."""

    aid: str
    again: bool = False  #: it had fallen silent with its token present and speaks again


@dataclass(frozen=True)
class Gone:
    """Peer ``aid`` is not live any more: its token vanished, or (``silent_s`` not None) it
    held its token without speaking for ``silent_s`` [mission s]."""

    aid: str
    busy: bool  #: its last state was not quiet (or it never published one)
    silent_s: float | None = None


PeerEvent = Came | Gone


def quiet_state(st: AgentState) -> bool:
    """Converged, empty partner list, nothing pending."""
    return st.phase == "converged" and not st.partners and not st.pending


class PeerBook:
    """One agent's view of its peers (see the module docstring).

    Args:
        me: this agent's id.
        start_positions: each other scenario agent's start position [m; world ENU].
        fresh_s: a state older than this [mission s] may be replaced by another stream.
        silent_s: a token without a state or pose for this long [mission s] counts as gone.
    """

    def __init__(self, me: str, start_positions: dict[str, Array], fresh_s: float,
                 silent_s: float) -> None:
        self.me = me
        self.silent_s = silent_s
        #: last known position of every known peer [m; world ENU] (first its start position)
        self.others_pos: dict[str, Array] = {a: np.asarray(p, dtype=np.float64).copy()
                                             for a, p in start_positions.items() if a != me}
        #: latest state of each peer and the mission time it arrived [s]
        self.states: dict[str, tuple[AgentState, float]] = {}
        self.live: set[str] = set()  #: peers whose token is present and that speak
        self.tokens: set[str] = set()  #: peers whose liveliness token is present
        #: mission time [s] each peer last spoke (a state or pose) or its token appeared
        self.heard: dict[str, float] = {}
        #: each peer's freshest pose: position [m; world ENU], unit camera direction [world
        #: ENU], mission time heard [s]
        self.poses: dict[str, tuple[Array, Array, float]] = {}
        self.latest = LatestStates(fresh_s)
        self.ever_seen: set[str] = set()  #: peers seen alive at least once
        #: mission time [s] a peer last left while busy (None: never)
        self.last_departure: float | None = None
        self.unknown_live: set[str] = set()  #: tokens of drones not (yet) admitted

    # -- liveliness tokens -------------------------------------------------------------------
    def token_appeared(self, aid: str, known: bool, now: float) -> list[PeerEvent]:
        """A liveliness token of ``aid`` appeared at mission time ``now`` [s]; ``known``:
        ``aid`` is a scenario agent or an admitted joiner (else remembered until
        :meth:`admit`)."""
        if aid == self.me:
            return []
        if not known:
            self.unknown_live.add(aid)
            return []
        self.tokens.add(aid)
        self.heard[aid] = max(self.heard.get(aid, -np.inf), now)
        return [self._come(aid)]

    def token_vanished(self, aid: str, now: float) -> list[PeerEvent]:
        """The liveliness token of ``aid`` vanished at mission time ``now`` [s]."""
        if aid == self.me:
            return []
        self.tokens.discard(aid)
        self.unknown_live.discard(aid)
        return [self._gone(aid, now, None)]

    def admit(self, aid: str, p: Vec | None, now: float) -> list[PeerEvent]:
        """A joiner was admitted at mission time ``now`` [s] (``p``: its position [m; world
        ENU] if known): known from now on, live if its token is present."""
        if p is not None and aid not in self.others_pos:
            self.others_pos[aid] = np.asarray(p, dtype=np.float64)
        if aid not in self.unknown_live:
            return []
        self.unknown_live.discard(aid)
        self.tokens.add(aid)
        self.heard[aid] = max(self.heard.get(aid, -np.inf), now)
        return [self._come(aid)]

    # -- publications (already checked by the caller) -------------------------------------------
    def pose(self, aid: str, p: Vec, v: Vec, now: float) -> list[PeerEvent]:
        """A valid pose of ``aid`` (position [m; world ENU], unit direction) heard at mission
        time ``now`` [s]."""
        if aid in self.others_pos:
            self.others_pos[aid] = np.asarray(p, dtype=np.float64)
        return self._spoke(aid, p, v, now)

    def state(self, msg: AgentState, now: float) -> tuple[bool, list[PeerEvent]]:
        """A valid state heard at mission time ``now`` [s]: (whether it is now the peer's
        latest, events). An older, repeated or rival-stream state only shows the peer
        speaks."""
        aid = msg.sender
        if not self.latest.offer(aid, msg.incarnation, msg.seq, now):
            self.heard[aid] = now
            return False, []
        events = self._spoke(aid, msg.p, msg.v, now)
        self.states[aid] = (msg, now)
        # Liveliness is the authority on who is alive now, but a join event can be missed
        # (token declared while our watcher was being set up): a state proves it started.
        self.ever_seen.add(aid)
        self.others_pos[aid] = np.asarray(msg.p, dtype=np.float64)
        return True, events

    def sweep(self, now: float) -> list[PeerEvent]:
        """Peers whose token is present but that have not spoken for ``silent_s`` at mission
        time ``now`` [s]: gone (in id order)."""
        out: list[PeerEvent] = []
        for aid in sorted(self.live):
            silent = now - self.heard.get(aid, now)
            if silent > self.silent_s:
                out.append(self._gone(aid, now, silent))
        return out

    # -- views ---------------------------------------------------------------------------------
    def coverage_estimate(self, own_vision: float) -> float:
        """Eq. 3.10 as this agent knows it: its own vision plus the live peers' last ones."""
        return own_vision + sum(st.vision for aid, (st, _t) in self.states.items()
                                if aid in self.live)

    def others(self) -> Array:
        """The other agents' last known positions (k, 3) [m; world ENU]."""
        return np.array(list(self.others_pos.values()), dtype=np.float64).reshape(-1, 3)

    # -- transitions ---------------------------------------------------------------------------
    def _come(self, aid: str, again: bool = False) -> Came:
        self.live.add(aid)
        self.ever_seen.add(aid)
        return Came(aid, again)

    def _spoke(self, aid: str, p: Vec, v: Vec, now: float) -> list[PeerEvent]:
        self.heard[aid] = now
        self.poses[aid] = (np.asarray(p, dtype=np.float64), np.asarray(v, dtype=np.float64),
                           now)
        if aid in self.tokens and aid not in self.live:
            return [self._come(aid, again=True)]
        return []

    def _gone(self, aid: str, now: float, silent: float | None) -> Gone:
        self.live.discard(aid)
        last = self.states.get(aid)
        busy = last is None or not quiet_state(last[0])
        if busy:
            self.last_departure = now
        return Gone(aid, busy, silent)
