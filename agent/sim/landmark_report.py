"""Per landmark, how well it was inspected: the report's landmark table, ``landmarks.csv``
and ``structure.png`` (the structure's mesh with the landmarks coloured by quality, the
unseen ones marked).

Where the numbers come from:

* an **inspection** (``result.inspection`` set): the captures. A landmark's row is its best
  capture (the highest eq. 3.1 quality logged for it): that camera's distance to it
  ``|q − p|`` [m], the incidence ``β = ∠(u, p − q)`` [deg] between the landmark's normal and the
  line to the camera, the logged quality, which drone and when (mission time τ [s]). Without a
  capture it is *not captured* (its note: ``given up: <reason>``, why it was given up), or
  *uncapturable* (with the capture table's reason).
* a **coverage** mission: the final poses. Each drone's camera (p, v) at the end gives eq. 3.1
  for every landmark (facing model; under ``visibility = "occlusion"`` a landmark hidden by the
  structure from that camera counts 0); the row is the best drone's: quality, distance,
  incidence. A landmark no final camera sees (quality 0) is *unseen*.

Every quantity is computed over all landmarks at once (numpy); positions [m; world ENU].
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from agent.core.vision import per_landmark
from agent.sim.result import SimResult

Array = NDArray[np.float64]
#: ``unoccluded(p, q, u)``: which landmarks (q, u) the structure leaves in sight of p
Sight = Callable[[Array, Array, Array], NDArray[np.bool_]]
#: Most triangles of a mesh drawn in ``structure.png`` (evenly thinned beyond).
MAX_FACES = 12000
#: Status words, worst first (the table's order).
STATUSES = ("not captured", "unseen", "uncapturable", "captured", "seen")


@dataclass(frozen=True)
class LandmarkTable:
    """One row per landmark, in the result's landmark order."""

    ids: NDArray[np.int64]
    status: NDArray[np.str_]  #: one of :data:`STATUSES`
    quality: Array  #: best eq. 3.1 quality (0: none)
    distance: Array  #: [m] from the best camera (NaN: none)
    incidence: Array  #: [deg] between the normal and the line to the best camera (NaN: none)
    by: NDArray[np.str_]  #: the best camera's drone ("" : none)
    tau: Array  #: [s] mission time of the best capture (NaN: none, or a coverage mission)
    reason: NDArray[np.str_]  #: why uncapturable ("" otherwise)
    source: str  #: "captures" or "final poses"

    @property
    def good(self) -> NDArray[np.bool_]:
        """Captured or seen."""
        return np.isin(self.status, ("captured", "seen"))

    def order(self) -> NDArray[np.intp]:
        """Rows worst first: by status (:data:`STATUSES`), then by quality."""
        severity = np.full(self.ids.size, len(STATUSES))
        for k, word in enumerate(STATUSES):  # a loop over the five statuses
            severity[self.status == word] = k
        return np.lexsort((self.ids, self.quality, severity))



def metric_axes_3d(ax: Any, lo: NDArray[np.float64], hi: NDArray[np.float64], pad: float
                   ) -> None:
    """3-D axes over [lo − pad, hi + pad] [m; world ENU] with one scale on every axis and
    metre labels (shared by every 3-D figure of the report)."""
    lo, hi = lo - pad, hi + pad
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_zlim(lo[2], hi[2])
    ax.set_box_aspect(tuple(hi - lo))
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_zlabel("z [m]")

def _geometry(P: Array, q: Array, u: Array) -> tuple[Array, Array]:
    """Distance [m] and incidence [deg] of landmarks (q, u) (m, 3) seen from P (m, 3)."""
    d = P - q
    r = np.linalg.norm(d, axis=1)
    cos_b = np.einsum("ij,ij->i", d, u) / np.where(r > 0.0, r, 1.0)
    return r, np.degrees(np.arccos(np.clip(cos_b, -1.0, 1.0)))


def _from_captures(result: SimResult) -> LandmarkTable:
    """The table of an inspection (module docstring)."""
    ids = np.asarray(result.landmark_ids, dtype=np.int64)
    m = ids.size
    caps = result.captures
    n_each = np.array([len(c.landmarks) for c in caps], dtype=np.intp)  # a loop over captures
    lm = np.array([x for c in caps for x in c.landmarks], dtype=np.int64)
    qual = np.array([x for c in caps for x in c.quality], dtype=np.float64)
    k = np.repeat(np.arange(len(caps)), n_each)
    order = np.argsort(ids, kind="stable")
    pos = np.clip(np.searchsorted(ids[order], lm), 0, max(m - 1, 0))
    ok = (ids[order][pos] == lm) if m else np.zeros(0, dtype=bool)
    row, k, qual = order[pos[ok]], k[ok], qual[ok]
    best = np.lexsort((-qual, row))  # per row, highest quality first
    first = best[np.r_[True, row[best][1:] != row[best][:-1]]] if best.size else best
    got, kb = row[first], k[first]
    quality, distance, incidence = np.zeros(m), np.full(m, np.nan), np.full(m, np.nan)
    tau = np.full(m, np.nan)
    by = np.full(m, "", dtype=object)
    if got.size:
        P = np.array([c.position for c in caps], dtype=np.float64)[kb]
        distance[got], incidence[got] = _geometry(P, result.q[got], result.u[got])
        quality[got] = qual[first]
        agents = np.array([c.agent for c in caps], dtype=object)[kb]
        t = np.array([c.t for c in caps], dtype=np.float64)[kb]
        off = np.array([result.clock_offsets.get(a, 0.0) for a in agents], dtype=np.float64)
        by[got], tau[got] = agents, t - off
    reason = np.full(m, "", dtype=object)
    status = np.full(m, "not captured", dtype=object)
    ins = result.inspection
    if ins is not None and ins.uncapturable:
        bad = np.isin(ids, np.fromiter(ins.uncapturable, dtype=np.int64))
        status[bad] = "uncapturable"
        reason[bad] = [ins.uncapturable[int(i)] for i in ids[bad]]  # the few uncapturable
    if ins is not None and ins.given_up:
        gone = np.isin(ids, np.fromiter(ins.given_up, dtype=np.int64))
        reason[gone] = [f"given up: {ins.given_up[int(i)]}" for i in ids[gone]]
    status[got] = "captured"
    return LandmarkTable(ids, status.astype(str), quality, distance, incidence,
                         by.astype(str), tau, reason.astype(str), "captures")


def _from_final_poses(result: SimResult, sight: Sight | None) -> LandmarkTable:
    """The table of a coverage mission (module docstring)."""
    ids = np.asarray(result.landmark_ids, dtype=np.int64)
    q, u = result.q, result.u
    P, V = result.positions[-1], result.directions[-1]
    vis = np.zeros((P.shape[0], ids.size))
    for i in range(P.shape[0]):  # a loop over drones; the landmarks are vectorised
        vis[i] = per_landmark(P[i], V[i], q, u, result.d_opt)
        if sight is not None and (seen := vis[i] > 0.0).any():
            hidden = np.flatnonzero(seen)[~sight(P[i], q[seen], u[seen])]
            vis[i, hidden] = 0.0
    best = np.argmax(vis, axis=0) if P.shape[0] else np.zeros(ids.size, dtype=np.intp)
    quality = vis[best, np.arange(ids.size)] if P.shape[0] else np.zeros(ids.size)
    seen = quality > 0.0
    distance, incidence = np.full(ids.size, np.nan), np.full(ids.size, np.nan)
    distance[seen], incidence[seen] = _geometry(P[best[seen]], q[seen], u[seen])
    by = np.where(seen, np.asarray(result.agent_ids, dtype=object)[best], "")
    return LandmarkTable(ids, np.where(seen, "seen", "unseen").astype(str), quality, distance,
                         incidence, by.astype(str), np.full(ids.size, np.nan),
                         np.full(ids.size, "", dtype=str), "final poses")


def landmark_table(result: SimResult, sight: Sight | None = None) -> LandmarkTable:
    """The per-landmark table of ``result`` (module docstring); ``sight`` is the structure's
    line-of-sight test, used for a coverage mission under ``visibility = "occlusion"``."""
    if result.inspection is not None:
        return _from_captures(result)
    return _from_final_poses(result, sight if result.visibility == "occlusion" else None)


def write_csv(table: LandmarkTable, result: SimResult, path: Path) -> None:
    """``landmarks.csv``: one row per landmark, worst first (the HTML table's order)."""
    o = table.order()
    cols = [table.ids[o].astype(str), table.status[o]]
    cols += [np.char.mod("%.4f", result.q[o, k]) for k in range(3)]
    cols += [np.char.mod("%.4f", table.quality[o]), np.char.mod("%.3f", table.distance[o]),
             np.char.mod("%.1f", table.incidence[o]), table.by[o],
             np.char.mod("%.2f", table.tau[o]), np.char.replace(table.reason[o], ",", ";")]
    rows = np.stack(cols, axis=1).astype(str)
    body = "\n".join(",".join(r) for r in rows.tolist())  # formatting the rows only
    path.write_text("id,status,x_m,y_m,z_m,quality,distance_m,incidence_deg,by,tau_s,reason\n"
                    + body + "\n", encoding="utf-8")


def plot_structure(result: SimResult, table: LandmarkTable, mesh: tuple[Array, Any] | None,
                   path: Path) -> None:
    """``structure.png``: the mesh (vertices [m], faces) in light grey, the landmarks
    captured or seen coloured by quality (viridis, 0..1), the others marked: red crosses
    (not captured, unseen), grey pluses (uncapturable); inspection captures as grey dots."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    fig = Figure(figsize=(8.0, 7.0), layout="constrained")
    FigureCanvasAgg(fig)
    ax: Any = fig.add_subplot(projection="3d")
    q = result.q
    pts = [q]
    if mesh is not None:
        vertices, faces = np.asarray(mesh[0], dtype=np.float64), np.asarray(mesh[1])
        faces = faces[:: max(1, int(np.ceil(faces.shape[0] / MAX_FACES)))]
        ax.add_collection3d(Poly3DCollection(vertices[faces], facecolor=(0.8, 0.8, 0.8, 0.25),
                                             edgecolor=(0.5, 0.5, 0.5, 0.15), linewidth=0.2))
        pts.append(vertices)
    good = table.good
    sc = ax.scatter(q[good, 0], q[good, 1], q[good, 2], c=table.quality[good], cmap="viridis",
                    vmin=0.0, vmax=1.0, marker="o", s=22, depthshade=False,
                    label=f"{'captured' if table.source == 'captures' else 'seen'} "
                          "(colour: quality)")
    miss = np.isin(table.status, ("not captured", "unseen"))
    if miss.any():
        ax.scatter(q[miss, 0], q[miss, 1], q[miss, 2], c="red", marker="x", s=50,
                   linewidths=2.0, depthshade=False, label=f"{table.status[miss][0]} "
                   f"({int(miss.sum())})")
    bad = table.status == "uncapturable"
    if bad.any():
        ax.scatter(q[bad, 0], q[bad, 1], q[bad, 2], c="0.35", marker="+", s=50,
                   depthshade=False, label=f"uncapturable ({int(bad.sum())})")
    if result.captures:
        C = np.array([c.position for c in result.captures], dtype=np.float64)
        ax.scatter(C[:, 0], C[:, 1], C[:, 2], c="0.45", marker=".", s=6, label="captures")
    allp = np.vstack(pts)
    lo, hi = allp.min(axis=0), allp.max(axis=0)
    metric_axes_3d(ax, lo, hi, 0.05 * float(np.max(hi - lo)) + 0.2)
    fig.colorbar(sc, ax=ax, shrink=0.6, label="best quality (eq. 3.1; 1 = head-on at d_opt)")
    ax.set_title(f"{result.scenario}: {int(good.sum())}/{good.size} landmarks "
                 f"{'captured' if table.source == 'captures' else 'seen at the end'}",
                 fontsize=9)
    ax.legend(loc="upper left", fontsize=8)
    fig.savefig(path, dpi=110)
