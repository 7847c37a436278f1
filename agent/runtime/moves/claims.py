"""An inspection drone's judge of its peers' capture claims, and its own claims and camera
shots (captures as evidence: :mod:`agent.protocol.captures`).

:class:`ClaimJudge` keeps each peer's published trajectory (its ``pose`` publications and
states, on the peer's own mission clock, the clock its claims are stamped with) and the ground
station's mocap of it (flown drones; on the shared simulation clock), and judges every claim a
peer's state carries: merged only when no landmark of it is uncapturable, the claimed camera
pose lies on the peer's published trajectory around the claimed time (and on its mocap where
there is some), and the inspection's own capture test (``imaged``: quality, field of view,
incidence, line of sight, vectorised over the claim's landmarks) holds for every landmark from
that pose. A refused claim is counted by reason and logged (one line per peer per
:data:`LOG_EVERY_S`), never merged and never judged again; a claim no published pose is heard
around (it captured before this drone listened) is judged on the pose only if it is the
claimer's start pose in the scenario, else on another drone's word (merged when a drone other
than the claimer names its landmarks captured: it judged the claim itself), else on physics
(the pose within reach, at the planner's speed, of the claimer's start and of the first pose
heard of it after the claim: then the capture test alone judges it), else left undecided (not
merged, not counted). A state of a build without claims names its captures
without evidence: refused, counted once per landmark.

:class:`Shots` holds the images asked of a confirming camera (a flown drone's, events
``Trigger`` then ``ImageTaken``): their landmarks count as captured only at the camera's word.
Positions [m; world ENU], times [s] of the mission clock named.
"""

from __future__ import annotations

import logging
import math
from collections import Counter
from collections.abc import Callable, Iterable
from dataclasses import dataclass

import msgspec
import numpy as np
from numpy.typing import NDArray

from agent.config.scenario import AgentSpec
from agent.protocol.captures import (
    MALFORMED,
    NO_EVIDENCE,
    NOT_CAPTURED,
    POSE,
    UNCAPTURABLE,
    Decided,
    Tracks,
    claim_ids,
    finite_pose,
    pose_agrees,
)
from agent.runtime.core.shared import AgentConfig
from agent.wire import keys
from agent.wire.ground import MocapPose
from agent.wire.peer import AgentState, CaptureClaim, Pose, unpack_bits

Array = NDArray[np.float64]
Mask = NDArray[np.bool_]
_log = logging.getLogger(f"viscover.{__name__}")

#: How much faster than the planner's ṗ_lim a claimer may have moved between two poses heard
#: of it (a flown vehicle overshoots its set-points).
SPEED_MARGIN = 2.0

#: One log line per peer at most this often [s mission].
LOG_EVERY_S = 5.0
#: Mocap samples kept per drone at most this often [s sim] (the stream runs at ≥ 100 Hz).
MOCAP_EVERY_S = 0.05

_POSE = msgspec.msgpack.Decoder(Pose)
_MOCAP = msgspec.msgpack.Decoder(MocapPose)


@dataclass(frozen=True)
class Tolerances:
    """How far a claimed pose may be from the claimer's published trajectory: ``tol_m`` [m],
    ``tol_rad`` [rad] of camera direction, over the poses published within ``window_s`` [s]
    of the claimed time (the same tolerances as an offer's pose check)."""

    tol_m: float = 0.5
    tol_rad: float = 0.35
    window_s: float = 2.0

    @staticmethod
    def of(cfg: AgentConfig | None) -> Tolerances:
        """An agent's: its offer tolerances, over ``fresh_periods`` state periods."""
        if cfg is None:
            return Tolerances()
        return Tolerances(cfg.pose_tolerance_m, cfg.pose_tolerance_rad,
                          cfg.fresh_periods * cfg.state_period_s)


class ClaimJudge:
    """Judges the peers' capture claims (see the module docstring).

    Args:
        agent_id: this drone (for log lines).
        ids: the mission's landmark ids (m,), in the scenario's row order.
        capturable: per row (m,): the capture table says some viewpoint captures it.
        imaged: the inspection's capture test: ``imaged(p, v, rows)`` -> the indices into
            ``rows`` a capture from p [m; world ENU], unit v takes.
        tol: the pose tolerances.
        agents: the scenario's drones (their start poses).
    """

    def __init__(self, agent_id: str, ids: NDArray[np.int64], capturable: Mask,
                 imaged: Callable[[Array, Array, NDArray[np.intp]], NDArray[np.intp]],
                 tol: Tolerances, agents: Iterable[AgentSpec] = (),
                 speed: float = float("inf"), turn: float = float("inf")) -> None:
        self.id, self.ids, self.capturable, self.imaged, self.tol = \
            agent_id, ids, capturable, imaged, tol
        #: the largest speed [m/s] a claimer's pose may have moved at (planner ṗ_lim, with
        #: :data:`SPEED_MARGIN` for a flown vehicle's overshoot)
        self.speed = SPEED_MARGIN * speed
        #: the largest turn rate [rad/s] of its camera (planner ω_lim, the same margin)
        self.turn = SPEED_MARGIN * turn
        self._order = np.argsort(ids, kind="stable")
        self._sorted = ids[self._order]
        self.tracks = Tracks()  #: published poses, on each claimer's clock
        self.mocap = Tracks()  #: the ground station's mocap, on the simulation clock
        self._mocap_rx: dict[str, float] = {}
        self.decided = Decided()
        self.refused: Counter[str] = Counter()  #: refused claims by reason
        self.accepted = 0  #: claims merged
        #: per peer, the landmarks its evidence-less captured sets were refused for
        self._unproven: dict[str, Mask] = {}
        #: each peer's latest captured set (a peer of this build: its own and those it judged)
        self.views: dict[str, Mask] = {}
        #: each scenario drone's start pose: position [m; world ENU], unit camera direction
        self.starts = {a.id: np.r_[a.p0, a.v0].astype(np.float64) for a in agents}
        self._logged: dict[str, float] = {}

    @property
    def refused_total(self) -> int:
        """Claims refused, every reason."""
        return sum(self.refused.values())

    # -- evidence in ----------------------------------------------------------------------
    def heard_pose(self, key: str, payload: bytes) -> None:
        """A peer's pose publication (already counted by the membership if bad): one sample
        of its trajectory at its own time."""
        try:
            msg = _POSE.decode(payload)
        except (msgspec.DecodeError, msgspec.ValidationError):
            return
        p, v = np.asarray(msg.p, dtype=np.float64), np.asarray(msg.v, dtype=np.float64)
        if keys.try_agent_of(key) != msg.sender or msg.sender == self.id \
                or not (np.isfinite(msg.t) and np.isfinite(p).all() and np.isfinite(v).all()):
            return
        self.tracks.add(msg.sender, msg.t, p, v)

    def heard_mocap(self, key: str, payload: bytes, now: float) -> None:
        """The ground station's mocap of a drone, heard at ``now`` [s]; decoded at most once
        per :data:`MOCAP_EVERY_S`."""
        aid = key.rsplit("/", 1)[-1]
        if now - self._mocap_rx.get(aid, -np.inf) < MOCAP_EVERY_S or \
                (aid not in self._mocap_rx and len(self._mocap_rx) >= 1024):
            return
        self._mocap_rx[aid] = now
        try:
            msg = _MOCAP.decode(payload)
        except (msgspec.DecodeError, msgspec.ValidationError):
            return
        if msg.drone != aid or len(msg.p) != 3 or not np.isfinite(msg.p).all() \
                or not np.isfinite(msg.t):
            return
        self.mocap.add(aid, msg.t, np.asarray(msg.p, dtype=np.float64))

    # -- judging --------------------------------------------------------------------------
    def judge(self, st: AgentState, cap: Mask, now: float) -> Mask:
        """The landmarks (m,) a peer's state proves captured that ``cap`` does not hold yet
        (its claims accepted), heard at ``now`` [s]; refused ones counted."""
        aid = st.sender
        self.tracks.add(aid, st.t, np.asarray(st.p), np.asarray(st.v))
        new = np.zeros(self.ids.size, dtype=np.bool_)
        view = unpack_bits(st.captured, self.ids.size) if st.captured else None
        if st.claims is not None and view is not None:  # its view, to vouch for claims
            self.views[aid] = view
        if st.claims is None:  # a build without evidence: its word only
            if view is not None:
                seen = self._unproven.setdefault(aid, np.zeros(self.ids.size, np.bool_))
                fresh = view & ~cap & ~seen
                if fresh.any():
                    seen |= fresh
                    self._refuse(aid, NO_EVIDENCE, int(fresh.sum()),
                                 f"{int(fresh.sum())} landmarks named captured without "
                                 "evidence", now)
            return new
        for c in st.claims:  # at most MAX_CAPTURE_CLAIMS per state
            if self.decided.get(aid, c) is not None:
                continue
            rows = self._rows(c)
            verdict = self._verdict(aid, c, rows)
            if verdict == "":
                continue  # no pose of it heard near that time: not judged yet
            self.decided.put(aid, c, verdict is None)
            if verdict is None:
                assert rows is not None
                self.accepted += 1
                new[rows] = True
            else:
                self._refuse(aid, verdict[0], 1, verdict[1], now)
        return new & ~cap

    def _rows(self, c: CaptureClaim) -> NDArray[np.intp] | None:
        """The scenario rows of a claim's landmarks, or None (malformed, unknown ids)."""
        ids = claim_ids(c) if finite_pose(c) else None
        if ids is None:
            return None
        k = np.searchsorted(self._sorted, ids)
        k = np.minimum(k, self._sorted.size - 1)
        if self._sorted.size == 0 or not (self._sorted[k] == ids).all():
            return None
        return np.asarray(self._order[k], dtype=np.intp)

    def _verdict(self, aid: str, c: CaptureClaim, rows: NDArray[np.intp] | None
                 ) -> tuple[str, str] | str | None:
        """None: accepted; "": undecided (no pose of ``aid`` heard around the claimed time,
        and no other drone vouches for it); else (reason, one line)."""
        if rows is None:
            return MALFORMED, "a malformed claim (ids, version or pose)"
        bad = ~self.capturable[rows]
        if bad.any():
            return UNCAPTURABLE, \
                f"claims uncapturable landmarks {self.ids[rows[bad]][:5].tolist()}"
        tol = self.tol
        p, v = np.asarray(c.p, dtype=np.float64), np.asarray(c.v, dtype=np.float64)
        track = self.tracks.around(aid, c.t, tol.window_s)
        seen = self.mocap.around(aid, c.t, tol.window_s)
        if track is None and seen is None and not self._at_start(aid, p, v) \
                and not self._vouched(aid, rows) and not self._reachable(aid, c.t, p):
            return ""
        track = np.zeros((0, 6)) if track is None else track
        seen = np.zeros((0, 6)) if seen is None else seen
        if (track.shape[0] and not pose_agrees(track, p, v, tol.tol_m, tol.tol_rad)
                and not self._between(aid, c.t, p, v)) or \
                (seen.shape[0] and not pose_agrees(seen, p, None, tol.tol_m, tol.tol_rad)):
            near = np.vstack([track[:, :3], seen[:, :3]])
            with np.errstate(over="ignore", invalid="ignore"):
                off = float(np.linalg.norm(near - p[None, :], axis=1).min())
            return POSE, (f"claims a capture at t = {c.t:.2f} s from a pose {off:.2f} m from the "
                          f"nearest of the {near.shape[0]} it published (or mocap saw) then")
        good = self.imaged(p, v, rows)
        if good.size != rows.size:
            return NOT_CAPTURED, (f"claims {rows.size - good.size} landmarks the capture test "
                                  f"fails for from its pose at t = {c.t:.2f} s")
        return None

    def _at_start(self, aid: str, p: Array, v: Array) -> bool:
        """Whether (p, v) is ``aid``'s start pose in the scenario (where every drone captures
        first, often before its peers listen)."""
        start = self.starts.get(aid)
        return start is not None and pose_agrees(start[None, :], p, v, self.tol.tol_m,
                                                 self.tol.tol_rad)

    def _reachable(self, aid: str, t: float, p: Array) -> bool:
        """Whether a claim at ``t`` [s] from p [m; world ENU] of a drone no pose of which was
        heard around ``t`` (it captured before this drone listened, or those samples were
        lost) is physically possible: p within reach of ``aid``'s start pose since the
        mission began and of the first pose heard after ``t``, at :attr:`speed`. Then the
        capture test alone judges it; else it stays undecided."""
        after = self.tracks.first_after(aid, t)
        start = self.starts.get(aid)
        if after is None or start is None or not np.isfinite(self.speed):
            return False
        t_after, p_after = after
        tol = self.tol.tol_m
        return bool(np.linalg.norm(p - p_after) <= tol + self.speed * (t_after - t)
                    and np.linalg.norm(p - start[:3]) <= tol + self.speed * max(t, 0.0))

    def _between(self, aid: str, t: float, p: Array, v: Array) -> bool:
        """Whether (p [m; world ENU], unit v) at ``t`` [s] is possible between the two
        samples of ``aid`` that bracket ``t``: p within reach of both at :attr:`speed`, v
        within a turn of both camera directions at :attr:`turn` (each with the tolerances).
        A drone heard only through its states (not a neighbour,
        :mod:`agent.runtime.ends.pose_interest`) or over a lossy link has samples too far
        apart for the polyline to follow its turns."""
        got = self.tracks.bracket(aid, t)
        if got is None or not (np.isfinite(self.speed) and np.isfinite(self.turn)):
            return False
        t0, r0, t1, r1 = got
        tol = self.tol
        if not (np.linalg.norm(p - r0[:3]) <= tol.tol_m + self.speed * (t - t0)
                and np.linalg.norm(p - r1[:3]) <= tol.tol_m + self.speed * (t1 - t)):
            return False
        d0, d1 = r0[3:], r1[3:]
        for d, dt in ((d0, t - t0), (d1, t1 - t)):  # v within a turn of each, at ω_lim
            if np.isfinite(d).all() and math.acos(max(-1.0, min(1.0, float(np.dot(v, d))))) \
                    > tol.tol_rad + self.turn * dt:
                return False
        return True

    def _vouched(self, aid: str, rows: NDArray[np.intp]) -> bool:
        """Whether a drone other than ``aid`` (and this one) names every landmark of ``rows``
        captured in its latest state: it judged that claim (or captured them) itself."""
        return any(who != aid and view[rows].all() for who, view in self.views.items())

    def _refuse(self, aid: str, reason: str, n: int, line: str, now: float) -> None:
        """Count ``n`` refusals for ``reason`` and say so (one line per peer per
        :data:`LOG_EVERY_S` of mission time ``now`` [s])."""
        self.refused[reason] += n
        if now - self._logged.get(aid, -np.inf) >= LOG_EVERY_S:
            self._logged[aid] = now
            _log.warning("agent %s: refused a capture claim of %s (%s): %s", self.id,
                         aid[:32], reason, line[:120])
