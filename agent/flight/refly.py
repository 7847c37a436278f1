"""An inspection run's captures as routes to fly again (pure: numpy and scipy, no I/O).

From ``result.json`` (:mod:`agent.sim.inspection_report`): each drone's capture events, in time
order, become *viewpoints* (camera position [m; world ENU], compass heading and pitch of the
optical axis); a route takes off above the drone's start, visits its viewpoints in order and
comes back above its start to land. Between captures the simulated drones flew around the
structure, but a re-flown mission flies straight lines, so every leg is checked against the
structure (its landmarks: a leg passing within ``near`` of one, or crossing its surface
element); a blocked leg gets a climb over the structure (two transit waypoints at the top
landmark's height + ``over``) when that is clear and inside the mission space, and a warning
otherwise.

Fences (horizontal polygons, [m; world ENU] x, y; corners clockwise seen from above, as
QGroundControl writes them): the *inclusion* rectangle is the mission space's, each side moved in
by ``margin`` but never past a waypoint; the *exclusion* rectangle is the structure's footprint
(the landmarks' horizontal bounding box, since ``result.json`` holds no mesh). An autopilot's
fence polygon is a vertical prism, so the exclusion rectangle is left out when a waypoint or a
leg enters it (roof viewpoints, courtyards), with a note saying so.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from agent.flight.geodetic import compass_heading

Array = NDArray[np.float64]

#: What export-plan says about a run without captures (a coverage mission's).
NO_CAPTURES = "no captures to re-fly: export-plan needs an inspection mission's run"
#: Least take-off height [m] (a start pose on the ground still takes off).
MIN_TAKEOFF = 1.0


@dataclass(frozen=True)
class Viewpoint:
    """One capture event to repeat: camera ``position`` [m; world ENU], ``heading`` of the optical
    axis [compass degrees in [0, 360), NaN if undefined], ``pitch`` [degrees, + up, − down,
    from the horizontal], the capture's time ``t`` [s] and its ``landmarks`` (ids)."""

    position: Array
    heading: float
    pitch: float
    t: float
    landmarks: tuple[int, ...]


@dataclass(frozen=True)
class Waypoint:
    """A point to fly to [m; world ENU]: a viewpoint's, or a transit point (``viewpoint`` None:
    a climb over the structure, the return above the start)."""

    position: Array
    viewpoint: Viewpoint | None = None


@dataclass
class Route:
    """One drone's flight: take off at ``launch`` (the ground point below its start [m; world
    ENU], z = 0) to ``takeoff_height`` [m], fly ``waypoints`` in order (the last one above the
    launch point), land at ``launch``. ``warnings``: legs left blocked."""

    agent: str
    launch: Array
    takeoff_height: float
    waypoints: list[Waypoint]
    warnings: list[str] = field(default_factory=list)

    @property
    def viewpoints(self) -> list[Viewpoint]:
        """The viewpoints, in flight order."""
        return [w.viewpoint for w in self.waypoints if w.viewpoint is not None]

    def path(self) -> Array:
        """Every point flown (n, 3) [m; world ENU]: launch, take-off point, waypoints, launch."""
        top = self.launch + np.array([0.0, 0.0, self.takeoff_height])
        return np.array([self.launch, top, *(w.position for w in self.waypoints), self.launch])


@dataclass(frozen=True)
class Fence:
    """Horizontal fence polygons (4, 2) [m; world ENU x, y], clockwise from above, or None; and
    one line per decision worth telling the user."""

    inclusion: Array | None
    exclusion: Array | None
    notes: tuple[str, ...] = ()


def _vec(value: Any, what: str) -> Array:
    try:
        v = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{what}: not a list of numbers") from None
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise ValueError(f"{what}: expected three finite numbers, got {value!r}")
    return v


def camera_angles(direction: Array, right: Array | None) -> tuple[float, float]:
    """(compass heading [degrees], pitch [degrees, + up]) of a camera looking along unit
    ``direction`` [world ENU] with horizontal image x axis ``right`` (v × ẑ): the heading is
    that of ẑ × right, defined even for a camera looking straight down; without ``right``, that
    of the direction's horizontal part (NaN when vertical)."""
    d = direction / np.linalg.norm(direction)
    pitch = math.degrees(math.asin(max(-1.0, min(1.0, float(d[2])))))
    if right is not None and math.hypot(float(right[0]), float(right[1])) > 1e-9:
        return compass_heading(-float(right[1]), float(right[0])), pitch
    return compass_heading(float(d[0]), float(d[1])), pitch


def viewpoints(doc: Mapping[str, Any]) -> dict[str, list[Viewpoint]]:
    """Each drone's viewpoints in capture order, from ``result.json``'s ``captures`` (drones
    in the document's ``agents`` order; those without a capture left out). ValueError for a run
    without captures and for malformed rows."""
    rows = doc.get("captures")
    if not isinstance(rows, list) or not rows:
        raise ValueError(NO_CAPTURES)
    order = [str(a) for a in doc.get("agents") or []]
    out: dict[str, list[Viewpoint]] = {}
    for k, row in enumerate(sorted(rows, key=lambda r: float(r.get("t", 0.0)))):
        try:
            agent = str(row["agent"])
            where = f"captures[{k}] ({agent})"
            pos = _vec(row["position"], f"{where}.position")
            direction = _vec(row["direction"], f"{where}.direction")
            right = _vec(row["right"], f"{where}.right") if row.get("right") else None
            t, ids = float(row["t"]), tuple(int(i) for i in row["landmarks"])
        except (KeyError, TypeError) as e:
            raise ValueError(f"captures[{k}]: missing or malformed field {e}") from None
        if np.linalg.norm(direction) < 1e-9:
            raise ValueError(f"{where}.direction: zero vector")
        heading, pitch = camera_angles(direction, right)
        out.setdefault(agent, []).append(Viewpoint(pos, heading, pitch, t, ids))
    order += [a for a in out if a not in order]
    return {a: out[a] for a in order if a in out}


def start_position(doc: Mapping[str, Any], agent: str) -> Array:
    """A drone's start position [m; world ENU] (``initial_poses``)."""
    try:
        return _vec(doc["initial_poses"][agent]["position"], f"initial_poses.{agent}.position")
    except (KeyError, TypeError):
        raise ValueError(f"initial_poses: no start position for {agent}") from None


class Structure:
    """The structure as its landmarks: positions ``q`` (m, 3) [m; world ENU], unit normals ``u``
    (m, 3) and ids; ``spacing`` [m] is the median distance between neighbouring landmarks."""

    def __init__(self, q: Array, u: Array, ids: Sequence[int]) -> None:
        self.q, self.u, self.ids = q, u, list(ids)
        self.top = float(q[:, 2].max())
        if len(q) >= 2:
            from scipy.spatial import cKDTree

            dist, _ = cKDTree(q).query(q, k=2)
            self.spacing = float(np.median(dist[:, 1]))
        else:
            self.spacing = 1.0

    @classmethod
    def from_doc(cls, doc: Mapping[str, Any]) -> Structure | None:
        """From ``result.json``'s ``landmarks`` (None if it has none)."""
        rows = doc.get("landmarks") or []
        if not rows:
            return None
        try:
            q = np.array([_vec(r["position"], "landmarks.position") for r in rows])
            u = np.array([_vec(r["normal"], "landmarks.normal") for r in rows])
            ids = [int(r["id"]) for r in rows]
        except (KeyError, TypeError) as e:
            raise ValueError(f"landmarks: missing or malformed field {e}") from None
        n = np.linalg.norm(u, axis=1, keepdims=True)
        return cls(q, u / np.where(n > 0.0, n, 1.0), ids)

    def blocking(self, a: Array, b: Array, near: float) -> int | None:
        """The id of a landmark the straight leg a → b [m; world ENU] passes within ``near`` [m]
        of, or crosses the surface at (its tangent plane, within ``spacing`` of it); None if
        the leg is clear."""
        d = b - a
        rel = self.q - a
        den = float(d @ d)
        t = np.clip(rel @ d / den, 0.0, 1.0) if den > 0.0 else np.zeros(len(self.q))
        dist = np.linalg.norm(rel - t[:, None] * d, axis=1)
        sa = np.einsum("ij,ij->i", a - self.q, self.u)
        sb = np.einsum("ij,ij->i", b - self.q, self.u)
        cross = sa * sb < 0.0
        tc = np.where(cross, sa / np.where(cross, sa - sb, 1.0), 0.0)
        miss = np.linalg.norm(a + tc[:, None] * d - self.q, axis=1)
        bad = (dist < near) | (cross & (miss < self.spacing))
        if not bad.any():
            return None
        return self.ids[int(np.argmin(np.where(bad, dist, np.inf)))]


def _leg(a: Array, b: Array, structure: Structure | None, near: float, over: float,
         ceiling: float) -> tuple[list[Array], int | None]:
    """Transit points that take a → b clear of the structure ([] if the straight leg is clear),
    and the id of a landmark still in the way (None when clear)."""
    if structure is None:
        return [], None
    hit = structure.blocking(a, b, near)
    if hit is None:
        return [], None
    z = max(structure.top + over, float(a[2]), float(b[2]))
    if z > ceiling:
        return [], hit
    c1, c2 = np.array([a[0], a[1], z]), np.array([b[0], b[1], z])
    transit = [c for c, end in ((c1, a), (c2, b)) if not np.allclose(c, end)]
    if not transit:  # both ends at the climb height already
        return [], hit
    legs = [a, *transit, b]
    for p, q in itertools.pairwise(legs):
        if structure.blocking(p, q, near) is not None:
            return [], hit
    return transit, None


def plan_route(agent: str, vps: Sequence[Viewpoint], start: Array,
               structure: Structure | None, *, near: float = 0.5, over: float = 2.0,
               ceiling: float = math.inf) -> Route:
    """The route of one drone: take off above ``start`` (to its height, at least
    :data:`MIN_TAKEOFF`), its viewpoints in order, back above the launch point; a leg that meets
    the structure climbs over it (top landmark + ``over`` [m], at most ``ceiling`` [m]) or is
    reported in ``warnings``."""
    launch = np.array([start[0], start[1], 0.0])
    height = max(float(start[2]), MIN_TAKEOFF)
    targets = [Waypoint(v.position, v) for v in vps]
    targets.append(Waypoint(launch + np.array([0.0, 0.0, height])))
    route = Route(agent, launch, height, [])
    prev = targets[-1].position
    for k, target in enumerate(targets):
        transit, hit = _leg(prev, target.position, structure, near, over, ceiling)
        route.waypoints += [Waypoint(p) for p in transit]
        route.waypoints.append(target)
        if hit is not None:
            what = f"viewpoint {k + 1}" if target.viewpoint is not None else "the return"
            route.warnings.append(
                f"{agent}: the straight leg to {what} meets the structure near landmark {hit} "
                "and no climb over it is clear: check that leg before flying")
        prev = target.position
    return route


def _rectangle(lo: Array, hi: Array) -> Array:
    """Corners (4, 2) of [lo, hi] in x, y, clockwise seen from above (x east, y north)."""
    return np.array([[lo[0], lo[1]], [lo[0], hi[1]], [hi[0], hi[1]], [hi[0], lo[1]]])


def _meets_box(a: Array, b: Array, lo: Array, hi: Array) -> bool:
    """Whether segment a → b meets the closed box [lo, hi] (any dimension; Liang-Barsky)."""
    t0, t1 = 0.0, 1.0
    for i in range(len(lo)):
        d = float(b[i] - a[i])
        if abs(d) < 1e-12:
            if a[i] < lo[i] or a[i] > hi[i]:
                return False
            continue
        ta, tb = (lo[i] - a[i]) / d, (hi[i] - a[i]) / d
        t0, t1 = max(t0, min(ta, tb)), min(t1, max(ta, tb))
        if t0 > t1:
            return False
    return True


def _space_xy(doc: Mapping[str, Any]) -> tuple[Array, Array] | None:
    space = doc.get("space") or {}
    lo, hi = space.get("lo") or [], space.get("hi") or []
    if len(lo) < 2 or len(hi) < 2 or any(v is None for v in (*lo[:2], *hi[:2])):
        return None
    return np.array(lo[:2], dtype=np.float64), np.array(hi[:2], dtype=np.float64)


def fences(doc: Mapping[str, Any], routes: Sequence[Route], margin: float = 1.0) -> Fence:
    """The fences shared by every drone's plan (see the module docstring)."""
    notes: list[str] = []
    paths = [r.path() for r in routes]
    xy = np.concatenate([p[:, :2] for p in paths])
    inclusion = None
    space = _space_xy(doc)
    if space is None:
        notes.append("no inclusion fence: the mission space is unbounded in x or y")
    else:
        lo, hi = space
        flo, fhi = np.minimum(lo + margin, xy.min(axis=0)), np.maximum(hi - margin, xy.max(axis=0))
        inclusion = _rectangle(flo, fhi)
        if np.any(flo < lo + margin) or np.any(fhi > hi - margin):
            notes.append(f"inclusion fence: less than {margin:g} m inside the mission space "
                         "where a waypoint comes closer to its edge")
    exclusion = None
    structure = Structure.from_doc(doc)
    if structure is not None:
        blo, bhi = structure.q[:, :2].min(axis=0), structure.q[:, :2].max(axis=0)
        inside = sum(any(_meets_box(p[k, :2], p[k + 1, :2], blo, bhi)
                         for k in range(len(p) - 1)) for p in paths)
        if inside:
            notes.append(f"no exclusion fence: {inside} of {len(paths)} routes fly over or into "
                         "the structure's footprint (roofs, courtyards), and a fence polygon "
                         "is a vertical prism")
        else:
            exclusion = _rectangle(blo, bhi)
    return Fence(inclusion, exclusion, tuple(notes))


def plan_routes(doc: Mapping[str, Any], *, near: float = 0.5, over: float = 2.0
                ) -> list[Route]:
    """Every drone's route (drones with captures, in the document's order). The climb-over
    ceiling is the mission space's top (if bounded)."""
    vps = viewpoints(doc)
    structure = Structure.from_doc(doc)
    hi = (doc.get("space") or {}).get("hi") or []
    ceiling = float(hi[2]) if len(hi) >= 3 and hi[2] is not None else math.inf
    return [plan_route(a, v, start_position(doc, a), structure, near=near, over=over,
                       ceiling=ceiling) for a, v in vps.items()]
