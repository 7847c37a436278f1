"""The captured set of an inspection: a grow-only set of landmark ids merged by union, and the
evidence a capture is believed on.

Every drone keeps its own copy and merges the captures its peers *prove*. Union is
idempotent, commutative and associative, so copies that have heard the same captures agree
whatever the order, duplication or loss of the messages in between, and a landmark once
captured is never un-captured (a state-based grow-only set). The caller journals what
:meth:`CapturedSet.merge` reports as new before it publishes it.

Captures as evidence. A drone publishes, with its state, claims of its own captures
(:class:`~agent.wire.peer.CaptureClaim`: the camera pose and time of one image and the
landmarks it captured; the newest :data:`NEWEST` and :data:`OLDER` older ones in turn,
:class:`OwnClaims`, so every claim is sent again and again while the state stays bounded). A
receiver merges a claim's landmarks only when

1. the claimed pose lies on the trajectory the claimer published around the claimed time
   (:class:`Tracks`, :func:`pose_agrees`: within ``tol_m`` of the polyline of its published
   poses that bracket it, each within ``window`` [s] of it, camera direction within
   ``tol_rad``), and on the ground station's mocap of it where there is some (position only);
2. no landmark of it is uncapturable (the capture table) and the inspection's own capture
   test holds for every one from that pose (the caller's, vectorised over the claim's rows).

A claim failing either is refused: counted by reason (:data:`REFUSALS`), never merged, and
decided once (:class:`Decided`: the same claim sent again is not judged again). A claim whose
time this drone heard no published pose of the claimer around (it captured before this drone
listened, a restart) cannot be judged on the pose: it is merged only when another drone than
its claimer already names its landmarks captured (it judged the claim itself), else neither
merged nor refused (the landmarks stay to capture for whoever owns them).
A state from a build without claims (``claims`` None) names its captures without evidence:
refused (``no_evidence``), counted once per landmark. Observers and ``viscover status`` count
a landmark captured when a strict majority of the drones' published captured sets name it
(:func:`agreed_bits`): one drone's word is not enough there either.
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Iterable
from typing import Final

import numpy as np
from numpy.typing import NDArray

from agent.wire.peer import (
    CLAIM_VERSION,
    MAX_CLAIM_IDS,
    CaptureClaim,
    unpack_bits,
)

Array = NDArray[np.float64]

#: Claims an agent's state carries: its newest ones, and older ones in turn.
NEWEST: Final = 8
OLDER: Final = 8
#: Why a peer's capture claim is refused.
NO_EVIDENCE: Final = "no_evidence"  #: a state naming captures without claims (older build)
MALFORMED: Final = "malformed"  #: ids not a packed set of the mission's landmarks, version
POSE: Final = "pose_mismatch"  #: not where the claimer published (or mocap saw) itself
NOT_CAPTURED: Final = "not_captured"  #: the capture test fails from the claimed pose
UNCAPTURABLE: Final = "uncapturable"  #: the capture table says no viewpoint captures it
REFUSALS: Final = (NO_EVIDENCE, MALFORMED, POSE, NOT_CAPTURED, UNCAPTURABLE)
#: Published poses kept per peer (a ring: minutes of flight at a tick of 0.1 s), and the
#: most of them a claim is compared with on each side of its time.
TRACK_LEN: Final = 4096
BRACKET: Final = 16
_ID = np.dtype("<i8")


class CapturedSet:
    """Landmark ids captured so far (grow-only)."""

    def __init__(self, ids: Iterable[int] = ()) -> None:
        self._ids: set[int] = {int(i) for i in ids}

    def merge(self, ids: Iterable[int]) -> list[int]:
        """Union with ``ids``; returns the ids that were not in the set before, sorted."""
        new = {int(i) for i in ids} - self._ids
        self._ids |= new
        return sorted(new)

    def __contains__(self, lid: object) -> bool:
        return lid in self._ids

    def __len__(self) -> int:
        return len(self._ids)

    def ids(self) -> list[int]:
        """The captured ids, sorted."""
        return sorted(self._ids)

    def mask(self, landmark_ids: NDArray[np.int64]) -> NDArray[np.bool_]:
        """Per landmark row (ids ``landmark_ids`` (m,)): captured or not."""
        if not self._ids:
            return np.zeros(landmark_ids.shape, dtype=np.bool_)
        return np.isin(landmark_ids, np.fromiter(self._ids, dtype=np.int64, count=len(self)))


def agreed_bits(sets: Iterable[bytes], m: int) -> NDArray[np.bool_]:
    """The landmarks (m,) a strict majority of the published captured sets (bit sets of m
    landmarks, one per drone; a malformed one counts as naming nothing) name: what observers
    count captured, so that no one drone's word makes a landmark captured."""
    votes = np.zeros(m, dtype=np.int64)
    n = 0
    for bits in sets:  # one set per drone
        n += 1
        mask = unpack_bits(bits, m) if bits else None
        if mask is not None:
            votes += mask
    return votes * 2 > n


def captured_count(sets: Iterable[bytes], m: int) -> int:
    """How many of m landmarks a strict majority of the published captured sets name
    (:func:`agreed_bits`)."""
    return int(agreed_bits(sets, m).sum())


# -- captures as evidence -----------------------------------------------------------------


def split_claims(t: float, p: Array, v: Array, ids: Iterable[int]) -> list[CaptureClaim]:
    """One image's claim(s): at mission time ``t`` [s] from ``p`` [m; world ENU], unit ``v``,
    landmark ``ids`` (split in chunks of :data:`MAX_CLAIM_IDS`)."""
    arr = np.asarray(list(ids), dtype=np.int64)
    pp = (float(p[0]), float(p[1]), float(p[2]))
    vv = (float(v[0]), float(v[1]), float(v[2]))
    return [CaptureClaim(CLAIM_VERSION, float(t), pp, vv,
                         arr[k:k + MAX_CLAIM_IDS].astype(_ID).tobytes())
            for k in range(0, arr.size, MAX_CLAIM_IDS)]


def claim_ids(claim: CaptureClaim) -> NDArray[np.int64] | None:
    """The landmark ids of a claim (int64), or None if it is not a packed, non-empty set of
    unique ids of a version this build reads."""
    if claim.version != CLAIM_VERSION or not claim.ids or len(claim.ids) % 8:
        return None
    ids = np.frombuffer(claim.ids, dtype=_ID).astype(np.int64)
    if np.unique(ids).size != ids.size:
        return None
    return ids


def finite_pose(c: CaptureClaim) -> bool:
    """Whether a claim's time and pose are finite and its direction (nearly) unit."""
    if not all(math.isfinite(x) for x in (c.t, *c.p, *c.v)):
        return False
    n = math.sqrt(c.v[0] ** 2 + c.v[1] ** 2 + c.v[2] ** 2)
    return 0.9 < n < 1.1


class OwnClaims:
    """This drone's own capture claims, in order, and the bounded window of them each state
    carries: the :data:`NEWEST` newest and :data:`OLDER` of the older ones in turn (so a peer
    that missed one hears it again later)."""

    def __init__(self) -> None:
        self.claims: list[CaptureClaim] = []
        self._turn = 0

    def add(self, t: float, p: Array, v: Array, ids: Iterable[int]) -> None:
        """A confirmed capture (see :func:`split_claims`)."""
        self.claims += split_claims(t, p, v, ids)

    def window(self) -> list[CaptureClaim]:
        """The claims the next state carries (advances the turn of the older ones)."""
        old, out = self.claims[:-NEWEST], self.claims[-NEWEST:]
        if old:
            k = self._turn % len(old)
            self._turn = k + OLDER
            out = (old[k:k + OLDER] + old[:max(0, k + OLDER - len(old))])[:OLDER] + out
        return out


class Tracks:
    """The poses each peer published (or the ground station's mocap saw of it), as heard: per
    peer a ring of :data:`TRACK_LEN` samples (mission time heard [s], position [m; world
    ENU], unit camera direction, NaN for a mocap sample)."""

    def __init__(self) -> None:
        self._t: dict[str, Array] = {}
        self._pv: dict[str, Array] = {}
        self._n: dict[str, int] = {}

    def add(self, aid: str, t: float, p: Array, v: Array | None = None,
            min_dt: float = 0.0) -> None:
        """A sample of ``aid`` heard at ``t`` [s]; skipped when the last one is less than
        ``min_dt`` [s] older (a mocap stream at 100 Hz). At most 1,024 peers."""
        if aid not in self._t:
            if len(self._t) >= 1024:
                return
            self._t[aid] = np.full(TRACK_LEN, -np.inf)
            self._pv[aid] = np.full((TRACK_LEN, 6), np.nan)
            self._n[aid] = 0
        n, ts = self._n[aid], self._t[aid]
        if n and t - ts[(n - 1) % TRACK_LEN] <= min_dt and t >= ts[(n - 1) % TRACK_LEN]:
            return  # too soon after the last one (or the same publication again)
        ts[n % TRACK_LEN] = t
        row = self._pv[aid][n % TRACK_LEN]
        row[:3] = p
        row[3:] = np.nan if v is None else v
        self._n[aid] = n + 1

    def first_after(self, aid: str, t: float) -> tuple[float, Array] | None:
        """The first sample of ``aid`` at or after time ``t`` [s]: (its time, position [m]),
        or None."""
        if aid not in self._t:
            return None
        ts = self._t[aid]
        later = np.flatnonzero(ts >= t)
        if later.size == 0:
            return None
        k = int(later[np.argmin(ts[later])])
        return float(ts[k]), self._pv[aid][k, :3]

    def bracket(self, aid: str, t: float) -> tuple[float, Array, float, Array] | None:
        """The last sample of ``aid`` at or before ``t`` [s] and the first at or after it:
        (time, row of position [m] and direction) of each, or None without one on each
        side."""
        if aid not in self._t:
            return None
        ts = self._t[aid]
        before, after = np.flatnonzero(ts <= t), np.flatnonzero(ts >= t)
        if before.size == 0 or after.size == 0:
            return None
        i = int(before[np.argmax(ts[before])])
        j = int(after[np.argmin(ts[after])])
        return float(ts[i]), self._pv[aid][i], float(ts[j]), self._pv[aid][j]

    def around(self, aid: str, t: float, window: float) -> Array | None:
        """The samples of ``aid`` that bracket time ``t`` [s] (the last one at or before it,
        the first at or after it, and one more on each side), in time order: rows (k, 6) of
        position [m] and direction; None when no sample within ``window`` [s] lies on one
        side of t (not heard then: it captured before this drone listened, or it was
        silent)."""
        if aid not in self._t:
            return None
        n = self._n[aid]
        order = np.arange(max(0, n - TRACK_LEN), n) % TRACK_LEN
        ts = self._t[aid][order]
        by_time = np.argsort(ts, kind="stable")
        ts, order = ts[by_time], order[by_time]
        i = int(np.searchsorted(ts, t, side="right")) - 1  # last at or before t
        j = int(np.searchsorted(ts, t, side="left"))  # first at or after t
        if i < 0 or j >= ts.size or t - ts[i] > window or ts[j] - t > window:
            return None
        lo, hi = max(0, min(i, j) - 1), max(i, j) + 2  # j ≤ i: samples at exactly t
        pick = np.arange(lo, min(hi, ts.size))
        if pick.size > 2 * BRACKET:  # many at one time (only a forger's track): its ends
            pick = np.r_[pick[:BRACKET], pick[-BRACKET:]]
        return self._pv[aid][order[pick]]


def pose_agrees(rows: Array, p: Array, v: Array | None, tol_m: float, tol_rad: float
                ) -> bool:
    """Whether the pose (p [m; world ENU], unit v; None: position only) lies on the polyline
    of the track ``rows`` (k ≥ 1, oldest first: position, direction (NaN: unknown)): within
    ``tol_m`` of one of its segments and, where directions are known, with the direction
    interpolated at the closest point within ``tol_rad`` [rad] of v."""
    pos, dirs = rows[:, :3], rows[:, 3:]
    one = pos.shape[0] == 1
    a, da = (pos, dirs) if one else (pos[:-1], dirs[:-1])
    ab, dd = (pos - pos, dirs - dirs) if one else (pos[1:] - a, dirs[1:] - da)
    den = np.einsum("ij,ij->i", ab, ab)
    with np.errstate(over="ignore", invalid="ignore"):  # a huge finite claim: refused
        s = np.clip(np.einsum("ij,ij->i", p[None, :] - a, ab) / np.where(den > 0, den, 1.0),
                    0.0, 1.0)
        d = np.linalg.norm(a + s[:, None] * ab - p[None, :], axis=1)
    close = d <= tol_m
    if v is None or not close.any():
        return bool(close.any())
    w = (da + s[:, None] * dd)[close]
    known = np.isfinite(w).all(axis=1)
    if not known.any():
        return True  # only mocap samples near: the position agrees
    w = w[known]
    cos = (w @ v) / np.maximum(1e-12, np.linalg.norm(w, axis=1) * float(np.linalg.norm(v)))
    return bool((np.arccos(np.clip(cos, -1.0, 1.0)) <= tol_rad).any())


class Decided:
    """The claims already judged, by (claimer, claim), so that a claim sent again is neither
    judged nor counted again; at most ``cap`` remembered (the oldest forgotten first)."""

    def __init__(self, cap: int = 1 << 16) -> None:
        self.cap = cap
        self._seen: dict[tuple[str, bytes], bool] = {}

    @staticmethod
    def key(aid: str, c: CaptureClaim) -> tuple[str, bytes]:
        """A claim's identity: claimer, time, pose and landmarks (a digest of them)."""
        return aid, np.asarray((c.t, *c.p, *c.v), dtype=np.float64).tobytes() + \
            hashlib.blake2b(c.ids, digest_size=16).digest()

    def get(self, aid: str, c: CaptureClaim) -> bool | None:
        """Accepted (True), refused (False) or not judged yet (None)."""
        return self._seen.get(self.key(aid, c))

    def put(self, aid: str, c: CaptureClaim, accepted: bool) -> None:
        """Remember the verdict on claim ``c`` of ``aid``."""
        if len(self._seen) >= self.cap:
            del self._seen[next(iter(self._seen))]
        self._seen[self.key(aid, c)] = accepted
