"""Example structures built from trimesh primitives, each one closed (watertight) body.

Every structure stands on the ground plane z = 0 [m; world ENU] with outward-facing
triangles. :func:`write_examples` saves them as binary STL files.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh

from agent.structure.mesh import yaw_rotation


def _prism(outline: list[tuple[float, float]], triangles: list[tuple[int, int, int]],
           height: float) -> trimesh.Trimesh:
    """A vertical prism z ∈ [0, height] [m] over a triangulated 2-D outline [m]."""
    mesh = trimesh.creation.extrude_triangulation(
        np.array(outline, dtype=np.float64), np.array(triangles, dtype=np.int64), height
    )
    if mesh.volume < 0:  # make the triangles face outwards whatever the outline's winding
        mesh.invert()
    return mesh


def l_building(
    long_side: float = 20.0, short_side: float = 12.0, wing: float = 6.0, height: float = 10.0
) -> trimesh.Trimesh:
    """An L-shaped building: footprint [0, long]×[0, wing] ∪ [0, wing]×[0, short] [m], z ≥ 0.

    The long wing runs along +x, the short wing along +y; the inner corner is at
    (wing, wing). All sizes [m].
    """
    if not (0 < wing < short_side and wing < long_side and height > 0):
        raise ValueError("need 0 < wing < short_side, wing < long_side and height > 0 [m]")
    a, b, c = long_side, short_side, wing
    # The L outline, with (0, c) added on the west wall so both rectangles share vertices.
    outline = [(0, 0), (a, 0), (a, c), (c, c), (c, b), (0, b), (0, c)]
    triangles = [(0, 1, 2), (0, 2, 3), (0, 3, 6), (6, 3, 4), (6, 4, 5)]
    return _prism(outline, triangles, height)


def bridge(
    span: float = 24.0, pier: float = 2.0, clearance: float = 6.0, deck: float = 1.0,
    width: float = 8.0,
) -> trimesh.Trimesh:
    """A bridge: a deck of thickness ``deck`` on two piers, one closed body [m].

    Side profile in the x-z plane: piers x ∈ [0, pier] and [span − pier, span] from z = 0 to
    ``clearance``, deck x ∈ [0, span], z ∈ [clearance, clearance + deck]; extruded along y
    over [−width/2, width/2]. The underside of the deck between the piers is open to view.
    """
    if not (0 < pier < span / 2 and clearance > 0 and deck > 0 and width > 0):
        raise ValueError("need 0 < pier < span/2 and positive clearance, deck, width [m]")
    s, p, h, t = span, pier, clearance, clearance + deck
    outline = [(0, 0), (p, 0), (p, h), (s - p, h), (s - p, 0), (s, 0), (s, h), (s, t), (0, t),
               (0, h)]
    triangles = [(0, 1, 2), (0, 2, 9),  # left pier
                 (4, 5, 6), (4, 6, 3),  # right pier
                 (8, 9, 2), (8, 2, 3), (8, 3, 6), (8, 6, 7)]  # deck
    profile = _prism(outline, triangles, width)  # (x, z_profile) extruded along +z
    # Rotate +90° about x: the profile's second axis becomes world z, extrusion becomes −y.
    turn = np.eye(4)
    turn[:3, :3] = [[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]]
    turn[1, 3] = width / 2.0
    profile.apply_transform(turn)
    return profile


def tower(
    radius: float = 3.0, height: float = 30.0, sections: int = 32, yaw: float = 0.0
) -> trimesh.Trimesh:
    """A tall cylindrical tower: axis along world z from z = 0 to ``height``, ``radius`` [m]."""
    if not (radius > 0 and height > 0 and sections >= 3):
        raise ValueError("need radius > 0, height > 0 [m] and at least 3 sections")
    transform = np.eye(4)
    transform[:3, :3] = yaw_rotation(yaw)
    transform[2, 3] = height / 2.0
    return trimesh.creation.cylinder(
        radius=radius, height=height, sections=sections, transform=transform
    )


def example_structures() -> dict[str, trimesh.Trimesh]:
    """The example structures by name, each with its default sizes [m]."""
    return {"l_building": l_building(), "bridge": bridge(), "tower": tower()}


def write_examples(folder: str | Path) -> list[Path]:
    """Write every example structure as ``<name>.stl`` into ``folder`` (created if needed)."""
    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    paths = []
    for name, mesh in example_structures().items():
        path = out / f"{name}.stl"
        mesh.export(str(path), file_type="stl")
        paths.append(path)
    return paths
