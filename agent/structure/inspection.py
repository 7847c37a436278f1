"""The capture table of an inspection: candidate viewpoints checked against the mission space,
the structure's margin and its line of sight (:class:`~agent.core.inspection.CaptureTable`).

Built once per mission, before take-off (by the simulator; for a team once, into the file its
agents load, :mod:`agent.world.prepared`): the candidates of
:func:`~agent.core.inspection.inspection_candidates`, kept when inside the mission box and at
least ``margin`` [m] from the structure's surface (outside it: one bulk R-tree query, then
point-triangle distances); for each kept candidate the landmarks it captures (eq. 3.1 ≥
quality, field of view, incidence) whose line of sight the structure's ray caster finds clear.
Only the landmarks near each group of candidates are tested (those within the ball of
:func:`~agent.core.inspection.capture_lobe` around any of them, by a k-d tree), and only the
pairs that pass are cast, in batches: the work is O(m + captures), not O(K·m), and the
captures are kept by rows (:class:`~agent.core.capture_rows.CaptureRows`). Landmarks no probe
pose can capture get the reason why; so do landmarks on surface buried inside another part or
facing a closed cavity
(:meth:`~agent.structure.model.StructureModel.hidden`), which no camera ever images. With
view sectors (``axis``, ``cos_cone``: :mod:`agent.core.views`) every capture test, probe pose
and reason is that of each view landmark's sector. Positions [m; world ENU].
"""

from __future__ import annotations

import math
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor

import numpy as np
from numpy.typing import NDArray

from agent.core.capture_rows import CaptureRows
from agent.core.inspection import (
    CaptureSpec,
    CaptureTable,
    capture_lobe,
    capture_quality,
    inspection_candidates,
    probe_poses,
    probe_quality,
    seed_rows,
    uncapturable_reasons,
)
from agent.structure.model import StructureModel
from agent.structure.sight_lines import sight_lines

Array = NDArray[np.float64]
Mask = NDArray[np.bool_]

def _inside(P: Array, lo: Array, hi: Array) -> Mask:
    return np.asarray(np.all((P >= lo) & (P <= hi), axis=-1), dtype=np.bool_)


def _clear_of(model: StructureModel | None, P: Array) -> Mask:
    """Positions (n, 3) at least the margin outside the structure, in free space reachable
    from outside (all, without one)."""
    if model is None or P.shape[0] == 0:
        return np.ones(P.shape[0], dtype=np.bool_)
    return model.reachable(P)


#: Captures (pairs that pass eq. 3.1) whose lines of sight are cast in one batch.
PAIR_BLOCK = 1 << 21
#: Threads casting lines of sight at once (embree and numpy release the GIL).
CAST_THREADS = 2
#: Cameras are grouped by cells of this fraction of their capture ball's radius.
CELL = 0.25
#: Camera-landmark pairs of one cell tested at once (bounds the dense block's memory).
CELL_BLOCK = 1 << 22

Progress = Callable[[str], None]
Pairs = tuple[NDArray[np.intp], NDArray[np.intp]]


def _unit(x: Array) -> Array:
    n = np.linalg.norm(x, axis=1)
    return np.asarray(x / np.where(n > 0.0, n, 1.0)[:, None], dtype=np.float64)


def _cells(X: Array, h: float) -> tuple[NDArray[np.int64], NDArray[np.intp],
                                         NDArray[np.intp]]:
    """Rows of X (n, 3) [m] grouped by the cube of edge ``h`` [m] they lie in: (cells (g, 3)
    integer corners, row order, group starts (g + 1,)); rows ascending within a group."""
    idx = np.floor(X / h).astype(np.int64)
    low = idx.min(axis=0)
    span = idx.max(axis=0) - low + 1
    key = ((idx[:, 0] - low[0]) * span[1] + (idx[:, 1] - low[1])) * span[2] + idx[:, 2] - low[2]
    keys, first, inverse = np.unique(key, return_index=True, return_inverse=True)
    cells = idx[first]
    order = np.argsort(inverse, kind="stable").astype(np.intp)
    starts = np.zeros(keys.size + 1, dtype=np.intp)
    np.cumsum(np.bincount(inverse, minlength=keys.size), out=starts[1:])
    return cells, order, starts


def _captures(P: Array, V: Array, q: Array, u: Array, d_opt: float, spec: CaptureSpec,
              lo: Array, hi: Array, model: StructureModel | None, caster: StructureModel | None,
              seen: Mask, axis: Array | None, cos_cone: float | None,
              progress: Progress | None = None) -> tuple[Array, Array, Pairs, Array]:
    """Candidates kept (in the box, clear of the structure), what each captures of the
    landmarks not hidden (``seen``): the capture pairs (k, j) sorted, and each candidate's
    summed eq. 3.1 quality (K,). The cameras are grouped by the cell of edge :data:`CELL` ·ρ
    their :func:`~agent.core.inspection.capture_lobe` ball's centre lies in; each group is
    tested (:func:`~agent.core.inspection.capture_quality`, the same numbers as over all
    landmarks) against the landmarks within ρ of any point of its cell only (a k-d tree over
    the landmarks), and only the pairs that pass are cast, in batches."""
    from scipy.spatial import cKDTree  # here: scipy.spatial costs start-up time

    keep = _inside(P, lo, hi)
    keep[keep] = _clear_of(model, P[keep])
    P, V = P[keep], V[keep]
    K = P.shape[0]
    value = np.zeros(K)
    empty = np.zeros(0, dtype=np.intp)
    live = np.flatnonzero(seen)
    if K == 0 or live.size == 0:
        return P, V, (empty, empty), value
    scale = float(np.linalg.norm(V, axis=1).max()) * float(np.linalg.norm(u, axis=1).max())
    c, rho = capture_lobe(d_opt, spec, scale)
    h = max(CELL * rho, 1e-6)
    cells, order, starts = _cells(P + c * _unit(V), h)
    tree = cKDTree(q[live])
    reach = rho + h * math.sqrt(3.0) / 2.0  # from the cell's centre to all of its balls
    ks: list[NDArray[np.int32]] = []
    js: list[NDArray[np.int32]] = []
    batch: list[tuple[NDArray[np.intp], NDArray[np.intp], Array]] = []
    pending = done = 0

    def cast() -> None:  # the batch's lines of sight, in CAST_THREADS calls at once
        nonlocal pending, done
        k, j, Q = (np.concatenate(x) for x in zip(*batch, strict=True))
        threads = CAST_THREADS if caster is not None and caster.caster.thread_safe \
            and k.size > 1 << 16 else 1
        parts = np.array_split(np.arange(k.size), threads)
        with ThreadPoolExecutor(len(parts)) as pool:  # the ray caster releases the GIL
            clear = np.concatenate(list(pool.map(
                lambda r: sight_lines(caster, P, q, u, (k[r], j[r])), parts)))
        ks.append(k[clear].astype(np.int32))
        js.append(j[clear].astype(np.int32))
        value[:] += np.bincount(k[clear], weights=Q[clear], minlength=K)
        done += k.size
        batch.clear()
        pending = 0

    for g in range(cells.shape[0]):  # one dense block per cell of cameras (not per landmark)
        near = tree.query_ball_point((cells[g] + 0.5) * h, reach)
        if not near:
            continue
        sub = live[np.sort(np.asarray(near, dtype=np.intp))]
        group = order[starts[g]:starts[g + 1]]
        step = max(1, CELL_BLOCK // sub.size)
        for a in range(0, group.size, step):  # at most CELL_BLOCK pairs at once
            cams = group[a:a + step]
            Q = capture_quality(P[cams], V[cams], q[sub], u[sub], d_opt, spec,
                                None if axis is None else axis[sub], cos_cone)
            kk, jj = np.nonzero(Q >= spec.threshold)
            if kk.size:
                batch.append((cams[kk], sub[jj], Q[kk, jj]))
                pending += kk.size
        if pending >= PAIR_BLOCK:
            cast()
            if progress is not None:
                progress(f"{starts[g + 1]:,}/{K:,} viewpoints tested, {done:,} lines of sight "
                         "cast")
    if batch:
        cast()
    k32 = np.concatenate(ks) if ks else np.zeros(0, dtype=np.int32)
    ks.clear()
    idx = _by_camera(k32)
    k = k32[idx].astype(np.intp)
    del k32  # one copy at a time: these are the largest arrays of the build
    j32 = np.concatenate(js) if js else np.zeros(0, dtype=np.int32)
    js.clear()
    return P, V, (k, j32[idx].astype(np.intp)), value


def _by_camera(k: NDArray[np.int32]) -> NDArray[np.intp]:
    """The order that sorts the pairs by camera k, when each camera's pairs form one run
    (its cell's block) with their landmarks ascending: the runs reordered, not the pairs
    sorted (O(pairs + cameras log cameras))."""
    if k.size == 0:
        return np.zeros(0, dtype=np.intp)
    starts = np.flatnonzero(np.r_[True, k[1:] != k[:-1]])
    lens = np.diff(np.r_[starts, k.size])
    order = np.argsort(k[starts], kind="stable")
    first, size = starts[order], lens[order]
    idx = np.arange(k.size, dtype=np.intp)
    idx += np.repeat(first - np.cumsum(size) + size, size)
    return idx


def capture_table(q: Array, u: Array, d_opt: float, spec: CaptureSpec, lo: Array, hi: Array,
                  model: StructureModel | None, occlusion: bool, axis: Array | None = None,
                  cos_cone: float | None = None, progress: Progress | None = None
                  ) -> CaptureTable:
    """Candidate viewpoints and their captures for landmarks (q, u) (m, 3) in the mission box
    [lo, hi] around ``model`` (the structure: margin and, with ``occlusion``, line of sight);
    with view sectors, ``axis`` (m, 3) and ``cos_cone`` (:mod:`agent.core.views`).
    Candidates are seeded by at most :data:`~agent.core.inspection.MAX_SEEDS` landmarks;
    every landmark none of them captures then gets its own probe poses as candidates, and
    those it still lacks tell why it cannot be captured. ``progress`` gets a line now and
    then. Cost O(m + pairs within capture range); the captures kept by rows
    (:class:`~agent.core.capture_rows.CaptureRows`)."""
    m = q.shape[0]
    caster = model if occlusion else None
    say = progress if progress is not None else (lambda _line: None)
    # Surface buried inside another part or facing a closed cavity: never imaged, whatever
    # the visibility model.
    say(f"{m:,} landmarks: buried faces and closed cavities")
    reason = np.zeros(m, dtype=np.int8) if model is None else model.hidden(q, u)
    seen = reason == 0
    seeds = seed_rows(m)
    seeds = seeds[seen[seeds]]
    P0, V0 = inspection_candidates(q[seeds], u[seeds], d_opt, spec, _rows(axis, seeds),
                                   cos_cone)
    say(f"{P0.shape[0]:,} candidate viewpoints from {seeds.size} seed landmarks")
    P, V, (k, j), value = _captures(P0, V0, q, u, d_opt, spec, lo, hi, model, caster, seen,
                                    axis, cos_cone, progress)
    missing = np.flatnonzero((np.bincount(j, minlength=m) == 0) & seen)
    if missing.size:
        PP, VV = probe_poses(q[missing], u[missing], d_opt, spec, _rows(axis, missing),
                             cos_cone)
        say(f"{missing.size:,} landmarks not captured yet: {PP.shape[0] * PP.shape[1]:,} "
            "probe poses")
        P2, V2, (k2, j2), value2 = _captures(PP.reshape(-1, 3), VV.reshape(-1, 3), q, u,
                                             d_opt, spec, lo, hi, model, caster, seen, axis,
                                             cos_cone, progress)
        found = np.bincount(j2, minlength=m) > 0
        if k2.size:
            k, j = np.r_[k, k2 + P.shape[0]], np.r_[j, j2]
        P, V, value = np.vstack([P, P2]), np.vstack([V, V2]), np.r_[value, value2]
        left = missing[~found[missing]]
        if left.size:  # (none left: every missed landmark found by its own probe poses)
            reason[left] = _reasons(q, u, left, d_opt, spec, lo, hi, model, caster, axis,
                                    cos_cone)
    useful = np.bincount(k, minlength=P.shape[0]) > 0
    renum = np.cumsum(useful) - 1
    K = int(useful.sum())
    np.take(renum, k, out=k)  # in place: k is the largest array here
    say(f"{K:,} useful viewpoints, {k.size:,} captures")
    return CaptureTable(P[useful], V[useful], CaptureRows.from_pairs(k, j, K, m),
                        value[useful], reason)


def _rows(axis: Array | None, rows: NDArray[np.intp]) -> Array | None:
    return None if axis is None else axis[rows]


def _reasons(q: Array, u: Array, rows: NDArray[np.intp], d_opt: float, spec: CaptureSpec,
             lo: Array, hi: Array, model: StructureModel | None,
             caster: StructureModel | None, axis: Array | None = None,
             cos_cone: float | None = None) -> NDArray[np.int8]:
    """Why each landmark of ``rows`` cannot be captured: its probe poses, filter by filter
    (with view sectors: code 7 instead of 6 when a probe pose around the normal, outside the
    sector, would have met the spec)."""
    qs, us, axs = q[rows], u[rows], _rows(axis, rows)
    PP, VV = probe_poses(qs, us, d_opt, spec, axs, cos_cone)
    m, S = PP.shape[0], PP.shape[1]
    pq = probe_quality(PP, VV, qs, us, d_opt, spec, axs, cos_cone) >= spec.threshold
    inside = _inside(PP, lo, hi)
    flat = PP.reshape(-1, 3)
    clear = np.zeros(m * S, dtype=np.bool_)
    cand = np.flatnonzero((pq & inside).reshape(-1))
    clear[cand] = _clear_of(model, flat[cand])
    clear = clear.reshape(m, S)
    sight = np.zeros(m * S, dtype=np.bool_)
    cand = np.flatnonzero((pq & inside & clear).reshape(-1))
    sight[cand] = sight_lines(caster, flat, qs, us, (cand, cand // S))
    out = uncapturable_reasons(pq, inside, clear, sight.reshape(m, S))
    out[out == 0] = 3  # a probe pose passed every filter yet captured nothing: hidden
    if axis is not None and (six := np.flatnonzero(out == 6)).size:
        P0, V0 = probe_poses(qs[six], us[six], d_opt, spec)
        near = probe_quality(P0, V0, qs[six], us[six], d_opt, spec) >= spec.threshold
        out[six[near.any(axis=1)]] = 7  # the spec is met near it, not from its sector
    return out
