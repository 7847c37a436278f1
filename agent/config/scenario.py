"""A validated scenario: the landmarks, the agents' initial states and sets, the planner's
parameters, the mission space and what the mission is for (coverage, or an inspection's
:class:`~agent.core.inspection.CaptureSpec`). Pure data; read from a TOML file by
:mod:`agent.config.parse` (the format is documented there and in docs/scenarios.md).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from agent.config.structure import StructureSpec
from agent.config.validation import ScenarioError
from agent.core.avoidance import MissionSpace
from agent.core.inspection import CaptureSpec
from agent.core.planner import PlannerParams
from agent.strategy.registry import StrategyName

Array = NDArray[np.float64]

__all__ = ["AgentSpec", "Scenario", "ScenarioError"]


@dataclass(frozen=True, eq=False)
class AgentSpec:
    """One agent's initial state: position ``p0`` (3,) [m], unit camera direction ``v0`` (3,)
    and the indices (into ``Scenario.q``) of the landmarks it owns at the start."""

    id: str
    p0: Array
    v0: Array
    landmarks: NDArray[np.intp]


@dataclass(frozen=True, eq=False)
class Scenario:
    """A validated scenario. Landmarks ``q`` (m, 3) [m] with unit normals ``u`` (m, 3);
    ``landmark_ids[j]`` is the id of row j. In a planar scenario every z is 0."""

    name: str
    seed: int
    planar: bool
    d_opt: float  #: optimal distance [m], eq. 3.6
    duration: float  #: longest simulated time [s]
    q: Array
    u: Array
    landmark_ids: list[int]
    agents: list[AgentSpec]
    params: PlannerParams
    space: MissionSpace
    source: str
    trading: bool = True  #: False: pose optimisation only (section 5.2, "trade not considered")
    #: Mesh structure (landmarks sampled on it by agent.world.structure.resolve_structure).
    structure: StructureSpec | None = None
    visibility: str = "facing"  #: "facing" (eq. 3.8) or "occlusion" (and line of sight)
    strategy: StrategyName = "thesis"  #: "thesis" (chapter 5) or "potential" (coverage moves)
    lost_after: float = 60.0  #: mission seconds before an absent agent is lost (0: never)
    #: boxes (k, 2, 3) [m; world ENU] no candidate viewpoint of the coverage moves may be in
    #: (agent.world.environment.environment_of); None: the structure's bounding box. Not read
    #: from a file: set by callers that know the structure's shape (the quality benchmark).
    keepout: NDArray[np.float64] | None = None
    #: What counts as a capture in an inspection mission (``[inspection]``); None: coverage.
    inspection: CaptureSpec | None = None
    #: With ``inspection.views`` = k > 1, once resolved (agent.world.views.expand_views): the
    #: rows are *view landmarks*, k per landmark (landmark id i → view ids i·k + s, s < k,
    #: same q and u, same owner), each captured only from inside its view sector:
    #: ``view_axis`` (m, 3) the sectors' unit axes, ``view_of`` (m,) the landmark id each
    #: view belongs to, ``view_cos`` the cosine of the sectors' half-angle (agent.core.views).
    #: None: one view per landmark (or not yet expanded).
    view_axis: NDArray[np.float64] | None = None
    view_of: NDArray[np.int64] | None = None
    view_cos: float | None = None

    @property
    def dims(self) -> int:
        """2 for the planar mode of chapter 5, else 3."""
        return 2 if self.planar else 3

    @property
    def views(self) -> int:
        """Images per landmark of an inspection (1 without ``inspection.views``)."""
        return 1 if self.inspection is None else self.inspection.views

    def view_axes(self, rows: NDArray[np.intp]) -> NDArray[np.float64] | None:
        """The view-sector axes of landmark ``rows`` (None: no view sectors)."""
        return None if self.view_axis is None else self.view_axis[rows]

    def initial_sets(self) -> dict[str, list[int]]:
        """Each agent's landmark ids at the start."""
        ids = np.asarray(self.landmark_ids, dtype=np.int64)
        return {a.id: ids[a.landmarks].tolist() for a in self.agents}

    def with_seed(self, seed: int) -> Scenario:
        """A copy with another seed (the CLI's ``--seed``)."""
        return dataclasses.replace(self, seed=int(seed))

    def summary(self) -> str:
        """One line: name, dims, landmark and agent counts, bounded or not."""
        bounded = "bounded" if np.isfinite(self.space.lo).any() or np.isfinite(
            self.space.hi).any() else "unbounded"
        agents = ", ".join(f"{a.id}:{a.landmarks.size}" for a in self.agents)
        n = len(self.agents)
        st = self.structure
        mesh = "" if st is None else (
            f", structure {st.mesh.name} (landmarks every {st.spacing:g} m), visibility "
            f"{self.visibility}" if st.sampled else f", plus landmarks every {st.spacing:g} m "
            f"on structure {st.mesh.name} (sampled at start), visibility {self.visibility}")
        m, k = self.q.shape[0], self.views
        count = f"{m} landmarks" if k == 1 else (
            f"{m} view landmarks ({m // k} landmark{'s' if m != k else ''} x {k} views)"
            if self.view_of is not None
            else f"{m} landmarks (each to be captured in {k} views)")
        return (
            f"{self.name}: {self.dims}-D, {count}, "
            f"{n} agent{'s' if n != 1 else ''} ({agents}), {bounded}, "
            f"avoidance {self.params.avoidance}, d_opt {self.d_opt:g} m, "
            f"duration {self.duration:g} s{mesh}"
        )
