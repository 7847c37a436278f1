"""Inspection scenes of the benchmark: four structure types of our own (concave, tall and
thin, round, roofs), each a mesh scenario with occlusion and a camera field of view, and
seeded random starts. Positions [m; world ENU]."""

from __future__ import annotations

import dataclasses
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from agent.config.parse import parse_scenario
from agent.config.scenario import Scenario
from agent.structure.examples import example_structures
from agent.world.structure import resolve_structure, structure_model


@dataclass(frozen=True)
class Scene:
    """One structure type: mesh name, optimal distance d_opt [m], landmark spacing [m] and
    the mission space (lo, hi) [m]."""

    kind: str
    mesh: str
    d_opt: float
    spacing: float
    lo: tuple[float, float, float]
    hi: tuple[float, float, float]
    camera: bool = False  #: specified by the camera's GSD (:data:`CAMERA`), not by quality
    views: int = 1  #: with the camera: each landmark in this many images PARALLAX_DEG apart
    scale: float = 1.0  #: the mesh scaled by this (lo, hi are given already scaled)


QUALITY = 0.3
FOV_DEG = (90.0, 70.0)
MAX_INCIDENCE_DEG = 75.0
MARGIN = 1.5
R_S = 2.0
@dataclass(frozen=True)
class BenchCamera:
    """The camera of the GSD scenes: a 1-inch 20 MP sensor (width, height [mm]) behind an
    8.8 mm lens, its image [px], and the spec: GSD ≤ 2 mm/px within 60° of incidence, aimed
    10 % finer, an image a second at most."""

    sensor_mm: tuple[float, float] = (13.2, 8.8)
    focal_mm: float = 8.8
    image_px: tuple[int, int] = (5472, 3648)
    gsd_mm: float = 2.0
    max_incidence_deg: float = 60.0
    aim_margin: float = 0.1
    trigger_s: float = 1.0


CAMERA = BenchCamera()

SCENES = (
    Scene("concave", "u_building", 6.0, 2.5, (-10.0, -10.0, 0.5), (30.0, 28.0, 16.0)),
    Scene("tall_thin", "wind_turbine", 5.0, 2.0, (-10.0, -10.0, 0.5), (15.0, 10.0, 32.0)),
    Scene("round", "storage_tank", 5.0, 2.0, (-15.0, -15.0, 0.5), (15.0, 15.0, 16.0)),
    Scene("roofs", "gabled_house", 5.0, 2.0, (-9.0, -9.0, 0.5), (23.0, 17.0, 15.0)),
    # CAD-like assemblies of closed parts that overlap or touch, and an open scan.
    Scene("cad_roof", "house_parts", 5.0, 2.0, (-9.0, -9.0, 0.5), (23.0, 17.0, 15.0)),
    Scene("cad_u", "u_boxes", 6.0, 2.5, (-10.0, -10.0, 0.5), (30.0, 28.0, 16.0)),
    Scene("cad_chimney", "chimney_plant", 5.0, 2.0, (-10.0, -10.0, 0.5), (18.0, 10.0, 30.0)),
    Scene("open_scan", "scan_house", 5.0, 2.0, (-9.0, -9.0, 0.5), (23.0, 17.0, 15.0)),
    # Specified by a camera and a ground sampling distance.
    Scene("gsd_roof", "house_parts", 5.0, 2.0, (-9.0, -9.0, 0.5), (23.0, 17.0, 15.0), True),
    # And with multi-view overlap: three images 20° apart of each landmark.
    Scene("views_roof", "house_parts", 5.0, 3.0, (-9.0, -9.0, 0.5), (23.0, 17.0, 15.0), True,
          3),
)
PARALLAX_DEG = 20.0


def _mesh_folder() -> Path:
    folder = Path(tempfile.gettempdir()) / "viscover-bench-meshes"
    folder.mkdir(exist_ok=True)
    for name, mesh in example_structures().items():
        path = folder / f"{name}.stl"
        if not path.exists():
            mesh.export(str(path), file_type="stl")
    return folder


def scene_text(scene: Scene, starts: np.ndarray) -> str:
    """The scenario TOML of ``scene`` with one drone at each row of ``starts`` (n, 3) [m]."""
    mesh = _mesh_folder() / f"{scene.mesh}.stl"
    agents = "".join(
        f'\n[[agents]]\nid = "D{i}"\nposition = {[float(x) for x in p]}\n'
        f"yaw = {float(np.arctan2(-p[1], -p[0]))!r}\n" for i, p in enumerate(starts))
    scaled = f"\nscale = {scene.scale!r}" if scene.scale != 1.0 else ""
    return f"""name = "{scene.kind}"
dims = 3
seed = 0
d_opt = {scene.d_opt}
duration = 900.0
visibility = "occlusion"
[space]
lo = {list(scene.lo)}
hi = {list(scene.hi)}
[planner]
dt = 0.1
p_lim = 1.5
p_min = 0.05
avoidance = "smooth"
r_s = {R_S}
d_w = 1.0
[structure]
mesh = "{mesh}"{scaled}
spacing = {scene.spacing}
z_min = 0.5
margin = {MARGIN}
{_spec(scene)}
{agents}"""


def _spec(scene: Scene) -> str:
    """The ``[inspection]`` (and ``[camera]``) tables of ``scene``."""
    if not scene.camera:
        return (f"[inspection]\nquality = {QUALITY}\nfov_deg = {list(FOV_DEG)}\n"
                f"max_incidence_deg = {MAX_INCIDENCE_DEG}")
    c = CAMERA
    views = f"\nviews = {scene.views}\nparallax_deg = {PARALLAX_DEG}" if scene.views > 1 else ""
    return (f"[inspection]\ngsd_mm = {c.gsd_mm}\nmax_incidence_deg = {c.max_incidence_deg}"
            f"\naim_margin = {c.aim_margin}{views}\n[camera]\nsensor_mm = {list(c.sensor_mm)}\n"
            f"focal_mm = {c.focal_mm}\nimage_px = {list(c.image_px)}\n"
            f"trigger_s = {c.trigger_s}")


def recheck_gsd(scene: Scene) -> tuple[float, float, float] | None:
    """The independent GSD re-check's numbers for ``scene`` (largest GSD [mm/px], pixel
    pitch [mm], focal length [mm]) from the camera's datasheet, None without a camera."""
    if not scene.camera:
        return None
    c = CAMERA
    pitch = max(c.sensor_mm[0] / c.image_px[0], c.sensor_mm[1] / c.image_px[1])
    return c.gsd_mm, pitch, c.focal_mm


def random_starts(scene: Scene, n: int, rng: np.random.Generator) -> np.ndarray:
    """n starts (n, 3) [m] drawn uniformly in the space below 6 m, at least 2·margin from
    the structure and R_s + 0.5 m from each other."""
    base = parse_scenario(scene_text(scene, np.array([scene.lo]) + 0.01), "bench")
    model = structure_model(base.structure) if base.structure is not None else None
    lo = np.array(scene.lo)
    hi = np.array(scene.hi)
    hi[2] = min(hi[2], 6.0)
    out: list[np.ndarray] = []
    while len(out) < n:
        p = rng.uniform(lo + 0.5, hi - 0.5)
        if model is not None and float(model.distance(p[None, :])[0]) < 2.0 * MARGIN:
            continue
        if any(np.linalg.norm(p - o) < R_S + 0.5 for o in out):
            continue
        out.append(p)
    return np.array(out)


def scenario(scene: Scene, starts: np.ndarray) -> Scenario:
    """The resolved scenario (mesh landmarks sampled and given to the nearest drones)."""
    sc = resolve_structure(parse_scenario(scene_text(scene, starts), f"bench/{scene.kind}"))
    return dataclasses.replace(sc, name=scene.kind)


def scaled_scene(scene: Scene, scale: float, spacing: float) -> Scene:
    """``scene`` with its mesh and space scaled by ``scale`` (about the origin) and landmarks
    every ``spacing`` [m]: the U building at 0.8 m holds about 1,000·scale² landmarks."""
    lo = (scene.lo[0] * scale, scene.lo[1] * scale, scene.lo[2] * scale)
    hi = (scene.hi[0] * scale, scene.hi[1] * scale, scene.hi[2] * scale)
    return dataclasses.replace(scene, spacing=spacing, lo=lo, hi=hi, scale=scale)
