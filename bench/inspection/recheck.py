"""Every logged capture re-checked from its logged pose, with maths written apart from the
project's: the quality f(r)·cos α·cos β of eq. 3.1 (f of eq. 3.6), the field of view in the
logged camera frame (optical axis ``direction``, image x axis ``right``; first checked to be
a unit, horizontal axis orthogonal to the optical one), the incidence, optionally the ground
sampling distance and a multi-view inspection's view sector, and the line of sight with
trimesh's own triangle ray caster (not the project's embree caster)."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Protocol, TypedDict

import numpy as np
import trimesh
from numpy.typing import NDArray
from trimesh.ray.ray_triangle import RayMeshIntersector

from agent.config.scenario import Scenario
from agent.core.inspection import CaptureSpec
from agent.protocol.records import CaptureRec
from agent.sim.result import CaptureEvent
from agent.storage.journal import Journal
from agent.world.structure import structure_model


class LoggedCapture(TypedDict):
    """One logged capture: the camera's position [m], optical axis and image x axis (world
    frame) and the ids of the landmarks it captured."""

    position: Sequence[float]
    direction: Sequence[float]
    right: Sequence[float]
    landmarks: Sequence[int]


class _Rays(Protocol):
    """What is used of trimesh's triangle ray caster: hit points (n, 3), their rays' and
    triangles' indices (n,)."""

    def intersects_location(
        self, ray_origins: NDArray[np.float64], ray_directions: NDArray[np.float64], *,
        multiple_hits: bool,
    ) -> tuple[NDArray[np.float64], NDArray[np.intp], NDArray[np.intp]]: ...


#: trimesh's triangle ray caster, with the types its docstrings give: trimesh leaves the class
#: unannotated (calling it is an untyped call), so it is bound here to a typed signature,
#: which mypy checks against the class (one argument, an ``intersects_location`` method).
_triangle_caster: Callable[[trimesh.Trimesh], _Rays] = RayMeshIntersector


def _camera_frame(v: np.ndarray, right: np.ndarray) -> np.ndarray | None:
    """Rows (right, up, forward) of the logged camera, or None if the log is not a camera
    frame with no roll (right not unit, not horizontal or not orthogonal to v)."""
    if abs(float(np.linalg.norm(right)) - 1.0) > 1e-6 or abs(right[2]) > 1e-6 \
            or abs(float(right @ v)) > 1e-6 or abs(float(np.linalg.norm(v)) - 1.0) > 1e-6:
        return None
    up = np.array([right[1] * v[2] - right[2] * v[1], right[2] * v[0] - right[0] * v[2],
                   right[0] * v[1] - right[1] * v[0]])
    return np.array([right, up, v])


def false_captures(mesh: trimesh.Trimesh, captures: list[LoggedCapture], ids: list[int],
                   q: np.ndarray, u: np.ndarray, d_opt: float, quality: float,
                   fov_deg: tuple[float, float], max_incidence_deg: float,
                   gsd: tuple[float, float, float] | None = None,
                   sectors: tuple[np.ndarray, float] | None = None) -> int:
    """How many (capture, landmark) pairs fail the independent check. ``gsd`` = (largest
    ground sampling distance [mm/px], sensor width [mm] / image width [px], focal length
    [mm]): each pair must also have range × pixel pitch / focal length / cos(incidence) ≤
    the largest. ``sectors`` = (unit axes (m, 3), one per row of q, and the cosine of the
    cones' half-angle) of a multi-view inspection: the unit direction from each landmark to
    the logged camera position must make an angle with its row's axis no larger than the
    cone's half-angle."""
    index = {lid: j for j, lid in enumerate(ids)}
    rays = _triangle_caster(mesh)
    bad = 0
    for cap in captures:  # one capture event at a time; its landmarks vectorised
        p = np.asarray(cap["position"], dtype=float)
        rows = np.array([index[lid] for lid in cap["landmarks"]])
        frame = _camera_frame(np.asarray(cap["direction"], dtype=float),
                              np.asarray(cap["right"], dtype=float))
        if frame is None:
            bad += rows.size
            continue
        d = q[rows] - p
        r = np.linalg.norm(d, axis=1)
        cam = d @ frame.T  # (k, 3) in (right, up, forward)
        cos_a = cam[:, 2] / r
        cos_b = -(d * u[rows]).sum(axis=1) / r
        f = (r / d_opt) * np.exp(1.0 - r / d_opt)
        ok = (cos_a > 0) & (cos_b > 0) & (f * cos_a * cos_b >= quality - 1e-9)
        ok &= np.degrees(np.arctan2(np.abs(cam[:, 0]), cam[:, 2])) <= fov_deg[0] / 2 + 1e-6
        ok &= np.degrees(np.arctan2(np.abs(cam[:, 1]), cam[:, 2])) <= fov_deg[1] / 2 + 1e-6
        ok &= np.degrees(np.arccos(np.clip(cos_b, -1, 1))) <= max_incidence_deg + 1e-6
        if gsd is not None:
            limit_mm, pitch_mm, focal_mm = gsd
            with np.errstate(divide="ignore"):
                ok &= r * 1000.0 * pitch_mm / focal_mm / cos_b <= limit_mm * (1 + 1e-9)
        if sectors is not None:
            axes, cos_half = sectors
            away = (p - q[rows]) / r[:, None]  # landmark → camera, unit
            angle = np.degrees(np.arccos(np.clip((away * axes[rows]).sum(axis=1), -1, 1)))
            ok &= angle <= np.degrees(np.arccos(cos_half)) + 1e-6
        dirs = d / r[:, None]
        loc, ray_idx, _ = rays.intersects_location(np.repeat(p[None], rows.size, axis=0),
                                                   dirs, multiple_hits=True)
        first = np.full(rows.size, np.inf)
        if len(ray_idx):
            np.minimum.at(first, ray_idx, np.linalg.norm(loc - p, axis=1))
        ok &= first >= r - 1e-3 * np.maximum(1.0, r)
        bad += int((~ok).sum())
    return bad


def close_views(captures: list[LoggedCapture], ids: list[int], q: np.ndarray,
                view_of: np.ndarray, views: int, parallax_deg: float) -> int:
    """How many landmarks of a multi-view inspection have two captured views whose viewing
    directions (landmark → logged camera position) are less than ``parallax_deg`` apart,
    from the logged positions only (rows of ``q`` are view landmarks, ``view_of`` their
    landmark's id, ``views`` of each)."""
    index = {lid: j for j, lid in enumerate(ids)}
    away = np.full(q.shape, np.nan)
    for cap in captures:  # one capture event at a time; its landmarks vectorised
        rows = np.array([index[lid] for lid in cap["landmarks"]], dtype=np.intp)
        d = np.asarray(cap["position"], dtype=float)[None, :] - q[rows]
        away[rows] = d / np.linalg.norm(d, axis=1)[:, None]
    order = np.argsort(view_of, kind="stable")
    w = away[order].reshape(-1, views, 3)  # (landmarks, views, 3), NaN where not captured
    cos = np.einsum("nki,nli->nkl", w, w)
    off = ~np.eye(views, dtype=bool)[None, :, :] & np.isfinite(cos)
    close = off & (cos > np.cos(np.radians(parallax_deg)) + 1e-12)
    return int(close.any(axis=(1, 2)).sum())


def spec_angles(spec: CaptureSpec) -> tuple[tuple[float, float], float]:
    """The re-check's field of view (horizontal, vertical) and largest incidence [deg] of a
    capture spec (180° and 90° where it has none)."""
    fov = (180.0, 180.0) if spec.fov is None else \
        (math.degrees(spec.fov[0]), math.degrees(spec.fov[1]))
    return fov, 90.0 if spec.max_incidence is None else math.degrees(spec.max_incidence)


def logged(captures: Sequence[CaptureEvent]) -> list[LoggedCapture]:
    """The capture events of a simulator run as the logged captures the re-check reads."""
    return [{"position": c.position, "direction": c.direction, "right": c.right,
             "landmarks": c.landmarks} for c in captures]


def journal_captures(root: Path, aids: list[str]) -> list[CaptureRec]:
    """Every capture record of the drones' journals under ``root``."""
    out = []
    for aid in aids:  # one journal per drone
        j = Journal(root / aid)
        try:
            out += [r for r in j.replay() if isinstance(r, CaptureRec)]
        finally:
            j.close()
    return out


def recheck_records(sc: Scenario, recs: list[CaptureRec]) -> int:
    """How many (record, landmark) pairs of journaled captures ``recs`` fail the independent
    check (:func:`false_captures`) of the scenario's inspection."""
    spec = sc.inspection
    assert spec is not None and sc.structure is not None
    fov = (180.0, 180.0) if spec.fov is None else (math.degrees(spec.fov[0]),
                                                   math.degrees(spec.fov[1]))
    inc = 90.0 if spec.max_incidence is None else math.degrees(spec.max_incidence)
    caps: list[LoggedCapture] = [
        {"position": r.p, "direction": r.v, "right": r.right, "landmarks": r.ids}
        for r in recs]
    return false_captures(structure_model(sc.structure).mesh, caps, list(sc.landmark_ids),
                          sc.q, sc.u, sc.d_opt, spec.quality, fov, inc)
