"""The kinematic simulator of chapter 5 (figure 5.1): n agents in one process.

Each agent integrates its own commanded velocities (eq. 5.1). Agents are asynchronous in the
thesis' sense: every tick of Δt each agent that is optimising takes one planner step (agents
in scenario order, each seeing the others' latest positions); an agent that has converged
tries the partners of its list in order (section 4.5): a partner still optimising is busy and
is dropped, a converged partner trades (Algorithm 7). A successful trade resets both lists and
restarts both pose optimisations; a failed one drops each from the other's list. The mission
is complete when every agent has converged and every partner list is empty. A scenario with
``trading = false`` runs pose optimisation only (every partner list starts empty).

A scenario with a ``[structure]`` first gets its mesh landmarks (:mod:`agent.world.structure`).
The structure is then an obstacle for every agent (section 4.3 rows from the closest mesh
points, steps truncated to keep ``structure.margin``), and with ``visibility = "occlusion"``
each agent plans over the landmarks its cached ray cast shows unoccluded (recast after
``structure.refresh`` metres) and trades (Algorithm 7) on fresh casts from both cameras: a
landmark hidden from a camera counts 0 for it. The recorded vision and coverage follow the
scenario's model; structure runs also record the coverage under both models (fresh casts).

Deterministic: there is no randomness in the dynamics; the scenario seed is recorded (and
seeds the landmark sampling on a mesh).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from agent.core.planner import integrate, plan_step
from agent.core.trading import PartnerList, trade_landmarks
from agent.core.vision import Landmarks, per_landmark
from agent.sim.result import SimResult, TradeEvent
from agent.strategy.registry import strategy_of
from agent.world.structure import (
    coverage_by_model,
    resolve_structure,
    structure_inputs,
    trade_sight_lines,
)

if TYPE_CHECKING:
    from agent.config.scenario import Scenario

Array = NDArray[np.float64]
ProgressFn = Callable[[float, float], None]


@dataclass
class _Agent:
    """Mutable state of one simulated agent."""

    id: str
    p: Array
    v: Array
    partners: PartnerList
    optimising: bool = True
    prev_dir: Array = field(default_factory=lambda: np.zeros(3))


class KinematicSim:
    """Step-by-step form of :func:`simulate` (useful for tests that inspect every tick)."""

    def __init__(self, scenario: Scenario) -> None:
        self.sc = scenario = resolve_structure(scenario)
        self.inputs = [structure_inputs(scenario) for _ in scenario.agents]
        ids = tuple(a.id for a in scenario.agents) if scenario.trading else ()
        self.agents = [
            _Agent(a.id, a.p0.astype(np.float64).copy(), a.v0.astype(np.float64).copy(),
                   PartnerList(a.id, ids))
            for a in scenario.agents
        ]
        self.owner = np.full(scenario.q.shape[0], -1, dtype=np.intp)
        for i, a in enumerate(scenario.agents):
            self.owner[a.landmarks] = i
        self.t = 0.0
        self.trades: list[TradeEvent] = []

    # -- observation -------------------------------------------------------------------
    def positions(self) -> Array:
        """Agent positions (n, 3) [m]."""
        return np.array([a.p for a in self.agents])

    def directions(self) -> Array:
        """Camera directions (n, 3), unit."""
        return np.array([a.v for a in self.agents])

    def visions(self) -> Array:
        """Per-agent vision of its own landmark set (n,), under the scenario's visibility
        model (occlusion: fresh casts, landmarks behind the structure count 0)."""
        q, u, d_opt = self.sc.q, self.sc.u, self.sc.d_opt
        out = np.zeros(len(self.agents))
        for i, a in enumerate(self.agents):  # loop over agents; landmarks are vectorised
            mine = self.owner == i
            each = per_landmark(a.p, a.v, q[mine], u[mine], d_opt)
            inputs = self.inputs[i]
            if inputs.model is not None and inputs.tracker is not None and each.any():
                seen = each > 0.0
                clear = inputs.model.unoccluded(a.p, q[mine][seen], u[mine][seen])
                each[np.flatnonzero(seen)[~clear]] = 0.0
            out[i] = each.sum()
        return out

    def coverage_by_model(self) -> tuple[float, float] | None:
        """Eq. 3.10 under (facing, occlusion) visibility; None without a structure."""
        model = self.inputs[0].model if self.inputs else None
        if model is None:
            return None
        return coverage_by_model(model, self.positions(), self.directions(), self.sc.q,
                                 self.sc.u, self.owner, self.sc.d_opt)

    @property
    def complete(self) -> bool:
        """Section 4.5: all agents converged and every partner list empty."""
        return all(not a.optimising and a.partners.next() is None for a in self.agents)

    # -- dynamics ----------------------------------------------------------------------
    def _plan(self, i: int) -> None:
        a = self.agents[i]
        mine = self.owner == i
        others = np.array([b.p for j, b in enumerate(self.agents) if j != i]).reshape(-1, 3)
        lm = Landmarks.of(self.sc.q[mine], self.sc.u[mine])
        step = plan_step(a.p, a.v, lm, None, self.sc.d_opt, self.sc.params, self.sc.space,
                         others, a.prev_dir, **self.inputs[i].planner_inputs(a.p, lm))
        if step.converged:
            a.optimising = False
            a.prev_dir = np.zeros(3)
            return
        p, v = integrate(a.p, a.v, step.p_dot, step.omega, self.sc.params.dt)
        a.p, a.v = self.sc.space.clip(p), v
        a.prev_dir = step.p_dir

    def _try_trades(self, i: int) -> None:
        a = self.agents[i]
        while (partner_id := a.partners.next()) is not None:
            j = next(k for k, b in enumerate(self.agents) if b.id == partner_id)
            b = self.agents[j]
            if b.optimising:  # busy: drop and try the next one
                a.partners.drop(b.id)
                continue
            mine, theirs = np.flatnonzero(self.owner == i), np.flatnonzero(self.owner == j)
            q, u = self.sc.q, self.sc.u
            both = np.concatenate((mine, theirs))
            model = self.inputs[i].model if self.inputs[i].tracker is not None else None
            clear_a, clear_b = trade_sight_lines(model, a.p, b.p, q[both], u[both])
            out = trade_landmarks(
                a.p, a.v, q[mine], u[mine], b.p, b.v, q[theirs], u[theirs], self.sc.d_opt,
                clear_a, clear_b,
            )
            if not out.success:
                a.partners.drop(b.id)
                b.partners.drop(a.id)
                continue
            self.owner[mine[out.a_to_b]] = j
            self.owner[theirs[out.b_to_a]] = i
            ids = self.sc.landmark_ids
            self.trades.append(TradeEvent(
                t=round(self.t, 9), initiator=a.id, partner=b.id,
                to_partner=[int(ids[k]) for k in mine[out.a_to_b]],
                to_initiator=[int(ids[k]) for k in theirs[out.b_to_a]],
                gain=out.gain,
            ))
            for x in (a, b):
                x.partners.reset()
                x.optimising = True
            return

    def tick(self) -> None:
        """Advance all agents by one sampling time Δt."""
        for i, a in enumerate(self.agents):
            if a.optimising:
                self._plan(i)
            if not a.optimising:
                self._try_trades(i)
        self.t += self.sc.params.dt


#: Why the lockstep engine refuses a strategy with moves of its own.
LOCKSTEP_THESIS_ONLY = ("strategy {strategy!r} runs on the agents' decision code only; the "
                        "lockstep engine runs the thesis (chapter 5) and inspection missions")


def simulate(scenario: Scenario, progress: ProgressFn | None = None) -> SimResult:
    """Run a scenario until the mission is complete or ``scenario.duration`` [s] elapses,
    lockstep: the thesis' strategy (this module); an inspection mission (``[inspection]``)
    until every capturable landmark is captured (:mod:`agent.sim.inspection`). A strategy
    with moves of its own (``potential``) runs on the agents' decision code only
    (:func:`agent.testing.agent_engine.simulate_agents`): ValueError here."""
    if scenario.inspection is not None:
        from agent.sim.inspection import InspectionSim

        ins = InspectionSim(resolve_structure(scenario))
        result = record_run(ins, ins.sc, progress, lambda: ins.done, ins.trades)
        result.captures, result.inspection = ins.captures, ins.summary()
        result.complete, result.t_complete = ins.complete, ins.t_complete
        return result
    if strategy_of(scenario.strategy).extends_thesis:
        raise ValueError(LOCKSTEP_THESIS_ONLY.format(strategy=scenario.strategy))
    sim = KinematicSim(scenario)
    return record_run(sim, sim.sc, progress, lambda: sim.complete, sim.trades)


def record_run(sim: Any, scenario: Scenario, progress: ProgressFn | None,
                over: Callable[[], bool], trades: list[TradeEvent]) -> SimResult:
    """Tick ``sim`` (positions, directions, visions, owner, coverage_by_model, tick, t) until
    ``over()`` or the scenario's duration, recording every tick into a :class:`SimResult`."""
    dt = scenario.params.dt
    n_ticks = int(np.ceil(scenario.duration / dt))
    times, pos, dirs, vis, own = [], [], [], [], []
    by_model: list[tuple[float, float]] = []

    def record() -> None:
        times.append(sim.t)
        pos.append(sim.positions())
        dirs.append(sim.directions())
        vis.append(sim.visions())
        own.append(sim.owner.copy())
        both = sim.coverage_by_model()
        if both is not None:
            by_model.append(both)

    record()
    t_complete: float | None = None
    for k in range(n_ticks):
        sim.tick()
        record()
        if progress is not None and (k % 50 == 0 or k == n_ticks - 1):
            progress(sim.t, scenario.duration)
        if over():
            t_complete = sim.t
            break
    if progress is not None:
        progress(sim.t, scenario.duration)
    vision = np.array(vis)
    return SimResult(
        scenario=scenario.name,
        seed=scenario.seed,
        planar=scenario.params.planar,
        agent_ids=[a.id for a in scenario.agents],
        landmark_ids=list(scenario.landmark_ids),
        q=scenario.q,
        u=scenario.u,
        space_lo=scenario.space.lo,
        space_hi=scenario.space.hi,
        d_opt=float(scenario.d_opt),
        times=np.array(times),
        positions=np.array(pos),
        directions=np.array(dirs),
        vision=vision,
        coverage=vision.sum(axis=1),
        owners=np.array(own),
        trades=trades,
        complete=t_complete is not None,
        t_complete=t_complete,
        visibility=scenario.visibility,
        coverage_by_model=np.array(by_model) if by_model else None,
        strategy=scenario.strategy,
    )
