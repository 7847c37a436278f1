"""Example structures built from trimesh primitives: closed (watertight) bodies, and
assemblies of closed parts that touch or overlap as CAD exports give them.

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
    mesh: trimesh.Trimesh = trimesh.creation.cylinder(
        radius=radius, height=height, sections=sections, transform=transform)
    return mesh


def gabled_house(length: float = 14.0, width: float = 8.0, eaves: float = 5.0,
                 ridge: float = 8.0) -> trimesh.Trimesh:
    """A house with a gabled roof: walls [0, length]×[0, width] up to ``eaves``, two roof
    planes meeting at a ridge along x at height ``ridge`` over y = width/2 [m]."""
    if not (length > 0 and width > 0 and 0 < eaves < ridge):
        raise ValueError("need positive length and width and 0 < eaves < ridge [m]")
    w = width
    outline = [(0.0, 0.0), (w, 0.0), (w, eaves), (w / 2.0, ridge), (0.0, eaves)]
    gable = _prism(outline, [(0, 1, 2), (0, 2, 4), (4, 2, 3)], length)  # (y, z) along +z
    turn = np.eye(4)  # profile axes (y, z), extrusion along world x
    turn[:3, :3] = [[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]
    gable.apply_transform(turn)
    return gable


def u_building(width: float = 20.0, depth: float = 16.0, wing: float = 6.0,
               height: float = 9.0) -> trimesh.Trimesh:
    """A U-shaped building round a courtyard open to +y: footprint [0, width]×[0, depth]
    less the courtyard [wing, width − wing]×[wing, depth] [m], ``height`` tall."""
    if not (0 < 2 * wing < width and 0 < wing < depth and height > 0):
        raise ValueError("need 0 < 2·wing < width, wing < depth and height > 0 [m]")
    a, b, c = width, depth, wing
    outline = [(0, 0), (a, 0), (a, b), (a - c, b), (a - c, c), (c, c), (c, b), (0, b)]
    triangles = [(0, 1, 4), (0, 4, 5), (1, 2, 3), (1, 3, 4), (0, 5, 6), (0, 6, 7)]
    return _prism(outline, triangles, height)


def storage_tank(radius: float = 6.0, wall: float = 8.0, roof: float = 2.5,
                 sections: int = 40) -> trimesh.Trimesh:
    """A round storage tank: a cylinder of ``radius`` up to ``wall`` with a conical roof
    rising ``roof`` more to its apex, axis along world z from z = 0 [m]."""
    if not (radius > 0 and wall > 0 and roof >= 0 and sections >= 3):
        raise ValueError("need positive radius and wall, roof ≥ 0 [m], ≥ 3 sections")
    profile = np.array([[0.0, 0.0], [radius, 0.0], [radius, wall], [0.0, wall + roof]])
    return trimesh.creation.revolve(profile, sections=sections)


def wind_turbine(radius: float = 1.5, height: float = 24.0, nacelle: tuple[float, float, float]
                 = (6.0, 3.0, 3.0)) -> trimesh.Trimesh:
    """A wind-turbine tower with its nacelle: a cylinder of ``radius`` from z = 0 to
    ``height`` and a box (length along x, width, height) [m] on its top, reaching 1 m
    beyond the axis to −x. Two closed bodies that overlap: the top of the tower is inside
    the nacelle (faces no camera can see)."""
    if not (radius > 0 and height > 0 and min(nacelle) > 0):
        raise ValueError("need positive radius, height and nacelle sizes [m]")
    mast = tower(radius, height, sections=24)
    lx, ly, lz = nacelle
    box = trimesh.creation.box(extents=(lx, ly, lz))
    box.apply_translation((lx / 2.0 - 1.0, 0.0, height - lz / 2.0 + 1.0))
    both = trimesh.util.concatenate([mast, box])
    assert isinstance(both, trimesh.Trimesh)
    return both


def box(lo: tuple[float, float, float], hi: tuple[float, float, float]) -> trimesh.Trimesh:
    """A closed axis-aligned box from corner lo to corner hi [m]."""
    a, b = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
    out: trimesh.Trimesh = trimesh.creation.box(extents=b - a)
    out.apply_translation((a + b) / 2.0)
    return out


def _assembly(parts: list[trimesh.Trimesh]) -> trimesh.Trimesh:
    """Closed parts side by side in one mesh, as a CAD export of an assembly writes them
    (touching or overlapping, never merged)."""
    both = trimesh.util.concatenate(parts)
    assert isinstance(both, trimesh.Trimesh)
    return both


def house_parts(length: float = 14.0, width: float = 8.0, eaves: float = 5.0,
                ridge: float = 8.0, overhang: float = 0.5, seat: float = 0.4) -> trimesh.Trimesh:
    """A house as a CAD export gives it: a closed body [0, length]×[0, width]×[0, eaves] and
    a closed roof prism set ``seat`` into it, overhanging the walls by ``overhang`` [m]. The
    body's top and the roof's underside above the body lie inside the other part."""
    if not (length > 0 and width > 0 and 0 < seat < eaves < ridge and overhang >= 0):
        raise ValueError("need positive length and width, 0 < seat < eaves < ridge [m]")
    body = box((0.0, 0.0, 0.0), (length, width, eaves))
    o, w, z0 = overhang, width, eaves - seat
    outline = [(-o, z0), (w + o, z0), (w / 2.0, ridge)]
    roof = _prism(outline, [(0, 1, 2)], length + 2.0 * o)  # (y, z) along +z
    turn = np.eye(4)  # profile axes (y, z), extrusion along world x from −o
    turn[:3, :3] = [[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]
    turn[0, 3] = -o
    roof.apply_transform(turn)
    return _assembly([body, roof])


def u_boxes(width: float = 20.0, depth: float = 16.0, wing: float = 6.0,
            height: float = 9.0, overlap: float = 1.0) -> trimesh.Trimesh:
    """A U building round a courtyard open to +y made of three overlapping closed boxes: a
    front block [0, width]×[0, wing] and two wings [0, wing]×[wing − overlap, depth] and
    [width − wing, width]×[wing − overlap, depth], ``height`` tall [m]."""
    if not (0 < 2 * wing < width and 0 < overlap < wing < depth and height > 0):
        raise ValueError("need 0 < 2·wing < width, 0 < overlap < wing < depth, height > 0")
    return _assembly([box((0.0, 0.0, 0.0), (width, wing, height)),
                      box((0.0, wing - overlap, 0.0), (wing, depth, height)),
                      box((width - wing, wing - overlap, 0.0), (width, depth, height))])


def chimney_plant(radius: float = 1.5, height: float = 24.0, platform: float = 3.0,
                  at: float = 16.0, house: tuple[float, float, float] = (8.0, 6.0, 6.0)
                  ) -> trimesh.Trimesh:
    """A chimney with a service platform and a boiler house, three closed parts: a shaft of
    ``radius`` up to ``height``, a platform disc of ``platform`` radius and 0.4 m thick at
    height ``at`` round it (the shaft passes through it), and a box (length along x, width,
    height) [m] set 0.5 m into the shaft's side towards +x."""
    if not (0 < radius < platform and 0 < at < height and min(house) > 0):
        raise ValueError("need 0 < radius < platform, 0 < at < height, positive house [m]")
    shaft = tower(radius, height, sections=24)
    disc = tower(platform, 0.4, sections=24)
    disc.apply_translation((0.0, 0.0, at))
    lx, ly, lz = house
    x0 = radius - 0.5
    return _assembly([shaft, disc, box((x0, -ly / 2.0, 0.0), (x0 + lx, ly / 2.0, lz))])


def scan_house(seed: int = 0) -> trimesh.Trimesh:
    """:func:`house_parts` as a scan gives it: open (the body has no floor: it was never
    seen), one soup of triangles with a third of them wound the wrong way (seeded)."""
    house = house_parts()
    floor = np.flatnonzero(house.face_normals[:12, 2] < -0.5)  # the body's two floor ones
    keep = np.setdiff1d(np.arange(len(house.faces)), floor)
    tri = np.asarray(house.triangles)[keep].copy()
    flip = np.random.default_rng(seed).random(tri.shape[0]) < 1.0 / 3.0
    tri[flip] = tri[flip][:, ::-1]
    return trimesh.Trimesh(vertices=tri.reshape(-1, 3),
                           faces=np.arange(tri.shape[0] * 3).reshape(-1, 3), process=False)


def example_structures() -> dict[str, trimesh.Trimesh]:
    """The example structures by name, each with its default sizes [m]."""
    return {"l_building": l_building(), "bridge": bridge(), "tower": tower(),
            "gabled_house": gabled_house(), "u_building": u_building(),
            "storage_tank": storage_tank(), "wind_turbine": wind_turbine(),
            "house_parts": house_parts(), "u_boxes": u_boxes(),
            "chimney_plant": chimney_plant(), "scan_house": scan_house()}


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
