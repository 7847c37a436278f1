"""One agent's part of an inspection mission (a scenario with ``[inspection]``): its captures,
the team's captured set as it hears it, and the motion the inspection strategy decides.

Every tick while the agent works (:meth:`Inspecting.step`, called by
:class:`~agent.runtime.moves.planning.Planning` in place of the planner step):

1. its camera captures every landmark not yet captured that it images at the scenario's
   quality (:func:`~agent.core.inspection.capture_quality`, field of view, incidence and a
   fresh line of sight under occlusion): :class:`~agent.runtime.moves.claims.Captures`
   journals them (:class:`~agent.protocol.records.CaptureRec`) before the captured set it
   publishes (with a claim: pose, time, landmarks) names them, then fires the camera (a
   Trigger effect); a confirming camera's (a flown drone's) capture counts only at its word
   that the image was taken (:meth:`on_image`);
2. the captured set grows with what the peers prove (their claims: pose, capture test,
   :class:`~agent.runtime.moves.claims.ClaimJudge`, :meth:`on_peer_state`);
3. it decides as the simulator's drones do (:mod:`agent.strategy.inspection`): the rest of its
   tour (:func:`~agent.strategy.inspection.advance_tour`), or a new tour over its remaining
   set (owned, uncaptured, capturable) when its set changed (a trade, an adoption); it flies
   to the tour's first viewpoint around the structure (:class:`~agent.structure.routes.
   RouteGrid`) with the transit of the coverage moves; when nothing of its own is left it
   flies back to its start (out of the others' way) and reports itself converged there (the
   team's completion then needs every drone so).

Viewpoints found out of reach (a stalled flight) or reached without their captures are
planned around; when only those are left it tries them all again, at most
:data:`~agent.strategy.inspection.MAX_RETRIES` times, then gives what is left up (``blocked``
or ``unreachable``, :func:`~agent.strategy.inspection.give_up_codes`). The given-up set, by
reason, is published with the state (:class:`~agent.wire.peer.GivenUp` sets, with the
capturable set) and merged from the peers' (:func:`~agent.protocol.inspection_end.
merge_given_up`): a landmark a drone gave up after trying it is nobody's work any more, and
the team's end names it (:meth:`Inspecting.end`).

A drone with nothing of its own left takes work (:meth:`Inspecting.take_work`): the strategy's
re-split with the peer whose remaining tour is longest, computed from that peer's published
state and carried out as a pair re-split leg (the journaled two-phase trade of the coverage
moves, :mod:`agent.protocol.regroup`: the peer accepts it only for its current set); when no
re-split helps (or :data:`TAKE_TRIES` offers came to nothing) it flies home. At the start
each drone offers the simulator's initial re-split to each later peer in team order
(:mod:`agent.runtime.moves.work_taker`). An adopter captures the uncaptured part of what it
adopted. Positions [m; world ENU].
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import NDArray

from agent.config.scenario import Scenario
from agent.core.inspection import capture_quality, uncapturable_line
from agent.core.orientation import turn_towards
from agent.protocol.inspection_end import (
    BATTERY,
    InspectionEnd,
    given_up_codes,
    given_up_sets,
    inspection_end,
    merge_given_up,
)
from agent.protocol.records import CaptureRec
from agent.runtime.core.events import Asking, ImageTaken
from agent.runtime.core.shared import AgentConfig
from agent.runtime.core.vehicle import VehicleView
from agent.runtime.moves.claims import ClaimJudge, Tolerances
from agent.runtime.moves.shots import Captures
from agent.strategy.inspection import (
    PeerWork,
    TakeWork,
    Tour,
    advance_tour,
    give_up_codes,
    gives_up,
    next_action,
    out_of_work,
    plan_tour,
    remaining,
)
from agent.structure.sight_lines import sight_lines
from agent.wire.peer import AgentState, GivenUp, pack_bits
from agent.world.environment import TransitProgress, transit_displacement
from agent.world.inputs import StructureInputs, World

Array = NDArray[np.float64]
Mask = NDArray[np.bool_]
_log = logging.getLogger(f"viscover.{__name__}")

#: Re-splits a drone with nothing left offers before it flies home.
TAKE_TRIES = 2


class Inspecting:
    """Captures and capture tours of one agent (see the module docstring)."""

    def __init__(self, agent_id: str, sc: Scenario, world: World, pose: VehicleView,
                 owned_rows: Callable[[], NDArray[np.intp]],
                 others: Callable[[], Array], record: Callable[[CaptureRec], None],
                 captured: list[CaptureRec], cfg: AgentConfig | None = None) -> None:
        assert sc.inspection is not None, "not an inspection mission"
        self.id, self.sc, self.spec, self.pose = agent_id, sc, sc.inspection, pose
        self.owned_rows, self.others, self.record = owned_rows, others, record
        assert world.tables is not None, "an inspection's tables are prepared"
        self.table, self.grid = world.tables
        if line := uncapturable_line(self.table.reason, np.asarray(sc.landmark_ids)):
            _log.warning("agent %s: %s", agent_id, line)
        self.structure = StructureInputs(world.model, False, 0.5, sc.params.d_w)
        self.occlusion = sc.visibility == "occlusion"
        self.ids = np.asarray(sc.landmark_ids, dtype=np.int64)
        self.caps = Captures(self.ids, captured, record, pose.trigger)  # journaled, proved
        self.captured, self.cap = self.caps.captured, self.caps.cap  # (the same objects)
        self.tour = Tour(np.zeros(0, dtype=np.intp), np.full(self.ids.size, -1, np.intp), 0.0)
        self.goal: int | None = None
        self.route = np.zeros((0, 3))
        self.blocked = np.zeros(self.table.P.shape[0], dtype=np.bool_)
        #: viewpoints it arrived at without capturing all they were for
        self.reached = np.zeros(self.table.P.shape[0], dtype=np.bool_)
        self._owned_key: bytes = b""
        self.progress = TransitProgress()  #: how the flight to the route's next point goes
        self.rejected = 0  #: peers' given-up sets of the wrong size
        self.judge = ClaimJudge(agent_id, self.ids, self.table.capturable,  # peers' claims
                                lambda p, v, rows: self._imaged(p, v, rows)[0],
                                Tolerances.of(cfg), sc.agents, sc.params.p_lim, sc.params.w_lim)
        #: where it flies when nothing is left [m]: its initial pose in the scenario (a flying
        #: agent's station after take-off, not the ground it took off from, below the fence's
        #: floor; the runner then lands it), a joiner's pose when it joined
        start = next((a.p0 for a in sc.agents if a.id == agent_id), None)  # a joiner: none
        self.home = np.asarray(pose.current()[0] if start is None else start,
                               dtype=np.float64).copy()
        self._homing = self._at_home = False
        #: nothing of its own left and no work to take: fly home (else wait where it is)
        self.want_home = False
        self.take_tries = 0  #: re-splits offered since it last had work
        self.retries = 0  #: times every viewpoint left was out of reach and all were retried
        #: the landmarks given up in its view (its own and its peers'), by reason code of
        #: agent.protocol.inspection_end (0: not given up); kept across captures (the end
        #: names only those not captured)
        self.given_up = np.zeros(self.ids.size, dtype=np.int8)
        self._given_up_sets: list[GivenUp] = []  #: as published
        self.capturable_bits = pack_bits(self.table.capturable)  #: as published
        self.last_image: float | None = None  #: when the camera last took an image [s]

    # -- the captured set ------------------------------------------------------------------
    def bits(self) -> bytes:
        """The captured set as published (one bit per landmark row)."""
        return pack_bits(self.cap)

    def given_up_bits(self) -> list[GivenUp]:
        """The given-up set as published (one bit set per reason)."""
        return self._given_up_sets

    def published(self) -> dict[str, Any]:
        """The state fields an inspection drone owns: its captured, capturable and given-up
        sets (one bit per landmark row)."""
        return {"captured": self.bits(), "capturable": self.capturable_bits,
                "given_up": list(self._given_up_sets), "claims": self.caps.own.window(),
                "refused_claims": self.judge.refused_total}

    def _give_up(self, codes: NDArray[np.int8]) -> None:
        """Merge given-up ``codes`` (m,) into this agent's view (and what it publishes)."""
        merged = merge_given_up(self.given_up, codes)
        if not np.array_equal(merged, self.given_up):
            self.given_up = merged
            self._given_up_sets = given_up_sets(merged)

    def on_peer_state(self, st: AgentState) -> None:
        """Merge the captures a peer's claims prove (union; :class:`ClaimJudge`: refused
        claims counted) and its given-up set (:func:`merge_given_up`; a set of the wrong size
        is counted, not used)."""
        if st.given_up:
            codes = given_up_codes(st.given_up, self.ids.size)
            if codes is None:
                self.rejected += 1
            else:
                self._give_up(codes)
        self.caps.merge(self.judge.judge(st, self.cap, self.pose.current()[2]))

    @property
    def complete(self) -> bool:
        """Every capturable landmark captured, in this agent's view."""
        return bool((self.cap | ~self.table.capturable).all())

    def end(self, t: float | None = None) -> InspectionEnd:
        """How the mission ended in this agent's view, once the team stopped or the time ran
        out: complete at ``t`` [s], or each capturable landmark not captured with why it was
        given up (:func:`~agent.protocol.inspection_end.inspection_end`)."""
        return inspection_end(self.ids, self.table.capturable, self.cap, self.given_up, t)

    def give_up_rest(self) -> int:
        """Leaving on low battery: give up (``battery``) what it still owns uncaptured and
        nobody gave up yet, so that the team's end says why if nobody captures it after;
        returns how many (they stay work for whoever takes them over)."""
        owned = np.zeros(self.ids.size, dtype=np.bool_)
        owned[self.owned_rows()] = True
        rest = remaining(owned, self.done, self.table) & (self.given_up == 0)
        self._give_up(np.where(rest, BATTERY, 0).astype(np.int8))
        return int(rest.sum())

    def _imaged(self, p: Array, v: Array, rows: NDArray[np.intp]
                ) -> tuple[NDArray[np.intp], Array]:
        """Which of ``rows`` a capture from p [m; world ENU], v (unit) takes (indices into
        ``rows``: quality ≥ the inspection's and, with occlusion, a clear line of sight) and
        every row's quality (eq. 3.1)."""
        q, u = self.sc.q, self.sc.u
        qual = capture_quality(p[None, :], v[None, :], q[rows], u[rows], self.sc.d_opt,
                               self.spec, self.sc.view_axes(rows), self.sc.view_cos)[0]
        good = np.flatnonzero(qual >= self.spec.threshold)
        if good.size and self.occlusion:
            model = self.structure.model
            good = good[sight_lines(model, p[None, :], q, u,
                                    (np.zeros(good.size, dtype=np.intp), rows[good]))]
        return good, qual

    def captures_at(self, p: Array, v: Array) -> Mask:
        """The landmarks (m,) a capture from p [m; world ENU], v (unit) would take, captured
        before or not (nothing is journaled)."""
        rows = np.arange(self.ids.size, dtype=np.intp)
        out = np.zeros(self.ids.size, dtype=np.bool_)
        out[rows[self._imaged(np.asarray(p, np.float64), np.asarray(v, np.float64), rows)[0]]] \
            = True
        return out

    @property
    def done(self) -> Mask:
        """Per landmark (m,): captured, or waiting for the camera's word (not to fly for)."""
        return self.caps.done

    def capture(self) -> list[int]:
        """Capture, at the current pose, every uncaptured landmark imaged well enough; the
        new ids are journaled first, then join the set. Returns them. With a confirming
        camera: the image is asked for only, its capture waits for :meth:`on_image`."""
        p, v, t = self.pose.current()
        self.caps.expire(float(t))
        rows = np.flatnonzero(~self.done)
        if rows.size == 0:
            return []
        camera = self.spec.camera
        if camera is not None and not camera.ready(float(t), self.last_image):
            return []  # the camera is not ready for its next image (trigger interval)
        good, qual = self._imaged(p, v, rows)
        if good.size == 0:
            return []
        self.last_image = float(t)
        return self.caps.took(rows[good], float(t), p, v, qual[good].tolist())

    def on_image(self, ev: ImageTaken) -> None:
        """The camera's word on an image asked for (:meth:`Captures.on_image`)."""
        self.caps.on_image(ev)

    # -- the motion ------------------------------------------------------------------------
    def _need(self) -> Mask:
        owned = np.zeros(self.ids.size, dtype=np.bool_)
        owned[self.owned_rows()] = True
        return remaining(owned, self.done, self.table) & ~out_of_work(self.given_up)

    def _choose(self, p: Array) -> None:
        """The next viewpoint: the rest of the tour, or a new tour when the set changed;
        around viewpoints found out of reach, and, when only those are left, them again (at
        most :data:`MAX_RETRIES` times, then what is left is given up and reported)."""
        owned = np.sort(self.owned_rows()).tobytes()
        need = self._need()
        if owned != self._owned_key:
            self._owned_key = owned
            self.blocked[:] = False
            self.tour = plan_tour(p, need, self.table)
        else:
            self.tour = advance_tour(p, self.tour, self.done, self.table)
        rows = self.tour.rows[~self.blocked[self.tour.rows]]
        if rows.size == 0 and need.any():
            self.tour = plan_tour(p, need, self.table, self.blocked)
            rows = self.tour.rows
            if rows.size == 0:  # only viewpoints out of reach capture what is left
                self.retries += 1
                if gives_up(self.retries):
                    self._give_up(give_up_codes(need, self.reached, self.table))
                    _log.warning("agent %s: gives up %d landmarks it could not capture: %s",
                                 self.id, int(need.sum()), self.ids[need][:10].tolist())
                    self.goal = None
                    return
                self.blocked[:] = False
                self.tour = plan_tour(p, need, self.table)
                rows = self.tour.rows
        if rows.size == 0:
            self.goal = None
            return
        self._homing = self._at_home = self.want_home = False  # new work, on the way home
        self.take_tries = 0
        self.goal = int(rows[0])
        target = self.table.P[self.goal]
        self.route = target[None, :].copy() if self.grid is None else self.grid.route(p, target)
        self.progress = TransitProgress()

    def step(self) -> Asking[bool]:
        """One tick: capture, decide, fly; True when nothing of this agent's is left (first
        where it is, so that it may take work from a peer; then at home)."""
        self.capture()
        if self.goal is not None and not ((self.tour.credit == self.goal) & ~self.done).any():
            self.goal = None  # captured meanwhile, by this agent or a peer
        if self.goal is not None and np.sort(self.owned_rows()).tobytes() != self._owned_key:
            self.goal = None  # the set changed (a re-split, an adoption): plan again
        p, v, _ = self.pose.current()
        if self.goal is None:
            self._choose(p)
            if self.goal is None:
                if self._need().any():
                    return False
                return (yield from self._home(p)) if self.want_home else True
        arrived = yield from self._fly(p, v)
        if arrived and self.route.shape[0] > 1:
            self.route = self.route[1:]  # the next point: closer than ever again, stalls kept
            self.progress = TransitProgress(stall=self.progress.stall)
        elif arrived:
            self.capture()
            if ((self.tour.credit == self.goal) & ~self.done).any():
                # reached, yet not everything it was for
                self.blocked[self.goal] = self.reached[self.goal] = True
            self.goal = None
        elif self.progress.stalled:
            _log.info("agent %s: viewpoint %d out of reach for now", self.id, self.goal)
            self.blocked[self.goal] = True
            self.goal = None
        return False

    @property
    def at_home(self) -> bool:
        """Back at its start with nothing left to do."""
        return self._at_home

    def take_work(self, peers: list[PeerWork]) -> TakeWork | None:
        """Nothing of its own left: a re-split with the peer whose remaining tour is longest
        (:func:`~agent.strategy.inspection.next_action`, from the peers' published states),
        or None, and then it flies home. At most :data:`TAKE_TRIES` offers per idle time."""
        if self.want_home or self.goal is not None:
            return None
        p, _, _ = self.pose.current()
        need = self._need()
        if need.any() or self.take_tries >= TAKE_TRIES:
            self.want_home = not need.any()
            return None
        self.take_tries += 1
        act = next_action(p, plan_tour(p, need, self.table), need, peers, self.done, self.table)
        if isinstance(act, TakeWork):
            return act
        self.want_home = True
        return None

    def peer_work(self, aid: str, p: Array, owned_rows: NDArray[np.intp]) -> PeerWork:
        """A peer's work as its state shows it: position, set and remaining tour [m]."""
        owned = np.zeros(self.ids.size, dtype=np.bool_)
        owned[owned_rows] = True
        owned &= ~out_of_work(self.given_up)  # what the team gave up is nobody's work
        length = plan_tour(p, remaining(owned, self.done, self.table), self.table).length
        return PeerWork(aid, p, owned, length)

    def _home(self, p: Array) -> Asking[bool]:
        """Nothing of ours left: fly back to the start (out of the others' way, as the
        strategy's GoHome); True once there (or stuck on the way)."""
        if self._at_home:
            return True
        if not self._homing:
            self._homing = True
            self.route = self.home[None, :].copy() if self.grid is None else \
                self.grid.route(p, self.home)
            self.progress = TransitProgress()
        prm = self.sc.params
        target = self.route[0]
        p_dot = transit_displacement(p, target, prm, self.sc.space, self.others(),
                                     self.structure) / prm.dt
        yield from self.pose.command(p_dot, np.zeros(3), prm.dt)
        dist = float(np.linalg.norm(target - self.pose.current()[0]))
        self.progress.update(dist)
        if dist <= max(prm.p_min * prm.dt, 1e-6) or self.progress.stalled:
            self.route, self.progress = self.route[1:], TransitProgress()
            self._at_home = self.route.shape[0] == 0
        return self._at_home

    def _fly(self, p: Array, v: Array) -> Asking[bool]:
        """One Δt towards the route's next point, the camera turning to the goal's view;
        True on arrival there (camera aligned at the last point)."""
        assert self.goal is not None
        prm = self.sc.params
        target, view = self.route[0], self.table.V[self.goal]
        p_dot = transit_displacement(p, target, prm, self.sc.space, self.others(),
                                     self.structure) / prm.dt
        v_next = turn_towards(v, view, prm.w_lim * prm.dt)
        axis = np.cross(v, v_next)
        ang = float(np.arctan2(np.linalg.norm(axis), float(v @ v_next)))
        omega = np.zeros(3) if ang <= 1e-12 else axis / np.linalg.norm(axis) * ang / prm.dt
        yield from self.pose.command(p_dot, omega, prm.dt)
        p2, v2, _ = self.pose.current()
        dist = float(np.linalg.norm(target - p2))
        cos_left = float(v2 @ view)
        turning = cos_left < 1.0 - 1e-6
        left = float(np.arccos(min(1.0, max(-1.0, cos_left))))  # angle to the view [rad]
        self.progress.update(dist, left)  # a flown camera that stops turning closer stalls
        last = self.route.shape[0] == 1
        return dist <= max(prm.p_min * prm.dt, 1e-6) and (not last or not turning)
