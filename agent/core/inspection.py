"""Inspection captures: when a camera pose images a landmark well enough (beyond the thesis).

(Over 400 lines, not split further: the capture test of eq. 3.1, the ball that bounds it,
the probe poses and the table they fill change together.)

An inspection mission asks every landmark to be *captured* once: imaged by some camera at a
per-landmark vision of at least ``quality`` (eq. 3.1: f(r)·cos α·cos β, 1 head-on at d_opt),
inside the camera's field of view and, optionally, at an incidence β no larger than
``max_incidence``; with several views per landmark (``views``), from inside the landmark's
view sector (:mod:`agent.core.views`). Line of sight (the occlusion model) is a mask the
caller computes with the structure's ray caster; this module is pure numpy and never casts a
ray.

Frames: every vector in the world frame (ENU), positions [m]. A camera (p, v) has no roll: its
image rows are horizontal (``right`` = v × ẑ, normalised; ``up`` = right × v), so a field of
view ``fov = (h, w)`` [rad] bounds the horizontal and vertical angles of q − p off the axis v.

Also here: the poses from which a landmark may be captured at all (:func:`probe_poses`,
used to tell capturable landmarks from uncapturable ones before take-off), the candidate
viewpoints of an inspection (:func:`inspection_candidates`), the ball around a camera that
holds all it can capture (:func:`capture_lobe`), and the capture table (:class:`CaptureTable`,
its captures kept by rows: :class:`CaptureRows`).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from agent.core.camera import Camera
from agent.core.capture_rows import CaptureRows
from agent.core.viewpoints import seed_viewpoints
from agent.core.views import MAX_VIEWS
from agent.core.vision import ExpDistance

Array = NDArray[np.float64]
Mask = NDArray[np.bool_]

#: Pairs (camera, landmark) evaluated per block by :func:`capture_quality` (bounds memory).
BLOCK = 1 << 20
#: Tilts of the probe poses off the landmark's normal [rad], and their azimuths.
PROBE_TILTS = np.radians([0.0, 25.0, 45.0, 65.0])
PROBE_AZIMUTHS = 8
#: With view sectors, the probe poses' largest tilt off the sector's axis [of its cone].
CONE_FILL = 0.9
#: At most this many landmarks seed the neighbourhood viewpoints (evenly spaced rows), up to
#: MAX_SEEDS · LANDMARKS_PER_SEED landmarks; past that, one seed per LANDMARKS_PER_SEED.
MAX_SEEDS = 400
LANDMARKS_PER_SEED = 25
#: Distances of the probe poses and the group viewpoints from the surface [in d_opt].
PROBE_DISTANCES = (1.0, 0.6, 1.6)
GROUP_DISTANCES = (1.0, 1.6, 2.4)


@dataclass(frozen=True)
class CaptureSpec:
    """What counts as a capture: least per-landmark vision ``quality`` of eq. 3.1, optional
    full field of view ``fov`` = (horizontal, vertical) [rad] and largest incidence
    ``max_incidence`` [rad] between the landmark's normal and the line to the camera; with a
    ``camera`` (:class:`~agent.core.camera.Camera`), optionally the largest ground sampling
    distance ``gsd`` [m/px] (:func:`~agent.core.camera.ground_sampling_distance`).

    A capture must meet the spec tightened by the margin ``aim`` (a fraction): vision ≥
    :attr:`threshold` = quality·(1 + aim) (at most 1) and GSD ≤ :attr:`gsd_aim` =
    (1 − aim)·gsd, so that a re-flight of the same viewpoints with position noise still
    meets the spec itself.

    With ``views`` = k > 1 each landmark is to be captured in k images whose viewing
    directions differ pairwise by at least ``parallax`` [rad]: the scenario's landmarks are
    then view landmarks, each captured only from its view sector (:mod:`agent.core.views`,
    the ``axis`` and ``cos_cone`` of :func:`capture_quality`)."""

    quality: float = 0.3
    fov: tuple[float, float] | None = None
    max_incidence: float | None = None
    camera: Camera | None = None
    gsd: float | None = None
    aim: float = 0.0
    views: int = 1
    parallax: float = math.radians(20.0)

    def __post_init__(self) -> None:
        if not 0.0 < self.quality <= 1.0:
            raise ValueError(f"quality must lie in (0, 1], got {self.quality}")
        if not 0.0 <= self.aim < 1.0:
            raise ValueError(f"aim must lie in [0, 1), got {self.aim}")
        if self.gsd is not None and (self.camera is None or not self.gsd > 0.0):
            raise ValueError("a gsd limit needs a camera and a positive gsd [m/px]")
        if not 1 <= self.views <= MAX_VIEWS or not 0.0 < self.parallax < math.pi / 2:
            raise ValueError(f"views must lie in 1..{MAX_VIEWS} and parallax in (0, pi/2), "
                             f"got {self.views}, {self.parallax}")

    def describe(self) -> str:
        """The spec in words: ``quality >= 0.3`` (with a margin: ``(aimed 0.33)``), or with a
        GSD limit ``GSD <= 2 mm/px (aimed 1.8), incidence <= 60 deg``; with several views
        ``, 3 views >= 20 deg apart`` after it."""
        if self.gsd is None or self.gsd_aim is None:
            text = f"quality >= {self.quality:g}"
            if self.aim != 0.0:
                text += f" (aimed {self.threshold:.3g})"
        else:
            text = f"GSD <= {self.gsd * 1000:.3g} mm/px (aimed {self.gsd_aim * 1000:.3g})"
            if self.max_incidence is not None:
                text += f", incidence <= {np.degrees(self.max_incidence):.3g} deg"
        if self.views > 1:
            text += f", {self.views} views >= {np.degrees(self.parallax):.3g} deg apart"
        return text

    @property
    def threshold(self) -> float:
        """The least eq. 3.1 vision a capture needs: quality·(1 + aim), at most 1."""
        return min(1.0, self.quality * (1.0 + self.aim))

    @property
    def gsd_aim(self) -> float | None:
        """The largest GSD [m/px] a capture may have: (1 − aim)·gsd (None: no limit)."""
        return None if self.gsd is None else (1.0 - self.aim) * self.gsd

    def _gsd_ok(self, r: Array, pu: Array) -> Mask | None:
        """GSD r²·(s/f)/⟨p − q, u⟩ ≤ gsd_aim for ranges r and ⟨p − q, u⟩ = r·cos β (same
        shapes, pu > 0); None without a GSD limit."""
        limit = self.gsd_aim
        if limit is None or self.camera is None:
            return None
        return np.asarray(r * r * self.camera.pixel_angle <= limit * pu * (1.0 + 1e-12),
                          dtype=np.bool_)


def camera_axes(V: Array) -> tuple[Array, Array]:
    """Image axes (right, up) (K, 3) of cameras looking along unit V (K, 3) with no roll:
    right = V × ẑ normalised (x̂ for a camera looking straight up or down), up = right × V."""
    right = np.cross(V, np.array([0.0, 0.0, 1.0]))
    n = np.linalg.norm(right, axis=1)
    flat = n < 1e-9
    right = np.where(flat[:, None], np.array([1.0, 0.0, 0.0]), right / np.where(flat, 1.0,
                                                                               n)[:, None])
    up = np.cross(right, V)
    return right, up


def _cone(axis: Array | None, cos_cone: float | None) -> float | None:
    """``cos_cone`` when a sector ``axis`` is given (it must then be), else None."""
    if axis is None:
        return None
    if cos_cone is None:
        raise ValueError("a view-sector axis needs its cos_cone")
    return cos_cone


def capture_quality(P: Array, V: Array, q: Array, u: Array, d_opt: float,
                    spec: CaptureSpec, axis: Array | None = None,
                    cos_cone: float | None = None) -> Array:
    """Eq. 3.1 per landmark for K cameras (P, V) (K, 3) over m landmarks (q, u) (m, 3)
    [m; world ENU], set to 0 outside the field of view, beyond the largest incidence or the
    aimed GSD, and, with view sectors (unit ``axis`` (m, 3) per landmark and ``cos_cone``,
    :mod:`agent.core.views`), when the direction from the landmark to the camera is outside
    its sector's cone; returns (K, m). Without ``fov`` and ``max_incidence`` this is the
    vision matrix of eq. 3.8."""
    K, m = P.shape[0], q.shape[0]
    out = np.zeros((K, m))
    if K == 0 or m == 0:
        return out
    cone = _cone(axis, cos_cone)
    term = ExpDistance(d_opt)
    right, up = camera_axes(V)
    half = None if spec.fov is None else np.tan(np.asarray(spec.fov) / 2.0)
    cos_inc = None if spec.max_incidence is None else np.cos(spec.max_incidence)
    rows = max(1, BLOCK // max(m, 1))
    for a in range(0, K, rows):  # blocks of cameras; landmarks vectorised
        b = min(K, a + rows)
        D = q[None, :, :] - P[a:b, None, :]  # (k, m, 3): q − p
        r = np.sqrt(np.einsum("kmi,kmi->km", D, D))
        dv = np.einsum("kmi,ki->km", D, V[a:b])
        pu = -np.einsum("kmi,mi->km", D, u)
        ok = (dv > 0.0) & (pu > 0.0) & (r > 0.0)
        if half is not None:
            ok &= np.abs(np.einsum("kmi,ki->km", D, right[a:b])) <= half[0] * dv
            ok &= np.abs(np.einsum("kmi,ki->km", D, up[a:b])) <= half[1] * dv
        if cos_inc is not None:
            ok &= pu >= cos_inc * r
        if axis is not None and cone is not None:  # ⟨(p − q)/r, a⟩ ≥ cos ρ
            ok &= -np.einsum("kmi,mi->km", D, axis) >= cone * r
        if (fine := spec._gsd_ok(r, np.maximum(pu, 1e-300))) is not None:
            ok &= fine
        block = np.zeros(r.shape)
        block[ok] = term.fbar(r[ok]) * dv[ok] * pu[ok]
        out[a:b] = block
    return out


def capture_range(d_opt: float, threshold: float, scale: float = 1.0) -> float:
    """The range r_max [m] beyond which no camera captures: eq. 3.1 is f̄(r)·⟨q − p, v⟩·
    ⟨p − q, u⟩ ≤ f̄(r)·r²·``scale`` = f(r)·scale (eq. 3.6; ``scale`` bounds ‖v‖·‖u‖), and
    f falls below ``threshold`` / scale for every r > r_max (the larger root, by bisection,
    rounded up)."""
    target = threshold / scale
    if target <= 0.0:
        return math.inf
    term = ExpDistance(d_opt)
    lo, hi = d_opt, 2.0 * d_opt  # f(d_opt) = 1 ≥ target; f decreases beyond d_opt
    while float(term.f(np.asarray(hi))) >= target:
        lo, hi = hi, 2.0 * hi
    for _ in range(100):
        mid = 0.5 * (lo + hi)
        if float(term.f(np.asarray(mid))) >= target:
            lo = mid
        else:
            hi = mid
    return hi * (1.0 + 1e-9)


def _reach(d_opt: float, spec: CaptureSpec, scale: float) -> float:
    """The range [m] beyond which nothing is captured: :func:`capture_range`, and with a GSD
    limit r ≤ gsd_aim·scale/pixel angle (r² s/f ≤ gsd_aim·⟨p − q, u⟩ ≤ gsd_aim·r·‖u‖)."""
    r_hi = capture_range(d_opt, spec.threshold, scale)
    if spec.gsd_aim is not None and spec.camera is not None:
        r_hi = min(r_hi, spec.gsd_aim * scale / spec.camera.pixel_angle * (1.0 + 1e-9))
    return r_hi


def _ball(d_opt: float, target: float, r_hi: float, cos_cap: float) -> tuple[float, float]:
    """(c, ρ): the ball centred c along an axis [m] of radius ρ [m] holding every point at
    range r ≤ ``r_hi`` and angle α off the axis with f(r)·cos α ≥ ``target`` (eq. 3.6) and
    cos α ≥ ``cos_cap``. For each r the farthest such point from the centre is at the
    largest α; c is chosen on a grid to make ρ small, ρ rounded up by the largest step of
    the sampled distance."""
    r = np.linspace(0.0, r_hi, 4097)
    with np.errstate(divide="ignore", invalid="ignore"):
        need = np.where(r > 0.0, target / ExpDistance(d_opt).f(np.maximum(r, 1e-300)), np.inf)
    cos_a = np.maximum(np.where(need <= 1.0, need, 1.0), min(cos_cap, 1.0))
    live = need <= 1.0 + 1e-12
    if not live.any():
        return 0.0, r_hi
    cs = np.linspace(0.0, r_hi, 513)
    g = r[None, :] ** 2 + cs[:, None] ** 2 - 2.0 * cs[:, None] * r[None, :] * cos_a[None, :]
    near = live | np.r_[live[1:], False] | np.r_[False, live[:-1]]  # and grid neighbours
    both = (near[1:] & near[:-1])[None, :]
    step = np.where(both, np.abs(np.diff(g, axis=1)), 0.0)
    rho2 = np.where(near[None, :], g, -np.inf).max(axis=1) + step.max(axis=1)
    best = int(np.argmin(rho2))
    return float(cs[best]), float(math.sqrt(max(rho2[best], 0.0))) * (1.0 + 1e-6) + 1e-9


def capture_lobe(d_opt: float, spec: CaptureSpec, scale: float = 1.0) -> tuple[float, float]:
    """A ball (centre c along the camera's unit axis v̂ [m], radius ρ [m]) holding every
    point q a camera at p captures: eq. 3.1 ≥ threshold needs f(r)·cos α ≥ threshold/scale
    (eq. 3.6, α off the axis, ``scale`` bounding ‖v‖·‖u‖), r ≤ :func:`capture_range` (and
    the GSD's range), and inside the field of view cos α ≥ cos α_fov."""
    cap = -1.0
    if spec.fov is not None:
        half = np.tan(np.asarray(spec.fov, dtype=np.float64) / 2.0)
        cap = 1.0 / math.sqrt(1.0 + float(half @ half))
    return _ball(d_opt, spec.threshold / scale, _reach(d_opt, spec, scale), cap)


def probe_poses(q: Array, u: Array, d_opt: float, spec: CaptureSpec,
                axis: Array | None = None, cos_cone: float | None = None
                ) -> tuple[Array, Array]:
    """Poses from which each landmark could be captured if nothing were in the way: cameras
    looking straight at it from directions tilted off its normal (up to ``max_incidence``)
    at distances around d_opt; with view sectors (``axis`` (m, 3), ``cos_cone``), tilted
    off its sector's axis instead, within :data:`CONE_FILL` of the cone's half-angle.
    Returns P, V (m, S, 3) [m; world ENU], S poses per landmark."""
    m = q.shape[0]
    cone = _cone(axis, cos_cone)
    if axis is not None and cone is not None:
        centre = axis
        tilts = PROBE_TILTS / PROBE_TILTS[-1] * (CONE_FILL * math.acos(min(1.0, cone)))
    else:
        centre = u
        tilts = PROBE_TILTS if spec.max_incidence is None else \
            PROBE_TILTS[PROBE_TILTS <= spec.max_incidence + 1e-12]
    az = np.arange(PROBE_AZIMUTHS) * (2.0 * np.pi / PROBE_AZIMUTHS)
    # A basis (e1, e2) orthogonal to each centre direction.
    helper = np.where((np.abs(centre[:, 2]) < 0.9)[:, None], np.array([0.0, 0.0, 1.0]),
                      np.array([1.0, 0.0, 0.0]))
    e1 = np.cross(centre, helper)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(centre, e1)
    dirs = [centre[:, None, :]]  # head-on (or along the sector's axis) first
    for t in tilts[tilts > 0.0]:
        ring = (np.cos(az)[None, :, None] * e1[:, None, :]
                + np.sin(az)[None, :, None] * e2[:, None, :])
        dirs.append(np.cos(t) * centre[:, None, :] + np.sin(t) * ring)
    W = np.concatenate(dirs, axis=1)  # (m, T, 3) unit, from the landmark to the camera
    dist = np.asarray(PROBE_DISTANCES) * d_opt
    P = q[:, None, None, :] + dist[None, None, :, None] * W[:, :, None, :]  # (m, T, R, 3)
    V = np.broadcast_to(-W[:, :, None, :], P.shape)
    return P.reshape(m, -1, 3), np.ascontiguousarray(V).reshape(m, -1, 3)


def probe_quality(P: Array, V: Array, q: Array, u: Array, d_opt: float,
                  spec: CaptureSpec, axis: Array | None = None,
                  cos_cone: float | None = None) -> Array:
    """Eq. 3.1 (with field of view and incidence limits, and with view sectors ``axis``
    (m, 3) and ``cos_cone`` their cones) of each landmark j from its own probe poses P[j],
    V[j] (m, S, 3); returns (m, S)."""
    m, S = P.shape[0], P.shape[1]
    if m == 0:
        return np.zeros((0, S))
    cone = _cone(axis, cos_cone)
    Pf, Vf = P.reshape(-1, 3), V.reshape(-1, 3)
    own = np.repeat(np.arange(m), S)
    D = q[own] - Pf
    r = np.sqrt((D * D).sum(axis=1))
    dv = (D * Vf).sum(axis=1)
    pu = -(D * u[own]).sum(axis=1)
    ok = (dv > 0.0) & (pu > 0.0) & (r > 0.0)
    if spec.max_incidence is not None:
        ok &= pu >= np.cos(spec.max_incidence) * r - 1e-12
    if axis is not None and cone is not None:
        ok &= -(D * axis[own]).sum(axis=1) >= cone * r - 1e-12
    if (fine := spec._gsd_ok(r, np.maximum(pu, 1e-300))) is not None:
        ok &= fine
    out = np.zeros(m * S)
    out[ok] = ExpDistance(d_opt).fbar(r[ok]) * dv[ok] * pu[ok]
    return out.reshape(m, S)


def seed_rows(m: int, max_seeds: int = MAX_SEEDS) -> NDArray[np.intp]:
    """Rows of the landmarks that seed candidate viewpoints: all, or ``max_seeds`` evenly
    spaced ones (landmarks sampled on a surface are in no spatial order); past
    ``max_seeds`` · :data:`LANDMARKS_PER_SEED` landmarks also every
    :data:`LANDMARKS_PER_SEED`-th row, so that the seeds keep up with a larger structure
    (else nearly every landmark would be missed by their candidates and add its own 75
    probe poses)."""
    if m <= max_seeds:
        return np.arange(m, dtype=np.intp)
    rows = np.unique(np.linspace(0, m - 1, max_seeds).round().astype(np.intp))
    if m > max_seeds * LANDMARKS_PER_SEED:
        rows = np.union1d(rows, np.arange(0, m, LANDMARKS_PER_SEED, dtype=np.intp))
    return np.asarray(rows, dtype=np.intp)


def inspection_candidates(q: Array, u: Array, d_opt: float, spec: CaptureSpec,
                          axis: Array | None = None, cos_cone: float | None = None
                          ) -> tuple[Array, Array]:
    """Candidate viewpoints of an inspection (K, 3) each [m; world ENU] seeded by the
    landmarks (q, u) (m, 3) given: their probe poses (in their view sectors with ``axis``
    and ``cos_cone``) and the neighbourhood viewpoints of
    :func:`~agent.core.viewpoints.seed_viewpoints` further back (wider footprints)."""
    P1, V1 = probe_poses(q, u, d_opt, spec, axis, cos_cone)
    P2, V2 = seed_viewpoints(q, u, d_opt, distances=GROUP_DISTANCES, block=MAX_SEEDS)
    return np.vstack([P1.reshape(-1, 3), P2]), np.vstack([V1.reshape(-1, 3), V2])


def captured_mask(quality: Array, clear: Mask | None, spec: CaptureSpec) -> Mask:
    """Captures from per-landmark qualities (any shape) and an optional line-of-sight mask
    of the same shape: quality ≥ ``spec.threshold`` and clear."""
    ok = quality >= spec.threshold
    return ok if clear is None else ok & clear


#: Why a landmark cannot be captured (codes of :func:`uncapturable_reasons`), in the order
#: the probe poses are filtered.
REASONS: dict[int, str] = {
    1: "every pose that would image it is outside the mission space",
    2: "every pose that would image it is inside the structure's margin",
    3: "the structure hides it from every pose that would image it",
    4: "it lies on a face buried inside another part of the structure",
    5: "it faces a closed cavity of the structure that no drone can enter",
    6: "no pose near it images it to the spec (quality, ground sampling distance, incidence)",
    7: "no pose near it images it to the spec from its view sector (inspection.views)",
}


def uncapturable_reasons(good: Mask, inside: Mask, clear_of_structure: Mask,
                         sight: Mask) -> NDArray[np.int8]:
    """Per landmark (rows of the (m, S) probe masks): 0 if some probe pose reaches the
    quality (``good``), lies in the mission space (``inside``), keeps the structure's margin
    (``clear_of_structure``) and sees it (``sight``); else the first filter that left no pose
    (a code of :data:`REASONS`)."""
    a = good & inside
    b = a & clear_of_structure
    c = b & sight
    out = np.zeros(good.shape[0], dtype=np.int8)
    out[~c.any(axis=1)] = 3
    out[~b.any(axis=1)] = 2
    out[~a.any(axis=1)] = 1
    out[~good.any(axis=1)] = 6
    return out


class CaptureTable:
    """The viewpoints of one inspection and what each captures: candidate poses P, V (K, 3)
    [m; world ENU], ``C`` (K, m) (viewpoint k captures landmark j: quality, field of view,
    incidence, feasible pose, line of sight), ``value`` (K,) the summed quality of its
    captures (ties of the cover), and per landmark the :data:`REASONS` code (0: capturable).

    ``C`` is given dense or as :class:`CaptureRows` (what the builder makes: it is kept by
    rows, :attr:`rows`); the dense matrix is made on first use of :attr:`C`."""

    def __init__(self, P: Array, V: Array, C: Mask | CaptureRows, value: Array,
                 reason: NDArray[np.int8]) -> None:
        self.P, self.V, self.value, self.reason = P, V, value, reason
        if isinstance(C, CaptureRows):
            self.rows = C
        else:
            self.rows = CaptureRows.from_dense(C)
            self.__dict__["C"] = C  # the cached_property's slot: no second dense copy
        if self.rows.shape != (P.shape[0], reason.shape[0]):
            raise ValueError(f"capture matrix {self.rows.shape} does not match "
                             f"{P.shape[0]} viewpoints x {reason.shape[0]} landmarks")

    @functools.cached_property
    def C(self) -> Mask:
        """C (K, m) dense (made once from :attr:`rows`)."""
        return self.rows.dense()

    @property
    def capturable(self) -> Mask:
        """Landmarks (m,) some feasible pose captures."""
        return np.asarray(self.reason == 0, dtype=np.bool_)

    @functools.cached_property
    def capturers(self) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
        """``C`` by columns (as :func:`agent.core.tours.capturers` gives it), computed once
        from :attr:`rows`."""
        return self.rows.columns()


def uncapturable_line(reason: NDArray[np.int8], ids: NDArray[np.int64], most: int = 20) -> str:
    """One line naming the uncapturable landmarks by reason (empty when there are none):
    ``3 uncapturable (the structure hides it ...): 4, 9, 17``."""
    parts = []
    for code, why in REASONS.items():
        bad = ids[reason == code]
        if bad.size:
            shown = ", ".join(map(str, bad[:most].tolist())) + (" ..." if bad.size > most else "")
            parts.append(f"{bad.size} uncapturable ({why}): {shown}")
    return "; ".join(parts)
