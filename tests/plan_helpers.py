"""A small inspection ``result.json`` document for the export-plan tests: a 4 m cube of landmarks
(walls and roof, 1 m apart) at x, y, z in [0, 4] [m; world ENU], two drones and their captures."""

from __future__ import annotations

from typing import Any

import numpy as np

ORIGIN = (47.3977419, 8.545594, 488.0)  #: lat, lon [degrees], alt [m] of the world origin


def cube_landmarks() -> list[dict[str, Any]]:
    """Landmarks on the cube's four walls and its roof, 1 m apart, with outward normals."""
    out: list[dict[str, Any]] = []
    s = np.arange(0.5, 4.0, 1.0)
    for a in s:
        for b in s:
            for pos, normal in (([0.0, a, b], [-1, 0, 0]), ([4.0, a, b], [1, 0, 0]),
                                ([a, 0.0, b], [0, -1, 0]), ([a, 4.0, b], [0, 1, 0]),
                                ([a, b, 4.0], [0, 0, 1])):
                out.append({"id": len(out) + 1, "position": [float(x) for x in pos],
                            "normal": [float(x) for x in normal]})
    return out


def capture(t: float, agent: str, position: list[float], direction: list[float],
            landmarks: list[int]) -> dict[str, Any]:
    """A capture row as the simulator writes it (right = v × ẑ normalised, x̂ when vertical)."""
    v = np.asarray(direction, dtype=float)
    v = v / np.linalg.norm(v)
    r = np.cross(v, [0.0, 0.0, 1.0])
    r = r / np.linalg.norm(r) if np.linalg.norm(r) > 1e-9 else np.array([1.0, 0.0, 0.0])
    return {"t": t, "agent": agent, "landmarks": landmarks, "position": position,
            "direction": v.tolist(), "right": r.tolist(), "quality": [0.5] * len(landmarks)}


def inspection_doc(crossing: bool = True) -> dict[str, Any]:
    """Two drones, A west of the cube and B east of it. With ``crossing`` A's route goes from
    the cube's south side straight through it to the north side (a climb over is needed) and B
    images the roof from above; without it, no route comes over the cube's footprint."""
    rows = [capture(0.0, "A", [-6.0, 2.0, 2.0], [1.0, 0.0, 0.0], [1, 2]),
            capture(0.0, "B", [10.0, 2.0, 2.0], [-1.0, 0.0, -0.3], [5, 6])]
    if crossing:
        rows += [capture(3.0, "A", [2.0, -4.0, 2.5], [0.0, 1.0, -0.1], [3]),
                 capture(6.0, "A", [2.0, 8.0, 3.0], [0.0, -1.0, 0.0], [4]),
                 capture(7.0, "B", [2.0, 2.0, 9.0], [0.0, 0.0, -1.0], [7, 8])]
    else:
        rows += [capture(3.0, "A", [-3.0, -4.0, 2.5], [1.0, 1.0, -0.1], [3]),
                 capture(6.0, "A", [-4.0, 8.0, 3.0], [1.0, -1.0, -0.2], [4]),
                 capture(7.0, "B", [8.0, 8.0, 5.0], [-1.0, -1.0, -0.5], [7, 8])]
    return {"scenario": "cube_test", "agents": ["A", "B"],
            "landmarks": cube_landmarks(),
            "space": {"lo": [-10.0, -10.0, 0.5], "hi": [14.0, 14.0, 12.0]},
            "initial_poses": {"A": {"position": [-6.0, 2.0, 2.0], "direction": [1, 0, 0]},
                              "B": {"position": [10.0, 2.0, 2.0], "direction": [-1, 0, 0]}},
            "final_poses": {}, "captures": rows, "inspection": {"quality": 0.3}}
