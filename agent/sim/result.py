"""What a simulation run produces: trajectories, visions, coverage and trades."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from agent.core.vision import per_landmark
from agent.protocol.inspection_end import InspectionEnd, captured_line, end_line

Array = NDArray[np.float64]


def completion_index(times: ArrayLike, t_complete: float | None) -> int:
    """The sample of mission times ``times`` [s] (ascending) at which the mission completed:
    the first at or after ``t_complete`` (the last if it did not complete: None). A recorded
    flight goes on after it: the drones fly home and land, their cameras off their landmarks."""
    t = np.asarray(times, dtype=np.float64)
    last = t.size - 1
    if t_complete is None or last < 0:
        return last
    return min(int(np.searchsorted(t, t_complete - 1e-9)), last)


@dataclass(frozen=True)
class TradeEvent:
    """One successful trade (Algorithm 7) at simulated time ``t`` [s]."""

    t: float
    initiator: str
    partner: str
    to_partner: list[int]  #: landmark ids moved initiator → partner
    to_initiator: list[int]  #: landmark ids moved partner → initiator
    gain: float  #: increase of the coverage score (eq. 3.10)


@dataclass(frozen=True)
class CaptureEvent:
    """Landmarks first captured by one camera at simulated time ``t`` [s]: their ids, the
    camera's ``position`` [m; world ENU], unit ``direction`` (optical axis) and unit
    ``right`` (the image's x axis, horizontal: with the direction it fixes the camera's
    orientation, also when it looks straight down), and each one's quality (eq. 3.1)."""

    t: float
    agent: str
    landmarks: list[int]
    position: list[float]
    direction: list[float]
    right: list[float]
    quality: list[float]


@dataclass(frozen=True)
class InspectionSummary:
    """How an inspection ended: the least quality of a capture, the ids captured, how many
    were capturable, each uncapturable landmark's id with the reason, and each capturable
    landmark not captured with why it was given up (:mod:`agent.protocol.inspection_end`;
    empty: every capturable landmark captured)."""

    quality: float
    captured: list[int]
    capturable: int
    uncapturable: dict[int, str]
    spec: str = ""  #: the spec in words (CaptureSpec.describe); "quality >= q" when empty
    given_up: dict[int, str] = field(default_factory=dict)  #: id -> reason, ids ascending
    #: The spec's numbers for the resolution report (agent.sim.resolution.spec_numbers):
    #: threshold, and with a camera pixel_angle [rad/px], gsd_limit_mm, gsd_aim_mm, ...
    numbers: dict[str, float] = field(default_factory=dict)
    parts: list[int] | None = None  #: each landmark's part of the structure's mesh

    @property
    def complete(self) -> bool:
        """Every capturable landmark captured."""
        return not self.given_up

    def line(self) -> str:
        """``captured N/M at <spec>; K uncapturable (reasons)``."""
        return captured_line(len(self.captured), self.capturable,
                             self.spec or f"quality >= {self.quality:g}", self.uncapturable)

    def end(self, t_complete: float | None) -> InspectionEnd:
        """The end (complete at ``t_complete`` [s], or what was given up)."""
        return InspectionEnd(dict(self.given_up), None if self.given_up else t_complete)

    def end_line(self, t_complete: float | None) -> str:
        """:meth:`line`, then ``complete at t = X s`` or ``INCOMPLETE: G given up (...)``."""
        return end_line(self.line(), self.end(t_complete))


@dataclass
class SimResult:
    """A whole run. Index order: time k, agent i, landmark j. Units: s, m, rad."""

    scenario: str
    seed: int
    planar: bool
    agent_ids: list[str]
    landmark_ids: list[int]
    q: Array  #: landmark positions (m, 3) [m; world ENU]
    u: Array  #: landmark normals (m, 3)
    space_lo: Array  #: mission space lower corner (3,) [m] (may be -inf)
    space_hi: Array  #: mission space upper corner (3,) [m] (may be +inf)
    d_opt: float
    times: Array  #: (T,) [s]
    positions: Array  #: (T, n, 3) [m]
    directions: Array  #: (T, n, 3) unit camera directions
    vision: Array  #: (T, n) per-agent vision over its own set
    coverage: Array  #: (T,) coverage score, eq. 3.10
    owners: Array  #: (T, m) owning agent index per landmark
    trades: list[TradeEvent] = field(default_factory=list)
    complete: bool = False  #: all agents converged and every partner list empty
    t_complete: float | None = None
    visibility: str = "facing"  #: the scenario's visibility model ("facing" | "occlusion")
    #: (T, 2) coverage under the facing and the occlusion model; None without a structure
    coverage_by_model: Array | None = None
    strategy: str = "thesis"  #: the scenario's strategy (agent.strategy.registry)
    captures: list[CaptureEvent] = field(default_factory=list)  #: inspection missions only
    inspection: InspectionSummary | None = None  #: None: a coverage mission
    #: The time axis (``times``) is mission time τ [s]. A recording's agents each had a
    #: mission clock: agent a's time t is τ = t − clock_offsets[a] [s] (simulator: 0), and a
    #: wall time w [s since the epoch] is τ = time_scale · (w − wall_origin); wall_origin is
    #: None for a simulation (no wall clock: τ is simulated time from its start).
    clock_offsets: dict[str, float] = field(default_factory=dict)
    time_scale: float = 1.0  #: [mission s / wall s]
    wall_origin: float | None = None  #: [s since the epoch]

    def tau_of_wall(self, wall: Array) -> Array:
        """Wall times [s since the epoch] on the mission time axis τ [s] (NaN without a wall
        clock: a simulation)."""
        w = np.asarray(wall, dtype=np.float64)
        if self.wall_origin is None:
            return np.full(w.shape, np.nan)
        return self.time_scale * (w - self.wall_origin)

    @property
    def final_owner(self) -> NDArray[np.intp]:
        """Owning agent index of each landmark at the end."""
        return np.asarray(self.owners[-1], dtype=np.intp)

    def seen_by_owner(self) -> NDArray[np.bool_]:
        """Eq. 3.1 at the poses of completion (:meth:`completion_index`; the final ones if
        it did not complete): True where a landmark's owner sees it (vision > 0, facing
        model), shape (m,)."""
        seen = np.zeros(len(self.landmark_ids), dtype=bool)
        if not len(self.times):
            return seen
        owner, k = self.final_owner, self.completion_index()
        for i in range(len(self.agent_ids)):  # agents, not landmarks: vectorised per agent
            mine = np.flatnonzero(owner == i)
            if mine.size:
                seen[mine] = per_landmark(self.positions[k, i], self.directions[k, i],
                                          self.q[mine], self.u[mine], self.d_opt) > 0.0
        return seen

    def quality_line(self) -> str:
        """One line: landmarks seen / unseen by their owner at completion (eq. 3.1 > 0)."""
        seen = self.seen_by_owner()
        unseen = np.asarray(self.landmark_ids)[~seen]
        line = f"{int(seen.sum())}/{seen.size} landmarks seen by their owner"
        if unseen.size:
            shown = ", ".join(str(int(j)) for j in unseen[:12])
            more = f", ... ({unseen.size} in all)" if unseen.size > 12 else ""
            line += f"; UNSEEN: {shown}{more}"
        return line

    def completion_index(self) -> int:
        """The sample at which the mission completed (:func:`completion_index`)."""
        return completion_index(self.times, self.t_complete if self.complete else None)

    def coverage_line(self) -> str:
        """One line: coverage (eq. 3.10) at start → completion under the scenario's visibility
        model (and at the end of the run when it went on and differs: a flight home), and for
        structure runs under both models, e.g. for ``viscover simulate``'s summary."""
        if not len(self.coverage):
            return "coverage: no samples"
        k, cov = self.completion_index(), self.coverage
        line = f"coverage {float(cov[0]):.4g} -> {float(cov[k]):.4g} ({self.visibility})"
        if k < len(cov) - 1 and abs(float(cov[-1]) - float(cov[k])) > 1e-9:
            line += (f" at completion, t = {float(self.times[k]):g} s; "
                     f"{float(cov[-1]):.4g} at the end, t = {float(self.times[-1]):g} s")
        by = self.coverage_by_model
        if by is not None and len(by):
            line += "; " + ", ".join(f"{name} {float(by[0, j]):.4g} -> {float(by[k, j]):.4g}"
                                     for j, name in enumerate(("facing", "occlusion")))
        return line
