"""The "potential" coverage strategy (``strategy = "potential"`` in a scenario): the
kinematic simulation of chapter 5 plus coverage moves that leave no visible landmark unseen.

Same conventions as :mod:`agent.sim.kinematic`: every tick of Δt each agent, in team order
and seeing the others' latest positions, either takes one planner step
(:func:`agent.core.planner.plan_step`), or flies one step towards a goal pose (transit), or,
once converged, works through its partner list (section 4.5). With a converged partner it
first tries Algorithm 7 (:func:`agent.core.trading.trade_landmarks`); if that moves nothing it
asks :func:`agent.core.coverage_moves.group_proposal` for a re-split of both sets with new
poses, which the partner checks with :func:`accept_pair_proposal`; if that fails too, for a
3-way re-split with each other converged agent (``triples``). When all pairs and triples
are exhausted, agent 0 proposes a re-split of all sets between n jointly chosen poses (a
team move, at most ``team_moves`` times, n ≥ 4). An agent that has just
converged first asks :func:`relocation_goal` whether a better viewpoint for its own set
exists. Transit: straight towards the goal at ≤ ṗ_lim with the same collision avoidance as
the planner (problem 4.11 and the R_s / wall truncation), turning the camera towards the
goal direction at ≤ ω_lim; on arrival (or when stuck) pose optimisation resumes.

Phases (``after_thesis``, the default): until the thesis strategy's completion condition
holds the run is exactly the thesis strategy (same ticks, same Algorithm 7 trades); only
then are relocations and group moves enabled, so the score may drop for a while (a flight to
a better viewpoint) but the final score is never below the thesis' from the same start:
should the moves end below it (a move predicts its gain at poses a blocked transit may not
reach), every agent takes back its phase-1 set and flies back to its phase-1 pose (once).

Every decision gets only the agent's own state and the messages of its peers (pose, set,
vision, converged); this driver is what builds those arguments (the agent processes make the
same moves from their own state and their peers' messages: :mod:`agent.runtime.moves`).
Counters bound the number of relocations per agent and pair moves per team, so every run
terminates. A mesh structure is an obstacle for planner steps
and transits (its closest points as section-4.3 rows, steps cut at the clearance), as in
:mod:`agent.sim.kinematic`; candidate viewpoints (:func:`environment_of`) avoid its bounding
box (the mesh's, else the landmarks') and stay in the mission space.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from agent.core.coverage_moves import (
    Goal,
    GroupProposal,
    OwnState,
    accept_pair_proposal,
    group_proposal,
    own_message,
    relocation_goal,
)
from agent.core.planner import integrate, plan_step
from agent.core.trading import PartnerList, trade_landmarks
from agent.core.viewpoints import Environment
from agent.core.vision import Landmarks, coverage_score, per_landmark
from agent.sim.result import TradeEvent
from agent.strategy.potential import (
    MAX_RELOCATIONS,
    TEAM_MOVES,
    TEAM_RESPLITS_PER_N2,
    TEAM_STARTS,
    TRIPLES,
    resplit_after_no_trade,
)
from agent.world.environment import (
    TransitProgress,
    environment_of,
    initial_owner,
    transit_displacement,
)
from agent.world.structure import StructureInputs, coverage_by_model, trade_sight_lines

if TYPE_CHECKING:
    from agent.config.scenario import Scenario

Array = NDArray[np.float64]

STRATEGY = "potential"  #: name of this strategy (``strategy = "potential"`` in a scenario)


@dataclass
class _Agent:
    """Mutable state of one simulated agent."""

    id: str
    p: Array
    v: Array
    partners: PartnerList
    mode: str = "opt"  #: "opt" (planner), "transit" (to goal) or "idle" (converged)
    goal: Goal | None = None
    progress: TransitProgress = field(default_factory=TransitProgress)  #: the transit so far
    relocations: int = 0
    prev_dir: Array = field(default_factory=lambda: np.zeros(3))


@dataclass(frozen=True)
class RunResult:
    """Outcome of one run: final poses, owners, score (eq. 3.10), simulated time [s]."""

    P: Array
    V: Array
    owner: NDArray[np.intp]
    score: float
    t: float
    complete: bool
    trades: int
    pair_moves: int
    relocations: int


class StrategySim:
    """Step-by-step simulation of one scenario with the coverage moves."""

    def __init__(self, scenario: Scenario, env: Environment | None = None,
                 max_relocations: int = MAX_RELOCATIONS, max_pair_moves: int | None = None,
                 triples: bool = TRIPLES, after_thesis: bool = True,
                 team_moves: int = TEAM_MOVES) -> None:
        self.sc = scenario
        self.env = env if env is not None else environment_of(scenario)
        #: The structure as an obstacle for planner steps and transits (as in chapter 5's
        #: simulator); none without a mesh.
        self.inputs = [StructureInputs.of(scenario) for _ in scenario.agents]
        ids = tuple(a.id for a in self.sc.agents)
        self.agents = [_Agent(a.id, a.p0.copy(), a.v0.copy(), PartnerList(a.id, ids))
                       for a in self.sc.agents]
        self.owner = initial_owner(scenario)
        self.t = 0.0
        self.trades = 0
        self.trade_events: list[TradeEvent] = []
        self.pair_moves = 0
        self.max_relocations = max_relocations
        self.triples = triples
        self.team_moves_left = team_moves
        self.finished = False
        #: Moves only once the thesis strategy has completed (phase 2); until then the run is
        #: exactly the thesis strategy, so phase 2 starts from the thesis' final state.
        self.moves = not after_thesis
        self.thesis_score: float | None = None
        self._thesis_state: tuple[Array, Array, NDArray[np.intp]] | None = None
        self.reverted = False
        n = len(self.agents)
        self.max_pair_moves = TEAM_RESPLITS_PER_N2 * n * n if max_pair_moves is None \
            else max_pair_moves

    # -- what an agent knows about itself and publishes ----------------------------------
    def _vision(self, i: int) -> float:
        mine = self.owner == i
        a = self.agents[i]
        each = per_landmark(a.p, a.v, self.sc.q[mine], self.sc.u[mine], self.sc.d_opt)
        lm = Landmarks.of(self.sc.q[mine], self.sc.u[mine])
        return float(self.inputs[i].seen_vision(each, a.p, lm).sum())

    def own(self, i: int) -> OwnState:
        """Agent i's own state."""
        a = self.agents[i]
        idx = np.flatnonzero(self.owner == i)
        return OwnState(a.id, a.p.copy(), a.v.copy(), idx.astype(np.int64), self.sc.q[idx],
                        self.sc.u[idx], self._vision(i))

    def _others(self, *exclude: int) -> Array:
        return np.array([b.p for j, b in enumerate(self.agents) if j not in exclude]
                        ).reshape(-1, 3)

    # -- dynamics ------------------------------------------------------------------------
    def _start_transit(self, i: int, goal: Goal) -> None:
        a = self.agents[i]
        a.mode, a.goal, a.progress = "transit", goal, TransitProgress()

    def _transit(self, i: int) -> None:
        a, prm = self.agents[i], self.sc.params
        assert a.goal is not None
        a.p = self.sc.space.clip(a.p + transit_displacement(
            a.p, a.goal.p, prm, self.sc.space, self._others(i), self.inputs[i]))
        cosang = float(np.clip(a.v @ a.goal.v, -1.0, 1.0))
        ang = float(np.arccos(cosang))
        if ang > 1e-9:
            axis = np.cross(a.v, a.goal.v)
            if np.linalg.norm(axis) < 1e-12:
                axis = np.cross(a.v, np.array([0.0, 0.0, 1.0]))
            axis /= np.linalg.norm(axis)
            turn = min(ang, prm.w_lim * prm.dt)
            _, a.v = integrate(a.p, a.v, np.zeros(3), axis * turn / prm.dt, prm.dt)
            if turn == ang:
                a.v = a.goal.v.copy()
        dist = float(np.linalg.norm(a.goal.p - a.p))
        a.progress.update(dist, float(np.arccos(np.clip(a.v @ a.goal.v, -1.0, 1.0))))
        arrived = dist < 1e-6 and float(a.v @ a.goal.v) > 1.0 - 1e-9
        if arrived or a.progress.stalled:
            a.mode, a.goal, a.prev_dir = "opt", None, np.zeros(3)

    def _plan(self, i: int) -> None:
        a = self.agents[i]
        mine = self.owner == i
        lm = Landmarks.of(self.sc.q[mine], self.sc.u[mine])
        step = plan_step(a.p, a.v, lm, None, self.sc.d_opt, self.sc.params, self.sc.space,
                         self._others(i), a.prev_dir, **self.inputs[i].planner_inputs(a.p, lm))
        if step.converged:
            a.mode, a.prev_dir = "idle", np.zeros(3)
            if self.moves and a.relocations < self.max_relocations:
                goal = relocation_goal(self.own(i), self._others(i), self.env, self.sc.d_opt)
                if goal is not None:
                    a.relocations += 1
                    self._start_transit(i, goal)
            return
        a.p, a.v = integrate(a.p, a.v, step.p_dot, step.omega, self.sc.params.dt)
        a.p = self.sc.space.clip(a.p)
        a.prev_dir = step.p_dir

    def _try_trades(self, i: int) -> None:
        a = self.agents[i]
        while (partner_id := a.partners.next()) is not None:
            j = next(k for k, b in enumerate(self.agents) if b.id == partner_id)
            b = self.agents[j]
            if b.mode != "idle":
                a.partners.drop(b.id)
                continue
            mine, theirs = np.flatnonzero(self.owner == i), np.flatnonzero(self.owner == j)
            q, u = self.sc.q, self.sc.u
            both = np.concatenate((mine, theirs))
            model = self.inputs[i].model if self.inputs[i].tracker is not None else None
            clear_a, clear_b = trade_sight_lines(model, a.p, b.p, q[both], u[both])
            out = trade_landmarks(a.p, a.v, q[mine], u[mine], b.p, b.v, q[theirs], u[theirs],
                                  self.sc.d_opt, clear_a, clear_b)
            if out.success:
                self.owner[mine[out.a_to_b]] = j
                self.owner[theirs[out.b_to_a]] = i
                self.trades += 1
                ids = self.sc.landmark_ids
                self.trade_events.append(TradeEvent(
                    t=round(self.t, 9), initiator=a.id, partner=b.id,
                    to_partner=[int(ids[k]) for k in mine[out.a_to_b]],
                    to_initiator=[int(ids[k]) for k in theirs[out.b_to_a]], gain=out.gain))
                for x in (a, b):
                    x.partners.reset()
                    x.mode = "opt"
                return
            if not self.moves:
                a.partners.drop(b.id)
                b.partners.drop(a.id)
                continue
            if self._resplit_after_no_trade(i, j):
                return
            a.partners.drop(b.id)
            b.partners.drop(a.id)

    def _resplit_after_no_trade(self, i: int, j: int) -> bool:
        """Agent i offers the strategy's re-split after a NoTrade with j (a pair, else a
        triple with each idle agent in team order); applied if every member accepts."""
        if self.pair_moves >= self.max_pair_moves:
            return False
        index = {b.id: k for k, b in enumerate(self.agents)}
        thirds = (own_message(self.own(k), True) for k in range(len(self.agents))
                  if k not in (i, j) and self.agents[k].mode == "idle")
        prop = resplit_after_no_trade(
            self.own(i), own_message(self.own(j), True), thirds,
            lambda out: self._others(i, *(index[x] for x in out)), self.env, self.sc.d_opt,
            self.triples)
        return prop is not None and self._apply_group(i, prop)

    def _group_move(self, i: int, peers: tuple[int, ...], starts: int = 1) -> bool:
        """Agent i proposes a re-split with converged peers; applied if every peer accepts."""
        if self.pair_moves >= self.max_pair_moves:
            return False
        prop = group_proposal(self.own(i), tuple(own_message(self.own(j), True) for j in peers),
                              self._others(i, *peers), self.env, self.sc.d_opt, starts)
        return prop is not None and self._apply_group(i, prop)

    def _apply_group(self, i: int, prop: GroupProposal) -> bool:
        """Re-split ``prop`` (led by agent i) if every member accepts it: ownership moves as
        in a trade and every member flies to its new pose."""
        index = {b.id: k for k, b in enumerate(self.agents)}
        team = tuple(index[m] for m in prop.members)
        if not all(accept_pair_proposal(self.own(j), prop) for j in team[1:]):
            return False
        for k, idx in enumerate(team):
            self.owner[prop.sets[k]] = idx
        self.pair_moves += 1
        for k, idx in enumerate(team):
            self.agents[idx].partners.reset()
            self._start_transit(idx, prop.goals[k])
        return True

    def tick(self) -> None:
        """Advance all agents by one sampling time Δt."""
        for i, a in enumerate(self.agents):
            if a.mode == "transit":
                self._transit(i)
            elif a.mode == "opt":
                self._plan(i)
            if a.mode == "idle":
                self._try_trades(i)
        if not self.moves and self.complete:
            self._start_moves()
        elif self.moves and self.complete and not self.finished:
            if self.team_moves_left > 0 and not self.reverted and self._team_move():
                self.team_moves_left -= 1
            elif not self.reverted and self._thesis_state is not None and (
                    self.result().score < (self.thesis_score or 0.0) - 1e-9):
                self._revert()
            else:
                self.finished = True
        self.t += self.sc.params.dt

    def _team_move(self) -> bool:
        """When pairs and triples are exhausted: the first agent proposes a re-split of every
        set between n jointly chosen poses (a group move with all peers' messages)."""
        n = len(self.agents)
        if n < 4 or not self._group_move(0, tuple(range(1, n)), starts=TEAM_STARTS):
            self.team_moves_left = 0  # n ≤ 3: the triples already were team moves
            return False
        return True

    def _revert(self) -> None:
        """Safeguard: the moves ended below the thesis' final state (e.g. a blocked transit);
        every agent takes back its phase-1 set and flies back to its phase-1 pose."""
        assert self._thesis_state is not None
        P, V, owner = self._thesis_state
        self.reverted = True
        self.max_pair_moves = self.pair_moves  # no further moves
        self.max_relocations = 0
        self.owner = owner.copy()
        for i, a in enumerate(self.agents):
            a.partners.reset()
            self._start_transit(i, Goal(P[i], V[i], 0.0))

    def _start_moves(self) -> None:
        """Phase 2: the thesis strategy has completed; every agent checks for a relocation
        and works through its partner list again, now with the coverage moves."""
        self.moves = True
        self.thesis_score = self.result().score
        self._thesis_state = (np.array([a.p for a in self.agents]),
                              np.array([a.v for a in self.agents]), self.owner.copy())
        for i, a in enumerate(self.agents):
            a.partners.reset()
            if a.mode == "idle" and a.relocations < self.max_relocations:
                goal = relocation_goal(self.own(i), self._others(i), self.env, self.sc.d_opt)
                if goal is not None:
                    a.relocations += 1
                    self._start_transit(i, goal)

    @property
    def complete(self) -> bool:
        """All agents converged and every partner list empty (in phase 2 if there is one)."""
        return all(a.mode == "idle" and a.partners.next() is None for a in self.agents)

    @property
    def done(self) -> bool:
        """The mission is over: complete with the coverage moves enabled, no team move or
        revert left to make."""
        return self.finished

    def positions(self) -> Array:
        """Positions (n, 3) [m; world ENU]."""
        return np.array([a.p for a in self.agents])

    def directions(self) -> Array:
        """Camera directions (n, 3), unit."""
        return np.array([a.v for a in self.agents])

    def visions(self) -> Array:
        """Per-agent vision of its own set (n,), eq. 3.4 (facing model)."""
        return np.array([self._vision(i) for i in range(len(self.agents))])

    def coverage_by_model(self) -> tuple[float, float] | None:
        """Eq. 3.10 under (facing, occlusion) visibility (fresh casts); None without a
        structure."""
        model = self.inputs[0].model if self.inputs else None
        if model is None:
            return None
        return coverage_by_model(model, self.positions(), self.directions(), self.sc.q,
                                 self.sc.u, self.owner, self.sc.d_opt)

    def result(self) -> RunResult:
        """Final poses, owners and the score of eq. 3.10 (with occlusion: of the landmarks
        whose line of sight is clear)."""
        P = np.array([a.p for a in self.agents])
        V = np.array([a.v for a in self.agents])
        score = coverage_score(P, V, self.sc.q, self.sc.u, self.owner, self.sc.d_opt)
        both = self.coverage_by_model() if self.sc.visibility == "occlusion" else None
        if both is not None:
            score = both[1]
        return RunResult(P, V, self.owner.copy(), score, self.t, self.done, self.trades,
                         self.pair_moves, sum(a.relocations for a in self.agents))
