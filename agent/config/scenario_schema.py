"""The schema of a scenario file: what the TOML may contain, as msgspec Structs (unknown
fields refused). Semantic checks and the built :class:`~agent.config.scenario.Scenario` are in
:mod:`agent.config.scenario`, whose docstring documents the format."""

from __future__ import annotations

from typing import Any

import msgspec

from agent.config.inspection import CameraTable, InspectionTable
from agent.config.structure import StructureTable
from agent.core.landmarks import BOX_FACES
from agent.core.planner import PlannerParams

DEFAULT_PLANNER = PlannerParams()


class SpaceTable(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    lo: list[float]
    hi: list[float]


class PlannerTable(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    dt: float = DEFAULT_PLANNER.dt
    p_lim: float = DEFAULT_PLANNER.p_lim
    p_min: float = DEFAULT_PLANNER.p_min
    w_lim: float = float(DEFAULT_PLANNER.w_lim)
    w_min: float = float(DEFAULT_PLANNER.w_min)
    tau: float = DEFAULT_PLANNER.tau
    beta: float = DEFAULT_PLANNER.beta
    avoidance: str = DEFAULT_PLANNER.avoidance
    r_s: float = DEFAULT_PLANNER.r_s
    d_w: float = DEFAULT_PLANNER.d_w
    lambda_dir: float | None = DEFAULT_PLANNER.lambda_dir


class LandmarkTable(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    position: list[float]
    normal: list[float] | None = None
    normal_angle: float | None = None
    id: int | None = None


class PolygonTable(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    sides: int
    side: float
    center: list[float] | None = None
    phase: float = 0.0


class BoxTable(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    center: list[float]
    size: list[float] | float
    faces: list[str] = msgspec.field(default_factory=lambda: list(BOX_FACES))
    count: int | None = None
    grid: list[int] | None = None


class CylinderTable(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    center: list[float]
    radius: float
    height: float
    around: int
    rows: int = 1
    phase: float = 0.0


class AgentTable(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    id: str
    position: list[float]
    yaw: float | None = None
    pitch: float | None = None
    direction: list[float] | None = None
    landmarks: list[int] = msgspec.field(default_factory=list)


class ScenarioFile(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    dims: int
    d_opt: float
    duration: float
    agents: list[AgentTable]
    name: str | None = None
    seed: int = 0
    trading: bool = True
    space: SpaceTable | None = None
    planner: PlannerTable = msgspec.field(default_factory=PlannerTable)
    landmarks: list[LandmarkTable] = msgspec.field(default_factory=list)
    # Converted per item (by ``kind``) so that errors name the right generator fields.
    generators: list[dict[str, Any]] = msgspec.field(default_factory=list)
    structure: StructureTable | None = None
    visibility: str = "facing"
    strategy: str = "thesis"
    lost_after: float = 60.0
    inspection: InspectionTable | None = None
    camera: CameraTable | None = None


GENERATORS: dict[str, type[msgspec.Struct]] = {
    "polygon": PolygonTable,
    "box": BoxTable,
    "cylinder": CylinderTable,
}

#: Tables nested in the top level: key → (struct type, is an array of tables).
CHILDREN: dict[str, tuple[type[msgspec.Struct], bool]] = {
    "space": (SpaceTable, False),
    "planner": (PlannerTable, False),
    "landmarks": (LandmarkTable, True),
    "agents": (AgentTable, True),
    "structure": (StructureTable, False),
    "inspection": (InspectionTable, False),
    "camera": (CameraTable, False),
}


# ---------------------------------------------------------------------------------------
# The validated scenario.
# ---------------------------------------------------------------------------------------
