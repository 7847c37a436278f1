"""Inspection missions in the kinematic simulator: every drone's decisions are those of
:mod:`agent.strategy.inspection`, taken in virtual time.

Before take-off the capture table is built (:func:`agent.structure.inspection.capture_table`:
candidate viewpoints, what each captures, which landmarks no pose can capture and why). Then
every tick of Δt, for each drone in team order (seeing the others' latest positions):

1. it acts: flies one Δt towards its goal viewpoint (the transit of the coverage moves:
   straight at ≤ ṗ_lim with section-4.3 avoidance of walls, drones and the structure, the
   camera turned at ≤ ω_lim), or settles (planner steps of eq. 3.8 over the landmarks the
   viewpoint was chosen for and that are still uncaptured), or flies home;
2. its camera captures, at this control step, every uncaptured landmark it images at the
   scenario's quality (field of view, incidence and, under occlusion, a fresh line of sight);
   the captured set grows by union (:class:`~agent.protocol.captures.CapturedSet`) and in
   this one process every drone hears it at once;
3. with no goal left it decides (:func:`~agent.strategy.inspection.next_action`): the next
   viewpoint of a fresh tour over its remaining set, or a re-split with the peer whose tour
   is longest (ownership moves as in a trade), or home.

At the start every pair of drones, in team order, tries one re-split
(:func:`~agent.strategy.inspection.split_pair`), so that initial sets far from their owner's
start are handed to a closer drone. A viewpoint a drone cannot reach (stalled transit) or
that captured less than planned after settling is blocked for that drone until its next tour
comes up empty; then it tries them all again, at most
:data:`~agent.strategy.inspection.MAX_RETRIES` times, and gives up what is left
(:func:`~agent.strategy.inspection.give_up_codes`: ``blocked`` where it reached a viewpoint,
else ``unreachable``), as the agents do. The mission is complete when every capturable
landmark is captured; it stops when it is, or when every drone is home (done), or at the
scenario's duration; :meth:`InspectionSim.summary` then names every capturable landmark not
captured with why it was given up (:mod:`agent.protocol.inspection_end`).
Deterministic: no randomness.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from agent.core.inspection import (
    REASONS,
    CaptureSpec,
    CaptureTable,
    camera_axes,
    capture_quality,
    uncapturable_line,
)
from agent.core.orientation import turn_towards
from agent.core.planner import integrate, plan_step
from agent.core.vision import Landmarks, per_landmark
from agent.protocol.captures import CapturedSet
from agent.protocol.inspection_end import inspection_end, merge_given_up
from agent.sim.resolution import scenario_parts, spec_numbers
from agent.sim.result import CaptureEvent, InspectionSummary, TradeEvent
from agent.strategy.inspection import (
    FlyTo,
    GoHome,
    PeerWork,
    TakeWork,
    Tour,
    advance_tour,
    give_up_codes,
    gives_up,
    initial_resplits,
    next_action,
    out_of_work,
    plan_tour,
    remaining,
    settle_set,
)
from agent.structure.routes import RouteGrid
from agent.structure.sight_lines import sight_lines
from agent.world.environment import TransitProgress, initial_owner, transit_displacement
from agent.world.structure import structure_inputs, structure_model
from agent.world.tables import mission_tables

if TYPE_CHECKING:
    from agent.config.scenario import Scenario

Array = NDArray[np.float64]
Mask = NDArray[np.bool_]
_log = logging.getLogger(f"viscover.{__name__}")

#: Longest settle at a viewpoint [ticks].
SETTLE_TICKS = 50


@dataclass
class _Drone:
    """Mutable state of one simulated inspection drone."""

    id: str
    p: Array
    v: Array
    home: Array
    blocked: Mask
    reached: Mask  #: viewpoints (K,) it arrived at without capturing all they were for
    tour: Tour
    mode: str = "work"  #: "work", "settle", "home" or "done"
    goal: int | None = None
    route: Array = field(default_factory=lambda: np.zeros((0, 3)))  #: waypoints to the goal
    progress: TransitProgress = field(default_factory=TransitProgress)  #: the flight so far
    settle_ticks: int = 0
    stale: bool = True  #: set or blocked viewpoints changed since the tour was planned
    distance: float = 0.0  #: flown so far [m]
    prev_dir: Array = field(default_factory=lambda: np.zeros(3))
    last_image: float | None = None  #: when its camera last took an image [s]
    retries: int = 0  #: times every viewpoint left was blocked and all were tried again


class InspectionSim:
    """Step-by-step inspection of one scenario (with ``[inspection]``, structure resolved)."""

    def __init__(self, scenario: Scenario, table: CaptureTable | None = None,
                 grid: RouteGrid | None = None) -> None:
        """``table`` and ``grid`` (from :func:`mission_tables`) may be passed in when several
        runs share the scenario's landmarks, space and structure."""
        assert scenario.inspection is not None, "not an inspection mission"
        self.sc = sc = scenario
        self.spec: CaptureSpec = scenario.inspection
        self.model = None if sc.structure is None else structure_model(sc.structure)
        self.occlusion = sc.visibility == "occlusion"
        if table is None:
            table, grid = mission_tables(sc)
        self.table, self.grid = table, grid
        if line := uncapturable_line(table.reason, np.asarray(sc.landmark_ids)):
            _log.warning("%s: %s", sc.name, line)  # before take-off, as the agents say it
        self.inputs = [structure_inputs(sc, occlusion=False) for _ in sc.agents]
        self.ids = np.asarray(sc.landmark_ids, dtype=np.int64)
        self.captured = CapturedSet()
        self.cap = np.zeros(self.ids.size, dtype=np.bool_)
        #: the landmarks given up, by reason code (0: not given up; the team's: every drone
        #: hears it at once here)
        self.given_up = np.zeros(self.ids.size, dtype=np.int8)
        self.owner = initial_owner(sc)
        self.t = 0.0
        self.captures: list[CaptureEvent] = []
        self.trades: list[TradeEvent] = []
        K = self.table.P.shape[0]
        self.drones = [
            _Drone(a.id, a.p0.astype(np.float64).copy(), a.v0.astype(np.float64).copy(),
                   a.p0.astype(np.float64).copy(), np.zeros(K, dtype=np.bool_),
                   np.zeros(K, dtype=np.bool_),
                   Tour(np.zeros(0, dtype=np.intp), np.full(self.ids.size, -1, np.intp), 0.0))
            for a in sc.agents
        ]
        self.t_complete: float | None = None
        for i in range(len(self.drones)):
            self._capture(i)
        self._initial_splits()
        for i in range(len(self.drones)):
            self._replan(i)

    # -- what a drone knows ----------------------------------------------------------------
    def _need(self, i: int) -> Mask:
        return remaining(self.owner == i, self.cap, self.table) & ~out_of_work(self.given_up)

    def _replan(self, i: int) -> None:
        d = self.drones[i]
        d.stale = False
        need = self._need(i)
        d.tour = plan_tour(d.p, need, self.table, d.blocked)
        if d.tour.empty and need.any() and d.blocked.any():  # everything left was blocked
            d.retries += 1
            if gives_up(d.retries):
                codes = give_up_codes(need, d.reached, self.table)
                self.given_up = merge_given_up(self.given_up, codes)
                _log.warning("%s: drone %s gives up %d landmarks it could not capture: %s",
                             self.sc.name, d.id, int(need.sum()), self.ids[need][:10].tolist())
                d.tour = plan_tour(d.p, self._need(i), self.table)  # nothing: it goes on
                return
            d.blocked[:] = False
            d.tour = plan_tour(d.p, need, self.table)

    def _others(self, i: int) -> Array:
        return np.array([d.p for j, d in enumerate(self.drones) if j != i]).reshape(-1, 3)

    def _peers(self, i: int) -> list[PeerWork]:
        out = out_of_work(self.given_up)
        return [PeerWork(d.id, d.p, (self.owner == j) & ~out, d.tour.length)
                for j, d in enumerate(self.drones) if j != i and d.mode in ("work", "settle")]

    # -- decisions -------------------------------------------------------------------------
    def _initial_splits(self) -> None:
        """The strategy's initial re-splits from the start (every pair once, in team order),
        the same pure function the agents compute."""
        P0 = np.array([d.p for d in self.drones])
        _, splits = initial_resplits(P0, self.owner, self.cap, self.table)
        for x in splits:
            self._apply_split(x.a, x.b, x.mine, x.theirs)

    def _apply_split(self, i: int, j: int, mine: Mask, theirs: Mask) -> None:
        """Drone i now owns ``mine`` and j ``theirs`` (their remaining sets), as a trade."""
        before_i, before_j = self.owner == i, self.owner == j
        self.owner[mine] = i
        self.owner[theirs] = j
        gave = before_i & (self.owner == j)
        took = before_j & (self.owner == i)
        self.trades.append(TradeEvent(
            t=round(self.t, 9), initiator=self.drones[i].id, partner=self.drones[j].id,
            to_partner=self.ids[gave].tolist(), to_initiator=self.ids[took].tolist(), gain=0.0))
        for k in (i, j):
            self.drones[k].goal = None
            self.drones[k].stale = True
            if self.drones[k].mode == "settle":
                self.drones[k].mode = "work"

    def _decide(self, i: int) -> None:
        d = self.drones[i]
        if d.stale:
            self._replan(i)
        else:
            d.tour = advance_tour(d.p, d.tour, self.cap, self.table)
            if d.tour.empty and self._need(i).any():  # e.g. only blocked rows were left
                self._replan(i)
        act = next_action(d.p, d.tour, self._need(i), self._peers(i), self.cap, self.table)
        if isinstance(act, FlyTo):
            self._head_for(i, act.row)
        elif isinstance(act, TakeWork):
            j = next(k for k, x in enumerate(self.drones) if x.id == act.peer)
            self._apply_split(i, j, act.mine, act.theirs)
            self._replan(i)
            self._replan(j)
            if not d.tour.empty:
                self._head_for(i, int(d.tour.rows[0]))
        elif isinstance(act, GoHome):
            d.mode, d.goal, d.progress = "home", None, TransitProgress()

    def _head_for(self, i: int, row: int) -> None:
        """Drone i's new goal: capture-table row ``row``, by a route around the structure."""
        d = self.drones[i]
        goal = self.table.P[row]
        d.goal, d.progress = row, TransitProgress()
        d.route = goal[None, :].copy() if self.grid is None else self.grid.route(d.p, goal)

    # -- dynamics --------------------------------------------------------------------------
    def _fly(self, i: int, p_goal: Array, v_goal: Array | None) -> bool:
        """One Δt towards (p_goal, v_goal); True on arrival. Counts stalls."""
        d, prm = self.drones[i], self.sc.params
        step = transit_displacement(d.p, p_goal, prm, self.sc.space, self._others(i),
                                    self.inputs[i])
        d.p = self.sc.space.clip(d.p + step)
        d.distance += float(np.linalg.norm(step))
        if v_goal is not None:
            d.v = turn_towards(d.v, v_goal, prm.w_lim * prm.dt)
        dist = float(np.linalg.norm(p_goal - d.p))
        left = 0.0 if v_goal is None else float(np.arccos(np.clip(d.v @ v_goal, -1.0, 1.0)))
        d.progress.update(dist, left)
        aligned = v_goal is None or float(d.v @ v_goal) > 1.0 - 1e-9
        return dist < 1e-6 and aligned

    def _settle(self, i: int) -> None:
        d = self.drones[i]
        assert d.goal is not None
        want = settle_set(d.goal, d.tour.credit, self.cap)
        if not want.any():
            d.mode, d.goal = "work", None
            return
        lm = Landmarks.of(self.sc.q[want], self.sc.u[want])
        step = plan_step(d.p, d.v, lm, None, self.sc.d_opt, self.sc.params, self.sc.space,
                         self._others(i), d.prev_dir,
                         **self.inputs[i].planner_inputs(d.p, lm))
        d.settle_ticks += 1
        if step.converged or d.settle_ticks > SETTLE_TICKS:
            d.blocked[d.goal] = d.reached[d.goal] = True
            d.mode, d.goal, d.prev_dir, d.stale = "work", None, np.zeros(3), True
            return
        p, d.v = integrate(d.p, d.v, step.p_dot, step.omega, self.sc.params.dt)
        p = self.sc.space.clip(p)
        d.distance += float(np.linalg.norm(p - d.p))
        d.p, d.prev_dir = p, step.p_dir

    def _capture(self, i: int) -> None:
        """Capture, at drone i's pose, every uncaptured landmark it images well enough."""
        d = self.drones[i]
        rows = np.flatnonzero(~self.cap)
        if rows.size == 0:
            return
        if self.spec.camera is not None and not self.spec.camera.ready(self.t, d.last_image):
            return  # the camera is not ready for its next image (trigger interval)
        qual = capture_quality(d.p[None, :], d.v[None, :], self.sc.q[rows], self.sc.u[rows],
                               self.sc.d_opt, self.spec, self.sc.view_axes(rows),
                               self.sc.view_cos)[0]
        good = np.flatnonzero(qual >= self.spec.threshold)
        if good.size and self.occlusion:
            clear = sight_lines(self.model, d.p[None, :], self.sc.q, self.sc.u,
                                (np.zeros(good.size, dtype=np.intp), rows[good]))
            good = good[clear]
        if good.size == 0:
            return
        new = rows[good]
        d.last_image = self.t
        self.cap[new] = True
        self.captured.merge(self.ids[new].tolist())
        self.captures.append(CaptureEvent(
            t=round(self.t, 9), agent=d.id, landmarks=self.ids[new].tolist(),
            position=d.p.tolist(), direction=d.v.tolist(),
            right=camera_axes(d.v[None, :])[0][0].tolist(), quality=qual[good].tolist()))

    def _act(self, i: int) -> None:
        d = self.drones[i]
        if d.mode == "home":
            if self._fly(i, d.home, None) or d.progress.stalled:
                d.mode = "done"
            return
        if d.mode == "settle":
            self._settle(i)
            return
        if d.goal is not None and not settle_set(d.goal, d.tour.credit, self.cap).any():
            d.goal = None  # captured meanwhile (by itself or a peer)
        if d.goal is None:
            self._decide(i)
        if d.goal is None:
            return
        goal = d.goal
        if d.route.shape[0] > 1:  # a waypoint on the way: turn towards the goal's view already
            if self._fly(i, d.route[0], self.table.V[goal]):
                d.route = d.route[1:]  # the next point: closer than ever again, stalls kept
                d.progress = TransitProgress(stall=d.progress.stall)
            elif d.progress.stalled:
                d.blocked[goal] = True
                d.goal = None
            return
        if self._fly(i, self.table.P[goal], self.table.V[goal]):
            self._capture(i)
            if settle_set(goal, d.tour.credit, self.cap).any():
                d.mode, d.settle_ticks, d.prev_dir = "settle", 0, np.zeros(3)
            else:
                d.goal = None
        elif d.progress.stalled:
            d.blocked[goal] = True
            d.goal, d.stale = None, True

    def tick(self) -> None:
        """Advance every drone by one Δt."""
        self.t += self.sc.params.dt
        for i, d in enumerate(self.drones):
            if d.mode != "done":
                self._act(i)
                self._capture(i)
        if self.t_complete is None and self.complete:
            self.t_complete = self.t

    # -- observation -----------------------------------------------------------------------
    @property
    def complete(self) -> bool:
        """Every capturable landmark captured."""
        return bool((self.cap | ~self.table.capturable).all())

    @property
    def done(self) -> bool:
        """Complete, or every drone has stopped (home or done: what it did not capture it
        gave up, or a peer still works on)."""
        return self.complete or all(d.mode in ("home", "done") for d in self.drones)

    def positions(self) -> Array:
        """Positions (n, 3) [m; world ENU]."""
        return np.array([d.p for d in self.drones])

    def directions(self) -> Array:
        """Camera directions (n, 3), unit."""
        return np.array([d.v for d in self.drones])

    def visions(self) -> Array:
        """Per-drone vision (eq. 3.4, facing model) of its own uncaptured set (n,)."""
        left = ~self.cap
        return np.array([per_landmark(d.p, d.v, self.sc.q[(self.owner == i) & left],
                                      self.sc.u[(self.owner == i) & left],
                                      self.sc.d_opt).sum() for i, d in enumerate(self.drones)])

    def coverage_by_model(self) -> tuple[float, float] | None:
        """Not recorded for inspections."""
        return None

    def distances(self) -> Array:
        """Distance flown by each drone so far (n,) [m]."""
        return np.array([d.distance for d in self.drones])

    def summary(self) -> InspectionSummary:
        """What was captured, the uncapturable landmarks with their reasons, and how the
        mission ended so far (:func:`~agent.protocol.inspection_end.inspection_end`; called
        when the run stopped: the team done, or the time out)."""
        reason = self.table.reason
        left = np.flatnonzero((reason != 0) & ~self.cap)  # one captured after all counts
        end = inspection_end(self.ids, self.table.capturable, self.cap, self.given_up,
                             self.t_complete)
        return InspectionSummary(
            quality=self.spec.quality, spec=self.spec.describe(), captured=self.captured.ids(),
            capturable=int(self.ids.size - left.size),
            uncapturable={int(self.ids[j]): REASONS[int(reason[j])] for j in left},
            given_up=end.given_up, numbers=spec_numbers(self.spec),
            parts=scenario_parts(self.sc))
