"""One agent's motion each tick while it optimises: the planner step of figure 4.1 executed by
its pose source (within the camera tilt limits of its gimbal, :mod:`agent.core.tilt`), with
the settle test of a flown vehicle (figure 6.2), and, beyond the thesis,
flights to a better viewpoint: once after an adoption, and in the coverage-move stage of
``strategy = "potential"`` (:mod:`agent.runtime.moves.coverage`: at convergence, and to the new
pose of
a committed pair re-split).

Relocation after adoption: landmarks adopted from a lost agent
(:mod:`agent.runtime.fencing.adoption`)
are often on the far side of the structure, where the adopter's camera gives them vision 0
and so a zero gradient: pose optimisation alone never turns towards them. Once the adopter
has converged again with landmarks it does not see, it asks the potential strategy's
:func:`~agent.core.coverage_moves.relocation_goal` for the best viewpoint of its whole set
(vectorised candidates, ≥ R_s from the others' positions, outside the structure's box), flies
there as the simulator's strategy does (:func:`~agent.world.environment.transit_displacement`:
straight at ≤ ṗ_lim with the avoidance of section 4.3, R_s kept, the mesh an obstacle, steps
cut at obstacles) turning its camera at ≤ ω_lim, and optimises again from there. Once per
adoption; a scenario without a lost agent runs chapter 5 exactly.
"""

from __future__ import annotations

import functools
import logging
from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

from agent.config.scenario import Scenario
from agent.core.coverage_moves import Goal, OwnState, relocation_goal
from agent.core.orientation import angles_from_direction
from agent.core.planner import plan_step
from agent.core.vision import Landmarks, per_landmark_cols
from agent.runtime.core.events import Asking, compute
from agent.runtime.core.shared import Shared
from agent.runtime.core.vehicle import SettleTest, VehicleView
from agent.runtime.ends.membership import Membership
from agent.runtime.moves.inspecting import Inspecting
from agent.world.environment import ALIGNED_RAD, TransitProgress, transit_displacement
from agent.world.inputs import StructureInputs

Array = NDArray[np.float64]
_log = logging.getLogger(f"viscover.{__name__}")



class Planning:
    """The motion of one agent (see the module docstring); :meth:`step` runs in the core's
    tick while the agent optimises."""

    def __init__(self, shared: Shared, sc: Scenario, members: Membership, pose: VehicleView,
                 owned: Callable[[], Landmarks], motion: Callable[[], bool] | None,
                 settle: SettleTest | None, in_move_stage: Callable[[], bool]) -> None:
        self.s, self.sc, self.members, self.pose = shared, sc, members, pose
        self.owned, self.motion, self.settle = owned, motion, settle
        #: whether the agent is in a stage of coverage moves (agent.runtime.moves.coverage)
        self.in_move_stage = in_move_stage
        self.relocate_armed = False  #: set by an adoption: relocate once at convergence
        self.goal: Goal | None = None  #: transit target (None: optimising)
        self.progress = TransitProgress()  #: how the transit to ``goal`` is doing
        self.relocations = 0
        self.prev_dir = np.zeros(3)  #: last planner direction (λ_dir of section 5.2)
        shared.on_success.append(self._forget_direction)  # section 4.5: optimise afresh
        #: an inspection mission's captures and tours (agent.runtime.moves.inspecting), else None
        self.inspecting: Inspecting | None = None

    def _forget_direction(self) -> None:
        """A new optimisation starts: no direction-change limit from the last one."""
        self.prev_dir = np.zeros(3)

    def arm_relocation(self) -> None:
        """An adoption gave us landmarks: relocate once at the next convergence if needed."""
        self.relocate_armed = True

    @functools.cached_property
    def structure(self) -> StructureInputs:
        """The scenario's structure as planner inputs (none without a structure)."""
        sc, spec = self.sc, self.sc.structure
        return StructureInputs(self.s.world.model, sc.visibility == "occlusion",
                               0.5 if spec is None else spec.refresh, sc.params.d_w)

    def others(self) -> Array:
        """The other agents' last known positions (k, 3) [m; world ENU]."""
        return self.members.book.others()

    def step(self) -> Asking[None]:
        """Figure 4.1: one planner step (or the test's motion, or a transit step); on
        convergence the agent stops optimising (section 4.5: it may trade). The planner step
        and the search for a better viewpoint are computed outside the core (the agent
        answers its peers meanwhile)."""
        s = self.s
        goal = s.take_goal()
        if goal is not None and self.inspecting is None:  # a committed pair re-split: fly to
            self.goal, self.progress = goal, TransitProgress()  # our new pose (an inspection
            # plans its own tour)
        if self.goal is not None:
            yield from self._transit()
            return
        if self.inspecting is not None:
            converged = yield from self.inspecting.step()
        elif self.motion is not None:
            converged = self.motion()
        else:
            lm = self.owned()
            others = self.others()
            p, v, t = self.pose.current()
            term, prm, space, prev = s.geo.term, self.sc.params, self.sc.space, self.prev_dir
            inputs, tilt = self.structure.planner_inputs(p, lm), self.pose.tilt_limits()
            rev = s.ledger_rev
            step = yield from compute(lambda: plan_step(p, v, lm, None, term, prm, space,
                                                        others, prev, **inputs, tilt=tilt))
            if s.ledger_rev != rev:  # the set changed while it computed (an adoption, a
                return  # re-split leg): the step is stale; optimise the new set next tick
            converged = step.converged
            if self.settle is not None:
                rest = None if converged else self.settle.update(t, p, v)
                if converged:
                    self.settle.reset()
                elif rest is not None:  # settled: hold the centre of the motion (fig. 6.2)
                    converged = True
                    self.pose.hold(rest[0], angles_from_direction(rest[1])[1])
            if not converged:
                yield from self.pose.command(step.p_dot, step.omega, self.sc.params.dt)
                self.prev_dir = step.p_dir
            elif (yield from self._relocate(p, v, lm, others)):
                return
        if converged:
            if s.optimising and s.phase == "optimising":
                s.converge()
                self._forget_direction()

    def _relocate(self, p: Array, v: Array, lm: Landmarks, others: Array) -> Asking[bool]:
        """At convergence after an adoption (if some owned landmark is unseen; once per
        adoption), or in the coverage-move stage (``max_relocations`` in all): start a transit
        to a better viewpoint for the own set if one exists."""
        s = self.s
        moves = self.in_move_stage() and self.relocations < s.cfg.max_relocations
        if not (self.relocate_armed or moves):
            return False
        self.relocate_armed = False
        each = per_landmark_cols(p, v, lm, self.s.geo.term)
        if lm.m == 0 or (not moves and bool((each > 0.0).all())):
            return False
        own = OwnState(self.s.id, p, v, np.zeros(lm.m, dtype=np.int64), lm.qT.T.copy(),
                       lm.uT.T.copy(), float(each.sum()))
        env, d_opt = s.world.environment(), self.sc.d_opt
        rev = s.ledger_rev
        goal = yield from compute(lambda: relocation_goal(own, others, env, d_opt))
        if s.ledger_rev != rev:  # found for a set we no longer own: optimise the new set
            return True  # (not converged; a new adoption armed the search again)
        if goal is None:
            return False
        self.goal, self.progress = goal, TransitProgress()
        self.relocations += 1
        _log.info("agent %s: %d owned landmarks unseen; flying to a better viewpoint "
                  "(%.2f, %.2f, %.2f), vision %.3f -> %.3f predicted", self.s.id,
                  int((each <= 0.0).sum()), *goal.p, own.vision, goal.predicted)
        return True

    def _transit(self) -> Asking[None]:
        """One step towards the goal: section 4.3 avoidance at ≤ ṗ_lim, camera turning at
        ≤ ω_lim; on arrival (or stalled) optimise again from there."""
        assert self.goal is not None
        prm, goal = self.sc.params, self.goal
        p, v, _ = self.pose.current()
        p_dot = transit_displacement(p, goal.p, prm, self.sc.space, self.others(),
                                     self.structure) / prm.dt
        tilt = self.pose.tilt_limits()  # turn to a direction the gimbal can reach
        goal_v = goal.v if tilt is None else tilt.clamp_direction(goal.v)
        axis = np.cross(v, goal_v)
        ang = float(np.arctan2(np.linalg.norm(axis), float(v @ goal_v)))
        omega = np.zeros(3)
        if ang > 1e-9 and np.linalg.norm(axis) <= 1e-12:  # facing away: turn about any
            axis = np.cross(v, [0.0, 0.0, 1.0])  # perpendicular axis, as the simulator does
            if np.linalg.norm(axis) <= 1e-12:
                axis = np.cross(v, [1.0, 0.0, 0.0])
        if ang > 1e-9:
            omega = axis / np.linalg.norm(axis) * min(ang, prm.w_lim * prm.dt) / prm.dt
        yield from self.pose.command(p_dot, omega, prm.dt)
        dist = float(np.linalg.norm(goal.p - p))
        self.progress.update(dist, ang)
        if (dist <= prm.p_min * prm.dt and ang < ALIGNED_RAD) or self.progress.stalled:
            self.goal = None
            self._forget_direction()
