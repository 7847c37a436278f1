"""What was imaged how well, part by part: the report's resolution section of an inspection.

Landmarks are grouped by the structure's part they lie on (a connected part of the mesh as
loaded, :mod:`agent.structure.repair`; none without a mesh) and by the way their face looks
(``up``, ``down``, or a compass side ``N``, ``E``, ``S``, ``W`` for the rest: normals within
45° of the vertical are up or down). For each group: how many landmarks, captured, left; the
ground sampling distance (GSD) of their captures (each landmark's finest, from the logged
camera positions: :func:`agent.core.camera.ground_sampling_distance`) with its median and
worst; and the least *margin* left to the spec: 1 − GSD / gsd limit with a camera's GSD
limit, else vision / quality − 1. A histogram shows the GSD (or the quality) of every
captured landmark against the limit. Positions [m; world ENU].
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from agent.core.camera import ground_sampling_distance

if TYPE_CHECKING:
    from agent.config.scenario import Scenario
    from agent.core.inspection import CaptureSpec
    from agent.sim.result import SimResult

Array = NDArray[np.float64]
Index = NDArray[np.intp]

#: Face directions: a normal within 45° of the vertical is "up" or "down".
VERTICAL_COS = float(np.cos(np.radians(45.0)))
SIDES = ("N", "E", "S", "W")


def face_direction(u: Array) -> list[str]:
    """``up``, ``down`` or the compass side (N, E, S, W) each unit normal u (m, 3) faces
    [world ENU: x east, y north]."""
    heading = np.degrees(np.arctan2(u[:, 0], u[:, 1])) % 360.0  # clockwise from north
    side = np.asarray(SIDES)[(((heading + 45.0) % 360.0) // 90.0).astype(np.intp)]
    out = np.where(u[:, 2] >= VERTICAL_COS, "up", np.where(u[:, 2] <= -VERTICAL_COS, "down",
                                                             side))
    return [str(x) for x in out]


def best_gsd(captures: Sequence[tuple[Sequence[float], Sequence[int]]], ids: Sequence[int],
             q: Array, u: Array, pixel_angle: float) -> Array:
    """Each landmark's finest GSD [m/px] over the captures that imaged it, (camera position
    [m; world ENU], landmark ids) each; NaN for a landmark never captured."""
    index = {int(lid): j for j, lid in enumerate(ids)}
    out = np.full(len(ids), np.inf)
    for position, lids in captures:  # one image at a time; its landmarks vectorised
        rows = np.array([index[int(x)] for x in lids if int(x) in index], dtype=np.intp)
        if rows.size == 0:
            continue
        g = ground_sampling_distance(np.asarray(position, dtype=np.float64)[None, :], q[rows],
                                    u[rows], pixel_angle)[0]
        np.minimum.at(out, rows, g)
    return np.where(np.isfinite(out), out, np.nan)


def spec_numbers(spec: CaptureSpec) -> dict[str, float]:
    """The numbers of ``spec`` the resolution report needs: the least vision ``quality`` and
    ``threshold``, and with a camera ``pixel_angle`` [rad/px], ``image_w`` / ``image_h``
    [px], ``trigger_s`` [s], ``gsd_limit_mm`` and ``gsd_aim_mm`` [mm/px] (with a limit)."""
    out = {"quality": spec.quality, "threshold": spec.threshold}
    if spec.camera is not None:
        out.update(pixel_angle=spec.camera.pixel_angle, image_w=float(spec.camera.image_px[0]),
                   image_h=float(spec.camera.image_px[1]), trigger_s=spec.camera.trigger_s)
    if spec.gsd is not None and spec.gsd_aim is not None:
        out.update(gsd_limit_mm=spec.gsd * 1000.0, gsd_aim_mm=spec.gsd_aim * 1000.0)
    return out


def scenario_parts(sc: Scenario) -> list[int] | None:
    """Each landmark's part of ``sc``'s structure mesh (None without a structure)."""
    if sc.structure is None:
        return None
    from agent.structure.repair import landmark_parts
    from agent.world.structure import structure_model

    part = landmark_parts(structure_model(sc.structure).mesh, sc.q)
    return None if part is None else [int(x) for x in part]


@dataclass(frozen=True)
class GroupRow:
    """One group of landmarks in the resolution table."""

    name: str  #: e.g. "part 2, facing up"
    landmarks: int
    captured: int
    left: int  #: capturable, not captured
    median: float  #: GSD [mm/px] (or quality) median over the captured ones; NaN if none
    worst: float  #: largest GSD [mm/px] (or least quality); NaN if none
    margin: float  #: least margin to the spec over the captured ones; NaN if none


def resolution_rows(part: Index | None, u: Array, captured: NDArray[np.bool_],
                    capturable: NDArray[np.bool_], value: Array, limit: float,
                    gsd: bool) -> list[GroupRow]:
    """One row per (part, face direction) group, least margin first. ``value`` per landmark:
    its GSD [mm/px] (``gsd``) or its capture quality; ``limit`` the spec's GSD limit [mm/px]
    or least quality."""
    sides = face_direction(u)
    parts = np.zeros(u.shape[0], dtype=np.intp) if part is None else part
    many = part is not None and np.unique(parts).size > 1
    side_names, side = np.unique(np.asarray(sides), return_inverse=True)
    part_names, part_of = np.unique(parts, return_inverse=True)
    key = part_of.reshape(-1) * side_names.size + side.reshape(-1)  # one group per pair
    margin = (1.0 - value / limit) if gsd else (value / limit - 1.0)
    rows = []
    for k in np.unique(key).tolist():  # a few groups, each vectorised
        g = key == k
        facing = str(side_names[k % side_names.size])
        name = (f"part {int(part_names[k // side_names.size]) + 1}, facing {facing}" if many
                else f"facing {facing}")
        got = g & captured
        vals, marg = value[got], margin[got]
        fine = vals[np.isfinite(vals)]
        rows.append(GroupRow(
            name=name, landmarks=int(g.sum()), captured=int(got.sum()),
            left=int((g & capturable & ~captured).sum()),
            median=float(np.median(fine)) if fine.size else float("nan"),
            worst=(float(fine.max()) if gsd else float(fine.min())) if fine.size
            else float("nan"),
            margin=float(np.nanmin(marg)) if np.isfinite(marg).any() else float("nan")))
    return sorted(rows, key=lambda r: (np.isnan(r.margin), r.margin))


def plot_histogram(path: Path, value: Array, limit: float, aim: float | None, gsd: bool) -> None:
    """A histogram of ``value`` (GSD [mm/px] or quality) of the captured landmarks, with the
    spec's limit (and the aimed one) marked, written to ``path`` (PNG)."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(6.0, 3.2))
    ax = fig.add_subplot(1, 1, 1)
    fine = value[np.isfinite(value)]
    ax.hist(fine, bins=min(30, max(5, fine.size // 4)), color="#4477aa")
    ax.axvline(limit, color="#cc3311", label="spec")
    if aim is not None and aim != limit:
        ax.axvline(aim, color="#ee7733", linestyle="--", label="aimed")
    ax.set_xlabel("ground sampling distance [mm/px]" if gsd else "capture quality (eq. 3.1)")
    ax.set_ylabel("landmarks")
    ax.legend(loc="best")
    fig.tight_layout()
    fig.savefig(str(path), dpi=100)


@dataclass(frozen=True)
class Resolution:
    """The resolution section of one inspection's report: the group rows, each landmark's
    value (GSD [mm/px] or quality; NaN if not captured), the spec's limit and aimed value,
    and whether the values are GSDs."""

    rows: list[GroupRow]
    value: Array
    limit: float
    aim: float | None
    gsd: bool

    def note(self) -> str:
        """One sentence saying what the table shows."""
        what = ("ground sampling distance [mm/px] of each landmark's finest capture, "
                f"against the spec's {self.limit:g} mm/px (aimed {self.aim:g}); margin = 1 "
                "- GSD / spec" if self.gsd else
                f"capture quality (eq. 3.1) against the spec's {self.limit:g}; margin = "
                "quality / spec - 1")
        return (f"Landmarks by part of the structure and the way their face looks, least "
                f"margin first: {what}.")


def resolution_of(result: SimResult) -> Resolution | None:
    """The resolution section of an inspection ``result`` (None for a coverage mission)."""
    ins = result.inspection
    if ins is None:
        return None
    ids = [int(x) for x in result.landmark_ids]
    numbers = ins.numbers
    captured = np.isin(np.asarray(ids), np.asarray(ins.captured, dtype=np.int64))
    uncapturable = np.isin(np.asarray(ids), np.asarray(list(ins.uncapturable), dtype=np.int64))
    limit_mm = numbers.get("gsd_limit_mm")
    pixel = numbers.get("pixel_angle")
    if limit_mm is not None and pixel is not None:
        value = 1000.0 * best_gsd([(c.position, c.landmarks) for c in result.captures], ids,
                                  result.q, result.u, pixel)
        limit, aim, gsd = limit_mm, numbers.get("gsd_aim_mm"), True
    else:
        best: dict[int, float] = {}
        for c in result.captures:  # capture events, each with its landmarks' qualities
            for lid, qual in zip(c.landmarks, c.quality, strict=True):
                best[int(lid)] = max(best.get(int(lid), 0.0), float(qual))
        value = np.array([best.get(i, np.nan) for i in ids])
        limit, aim, gsd = ins.quality, numbers.get("threshold"), False
    part = None if ins.parts is None else np.asarray(ins.parts, dtype=np.intp)
    rows = resolution_rows(part, result.u, captured, ~uncapturable, value, limit, gsd)
    return Resolution(rows, value, float(limit), None if aim is None else float(aim), gsd)
