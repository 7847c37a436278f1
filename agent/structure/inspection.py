"""The capture table of an inspection: candidate viewpoints checked against the mission space,
the structure's margin and its line of sight (:class:`~agent.core.inspection.CaptureTable`).

Built once per mission, before take-off, by everyone who plans (the simulator, each agent):
the candidates of :func:`~agent.core.inspection.inspection_candidates`, kept when inside the
mission box and at least ``margin`` [m] from the structure's surface (outside it); for each kept
candidate the landmarks it captures (eq. 3.1 ≥ quality, field of view, incidence) whose line
of sight the structure's ray caster finds clear (only the pairs that pass the quality test are
cast, in one batch). Landmarks no probe pose can capture get the reason why; so do landmarks
on surface buried inside another part or facing a closed cavity
(:meth:`~agent.structure.model.StructureModel.hidden`), which no camera ever images. With
view sectors (``axis``, ``cos_cone``: :mod:`agent.core.views`) every capture test, probe pose
and reason is that of each view landmark's sector. Positions [m; world ENU].
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from agent.core.inspection import (
    CaptureSpec,
    CaptureTable,
    capture_quality,
    inspection_candidates,
    probe_poses,
    probe_quality,
    seed_rows,
    uncapturable_reasons,
)
from agent.structure.model import StructureModel

Array = NDArray[np.float64]
Mask = NDArray[np.bool_]

#: Hits closer to a landmark than this fraction of the range (at least 1 m) along its line of
#: sight are its own face (the unlifted cast of :func:`sight_lines`).
SIGHT_TOL = 2e-4


def _inside(P: Array, lo: Array, hi: Array) -> Mask:
    return np.asarray(np.all((P >= lo) & (P <= hi), axis=-1), dtype=np.bool_)


def _clear_of(model: StructureModel | None, P: Array) -> Mask:
    """Positions (n, 3) at least the margin outside the structure, in free space reachable
    from outside (all, without one)."""
    if model is None or P.shape[0] == 0:
        return np.ones(P.shape[0], dtype=np.bool_)
    return model.reachable(P)


def sight_lines(model: StructureModel | None, P: Array, q: Array, u: Array,
                pairs: tuple[NDArray[np.intp], ...]) -> Mask:
    """For (camera row, landmark row) pairs: the line of sight P[k] → q[j] is clear of the
    structure (all clear without a structure). Two batched casts, both must be clear: to the
    landmark lifted off its face (``caster.lift`` along u), and to the landmark itself with
    nothing closer than :data:`SIGHT_TOL` of the range before it (its own face): the first
    alone lets a ray through that grazes an edge standing proud of the face a few
    centimetres away (a part set into another) by less than the lift."""
    k, j = pairs
    if model is None or k.size == 0:
        return np.ones(k.size, dtype=np.bool_)
    caster = model.caster
    clear = np.asarray(caster.segment_clear(P[k], q[j] + caster.lift * u[j]), dtype=np.bool_)
    live = np.flatnonzero(clear)
    if live.size:
        rng = np.linalg.norm(q[j[live]] - P[k[live]], axis=1)
        clear[live] = caster.segment_clear(P[k[live]], q[j[live]],
                                           SIGHT_TOL * np.maximum(1.0, rng))
    return clear


def _captures(P: Array, V: Array, q: Array, u: Array, d_opt: float, spec: CaptureSpec,
              lo: Array, hi: Array, model: StructureModel | None, caster: StructureModel | None,
              seen: Mask, axis: Array | None, cos_cone: float | None
              ) -> tuple[Array, Array, Mask, Array]:
    """Candidates kept (in the box, clear of the structure) and what each captures of the
    landmarks not hidden (``seen``)."""
    keep = _inside(P, lo, hi)
    keep[keep] = _clear_of(model, P[keep])
    P, V = P[keep], V[keep]
    Q = capture_quality(P, V, q, u, d_opt, spec, axis, cos_cone)
    good: Mask = (Q >= spec.threshold) & seen[None, :]
    pairs = np.nonzero(good)
    good[pairs] = sight_lines(caster, P, q, u, pairs)
    return P, V, good, np.where(good, Q, 0.0).sum(axis=1)


def capture_table(q: Array, u: Array, d_opt: float, spec: CaptureSpec, lo: Array, hi: Array,
                  model: StructureModel | None, occlusion: bool, axis: Array | None = None,
                  cos_cone: float | None = None) -> CaptureTable:
    """Candidate viewpoints and their captures for landmarks (q, u) (m, 3) in the mission box
    [lo, hi] around ``model`` (the structure: margin and, with ``occlusion``, line of sight);
    with view sectors, ``axis`` (m, 3) and ``cos_cone`` (:mod:`agent.core.views`).
    Candidates are seeded by at most :data:`~agent.core.inspection.MAX_SEEDS` landmarks;
    every landmark none of them captures then gets its own probe poses as candidates, and
    those it still lacks tell why it cannot be captured."""
    caster = model if occlusion else None
    # Surface buried inside another part or facing a closed cavity: never imaged, whatever
    # the visibility model.
    reason = np.zeros(q.shape[0], dtype=np.int8) if model is None else model.hidden(q, u)
    seen = reason == 0
    seeds = seed_rows(q.shape[0])
    seeds = seeds[seen[seeds]]
    P, V, good, value = _captures(*inspection_candidates(
        q[seeds], u[seeds], d_opt, spec, _rows(axis, seeds), cos_cone),
        q, u, d_opt, spec, lo, hi, model, caster, seen, axis, cos_cone)
    missing = np.flatnonzero(~good.any(axis=0) & seen)
    if missing.size:
        PP, VV = probe_poses(q[missing], u[missing], d_opt, spec, _rows(axis, missing),
                             cos_cone)
        P2, V2, good2, value2 = _captures(PP.reshape(-1, 3), VV.reshape(-1, 3), q, u, d_opt,
                                          spec, lo, hi, model, caster, seen, axis, cos_cone)
        P, V = np.vstack([P, P2]), np.vstack([V, V2])
        good, value = np.vstack([good, good2]), np.concatenate([value, value2])
        found = np.asarray(good2.any(axis=0), dtype=np.bool_)
        left = missing[~found[missing]]
        reason[left] = _reasons(q, u, left, d_opt, spec, lo, hi, model, caster, axis,
                                cos_cone)
    useful = good.any(axis=1)
    return CaptureTable(P[useful], V[useful], good[useful], value[useful], reason)


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
