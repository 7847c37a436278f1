"""Seeded inspection scenes for the coverage-quality benchmark.

Structure types (all 3-D, metres, world ENU, ground at z = 0):

- ``box``: one building, landmarks on its four walls and roof (no floor);
- ``lshape``: an L-shaped building made of two boxes; landmarks inside the other box or on
  the shared wall are removed;
- ``pier``: a vertical cylinder (lateral surface, several rings);
- ``bridge``: a deck (box: top, underside, both long sides, both ends) on 2-3 cylindrical
  columns.

Each structure has a *tuning* and a *held-out* parameter set (disjoint seeds and shifted
parameter ranges). A scene adds a team of n drones with random start poses (inside the
mission space, outside the structure's boxes with a clearance, pairwise ≥ R_s apart, heading
towards the structure ± 60°) and a random initial partition (every landmark to a uniformly
random drone).
Everything is a pure function of its arguments (numpy ``default_rng`` seeded explicitly).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from agent.config.scenario import AgentSpec, Scenario
from agent.core.avoidance import MissionSpace
from agent.core.landmarks import box_faces, cylinder
from agent.core.planner import PlannerParams
from agent.core.viewpoints import Environment

Array = NDArray[np.float64]

KINDS: tuple[str, ...] = ("box", "lshape", "pier", "bridge")
SPLITS: tuple[str, ...] = ("tuning", "heldout")
TEAM_SIZES: tuple[int, ...] = (2, 3, 4, 5, 6, 8)
D_OPT = 2.0  #: optimal viewing distance [m]
R_S = 1.0  #: safety radius [m]
CLEARANCE = 0.3  #: least distance of a drone from the structure's boxes [m]
#: Seed offsets that keep the tuning and held-out structures disjoint.
_SPLIT_SEED = {"tuning": 1_000, "heldout": 9_000}


@dataclass(frozen=True)
class Structure:
    """A structure: landmarks q, u (m, 3) [m; world ENU], its obstacle boxes (B, 2, 3) [m]
    (cylinders by their bounding boxes) and the mission space [lo, hi] [m]."""

    kind: str
    split: str
    index: int
    q: Array
    u: Array
    boxes: Array
    lo: Array
    hi: Array

    @property
    def name(self) -> str:
        """E.g. ``box-tuning-3``."""
        return f"{self.kind}-{self.split}-{self.index}"

    def environment(self) -> Environment:
        """Where a camera may be: the mission box outside the structure (plus clearance)."""
        return Environment(self.lo, self.hi, self.boxes, CLEARANCE, R_S)


@dataclass(frozen=True)
class Scene:
    """A structure plus a team: start poses p0, v0 (n, 3) and initial owners (m,)."""

    structure: Structure
    n: int
    start: int
    p0: Array
    v0: Array
    owner0: NDArray[np.intp]
    d_opt: float = D_OPT
    params: PlannerParams = dataclasses.field(
        default_factory=lambda: PlannerParams(avoidance="smooth", r_s=R_S, d_w=0.5))
    duration: float = 400.0

    @property
    def name(self) -> str:
        """E.g. ``box-tuning-3-n4-s7``."""
        return f"{self.structure.name}-n{self.n}-s{self.start}"

    def scenario(self) -> Scenario:
        """The scene as a validated-shape :class:`Scenario` for :mod:`agent.sim.kinematic`."""
        s = self.structure
        agents = [AgentSpec(f"D{i}", self.p0[i].copy(), self.v0[i].copy(),
                            np.flatnonzero(self.owner0 == i).astype(np.intp))
                  for i in range(self.n)]
        return Scenario(
            name=self.name, seed=self.start, planar=False, d_opt=self.d_opt,
            duration=self.duration, q=s.q, u=s.u, landmark_ids=list(range(1, s.q.shape[0] + 1)),
            agents=agents, params=self.params, space=MissionSpace(s.lo.copy(), s.hi.copy()),
            source=f"<{self.name}>", trading=True, keepout=s.boxes.copy(),
        )


def _box_bounds(center: Array, size: Array) -> Array:
    """(2, 3) rows lo, hi of an axis-aligned box [m]."""
    return np.stack([center - size / 2.0, center + size / 2.0])


def _grid(size_a: float, size_b: float, spacing: float) -> tuple[int, int]:
    """Cell counts for a face of size_a × size_b [m] with about ``spacing`` [m] per landmark."""
    return max(1, round(size_a / spacing)), max(1, round(size_b / spacing))


def _box_landmarks(center: Array, size: Array, spacing: float, faces: tuple[str, ...]
                   ) -> tuple[Array, Array]:
    """Landmarks on the listed faces of a box, about ``spacing`` [m] apart (per-face grids)."""
    qs, us = [], []
    tang = {"x": (1, 2), "y": (0, 2), "z": (0, 1)}
    for f in faces:
        a, b = tang[f[1]]
        q, u = box_faces(center, size, [f], _grid(size[a], size[b], spacing))
        qs.append(q)
        us.append(u)
    return np.vstack(qs), np.vstack(us)


def _outside(q: Array, box: Array, tol: float = 1e-6) -> NDArray[np.bool_]:
    """Rows of q not inside or on the closed box (2, 3) [m]."""
    return np.asarray(~np.all((q >= box[0] - tol) & (q <= box[1] + tol), axis=1), dtype=np.bool_)


def _space_around(boxes: Array, pad: float, top_pad: float) -> tuple[Array, Array]:
    """Mission space: the boxes' hull padded by ``pad`` sideways, z from 0.3 m to top + top_pad."""
    lo = boxes[:, 0, :].min(axis=0) - pad
    hi = boxes[:, 1, :].max(axis=0) + pad
    lo[2] = 0.3
    hi[2] = boxes[:, 1, 2].max() + top_pad
    return lo, hi


def make_structure(kind: str, split: str, index: int) -> Structure:
    """The ``index``-th seeded structure of a kind in a split (tuning or heldout)."""
    if kind not in KINDS or split not in SPLITS:
        raise ValueError(f"unknown structure {kind!r}/{split!r}; use {KINDS} × {SPLITS}")
    rng = np.random.default_rng(_SPLIT_SEED[split] + 97 * KINDS.index(kind) + index)
    held = split == "heldout"
    walls = ("+x", "-x", "+y", "-y", "+z")
    if kind == "box":
        size = rng.uniform([3.0, 2.0, 2.0], [6.0, 5.0, 4.0]) * (1.15 if held else 1.0)
        center = np.array([0.0, 0.0, size[2] / 2.0])
        q, u = _box_landmarks(center, size, rng.uniform(1.2, 1.8), walls)
        boxes = _box_bounds(center, size)[None]
    elif kind == "lshape":
        s1 = rng.uniform([4.0, 2.0, 2.0], [7.0, 3.0, 4.0]) * (1.1 if held else 1.0)
        s2 = rng.uniform([2.0, 3.0, 2.0], [3.0, 5.0, 4.0]) * (1.1 if held else 1.0)
        c1 = np.array([0.0, 0.0, s1[2] / 2.0])
        c2 = np.array([s1[0] / 2.0 - s2[0] / 2.0, s1[1] / 2.0 + s2[1] / 2.0, s2[2] / 2.0])
        b1, b2 = _box_bounds(c1, s1), _box_bounds(c2, s2)
        spacing = rng.uniform(1.3, 1.8)
        q1, u1 = _box_landmarks(c1, s1, spacing, walls)
        q2, u2 = _box_landmarks(c2, s2, spacing, walls)
        k1, k2 = _outside(q1, b2), _outside(q2, b1)
        q, u = np.vstack([q1[k1], q2[k2]]), np.vstack([u1[k1], u2[k2]])
        boxes = np.stack([b1, b2])
    elif kind == "pier":
        radius = rng.uniform(0.5, 1.5) * (1.2 if held else 1.0)
        height = rng.uniform(3.0, 7.0)
        around = int(rng.integers(8, 15))
        rows = max(2, round(height / 1.8))
        q, u = cylinder(np.zeros(3), radius, height, around, rows, rng.uniform(0, np.pi))
        boxes = np.array([[[-radius, -radius, 0.0], [radius, radius, height]]])
    else:  # bridge
        length = rng.uniform(8.0, 12.0) * (1.15 if held else 1.0)
        width = rng.uniform(2.5, 4.0)
        thick = rng.uniform(0.6, 1.0)
        z0 = rng.uniform(3.0, 4.5)
        deck_c = np.array([0.0, 0.0, z0 + thick / 2.0])
        deck_s = np.array([length, width, thick])
        spacing = rng.uniform(1.6, 2.2)
        qd, ud = _box_landmarks(deck_c, deck_s, spacing, ("+x", "-x", "+y", "-y", "+z", "-z"))
        ncol = 2 if length < 10.0 else 3
        rad = rng.uniform(0.3, 0.6)
        xs = np.linspace(-length / 2.0 + 1.5, length / 2.0 - 1.5, ncol)
        cols = [cylinder(np.array([x, 0.0, 0.0]), rad, z0, 6, 2, 0.3) for x in xs]
        q = np.vstack([qd, *(c[0] for c in cols)])
        u = np.vstack([ud, *(c[1] for c in cols)])
        boxes = np.vstack([_box_bounds(deck_c, deck_s)[None]]
                          + [np.array([[[x - rad, -rad, 0.0], [x + rad, rad, z0]]]) for x in xs])
    lo, hi = _space_around(boxes, pad=2.0 * D_OPT + 1.0, top_pad=D_OPT + 1.5)
    return Structure(kind, split, index, q, u, boxes, lo, hi)


def random_starts(structure: Structure, n: int, seed: int) -> tuple[Array, Array]:
    """n start poses: positions uniform in the mission space, outside the boxes with clearance
    and pairwise ≥ R_s apart (rejection sampling, batch-vectorised); heading towards the
    structure's centre ± 60° of yaw (the drone took off facing the work), pitch ±0.3 rad."""
    rng = np.random.default_rng(seed)
    env = structure.environment()
    pts = np.zeros((0, 3))
    while pts.shape[0] < n:
        cand = rng.uniform(structure.lo, structure.hi, size=(64, 3))
        for c in cand[_clear(cand, env)]:
            if pts.shape[0] == n:
                break
            if not pts.shape[0] or float(np.linalg.norm(pts - c, axis=1).min()) >= R_S:
                pts = np.vstack([pts, c])
    centre = structure.q.mean(axis=0)
    to_c = centre - pts
    yaw = np.arctan2(to_c[:, 1], to_c[:, 0]) + rng.uniform(-np.pi / 3, np.pi / 3, n)
    pitch = rng.uniform(-0.3, 0.3, n)
    v = np.stack([np.cos(pitch) * np.cos(yaw), np.cos(pitch) * np.sin(yaw), np.sin(pitch)], 1)
    return pts, v


def _clear(P: Array, env: Environment) -> NDArray[np.bool_]:
    """Positions in the mission space and outside the inflated boxes."""
    lo = env.boxes[:, 0, :] - env.margin
    hi = env.boxes[:, 1, :] + env.margin
    inside = np.all((P[:, None, :] > lo[None]) & (P[:, None, :] < hi[None]), axis=2)
    clear = ~inside.any(axis=1) & np.all((P >= env.lo) & (P <= env.hi), axis=1)
    return np.asarray(clear, dtype=np.bool_)


def make_scene(kind: str, split: str, index: int, n: int, start: int) -> Scene:
    """Structure ``index`` of kind/split, a team of n drones, random start number ``start``."""
    s = make_structure(kind, split, index)
    seed = 100_003 * (_SPLIT_SEED[split] + 97 * KINDS.index(kind) + index) + 101 * n + start
    p0, v0 = random_starts(s, n, seed)
    rng = np.random.default_rng(seed + 7)
    owner0 = np.asarray(rng.integers(0, n, size=s.q.shape[0]), dtype=np.intp)
    return Scene(s, n, start, p0, v0, owner0)
