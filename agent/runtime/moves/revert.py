"""The safeguard of ``strategy = "potential"`` as the agents run it: should the coverage moves
end below the score the thesis' strategy reached from the same start (a move predicts its gain
at poses a blocked transit may not reach), every agent takes back its thesis-stage set and
flies back to its thesis-stage pose.

- **Record.** When its thesis stage ends (stage 1 -> 2), or earlier when it first sees a peer
  in stage 2 (that peer's condition held, so we were quiet in our final thesis-stage state;
  its moves may soon change ours), an agent keeps its own set, pose and vision (eq. 3.8), and
  publishes that vision (``AgentState.stage1_vision``). So the records of all agents are taken
  before any move and form the thesis stage's partition.
- **Decide.** Entering the last stage (:attr:`CoverageMoves.final_stage`: the completion condition
  held in the stage before, so every live agent is converged and quiet and the states all see
  are the same) an agent compares the team's score now, Σ of the published visions (eq. 3.10),
  with Σ of the published thesis-stage visions. Below it by more than :data:`REVERT_TOL`
  relative it reverts and publishes ``reverting``; an agent that sees a peer reverting reverts
  too (the first to decide acted on the quiet states the others saw, and its pulls change
  them).
- **Revert.** It pulls back every landmark of its record that another agent owns (a pull
  names the landmarks and is given only by an agent that owns them all, to an agent that
  says it reverts: :func:`agent.protocol.regroup.pull_terms`), then flies to its recorded
  pose and optimises there. The last stage makes no coverage moves, so the team settles at the
  thesis' optimum again.

The record is journaled (``StageRec``), so a restarted agent keeps it. One restarted from a
journal without it records only if it sees a peer still in the thesis stage after the restart;
otherwise it publishes -1 (unknown), and an unknown vision anywhere in the team means no
revert.

The registered move ``revert`` (a ``holding`` move: it holds the pose while it pulls); its
state, its published fields (``stage1_vision``, ``reverting``) and the pulls it gives are its
own.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from agent.core.coverage_moves import Goal
from agent.protocol.machine import DecideFn, IntArray
from agent.protocol.records import StageRec
from agent.protocol.regroup import pull_decision, pull_terms
from agent.runtime.core.events import Asking
from agent.runtime.core.shared import Attempt, vec3
from agent.runtime.moves.move import Move, MoveContext
from agent.strategy.registry import strategy_of
from agent.wire.peer import Offer, pack_arrays, unpack

_log = logging.getLogger(f"viscover.{__name__}")

#: The moves ended below the thesis stage's score by more than this (relative): revert.
REVERT_TOL = 1e-6
#: Pull tries (each one offer) before an agent flies back with what it got.
PULL_TRIES = 40


@dataclass(frozen=True)
class Stage1:
    """An agent's own state when its thesis stage ended: pose p, v [m; world ENU], its
    landmark ids and its vision of them (eq. 3.8)."""

    p: np.ndarray
    v: np.ndarray
    ids: IntArray
    vision: float


class Revert(Move):
    """Record, decision and pulls of one agent (see the module docstring)."""

    kind = "holding"

    def __init__(self, ctx: MoveContext) -> None:
        super().__init__(ctx)
        shared = ctx.shared
        self.s, self.members, self.c_req = shared, ctx.members, ctx.c_req
        self.pose_now, self.vision, self.stages = ctx.pose_now, ctx.vision, ctx.coverage
        strategy = strategy_of(shared.sc.strategy)
        self.enabled = strategy.coverage_moves and shared.sc.trading
        self.record: Stage1 | None = None
        self.stage1_vision = -1.0  #: our vision when the thesis stage ended (-1: unknown)
        self.reverting = False  #: we take back our thesis-stage set and pose
        self.pulled = False  #: the pulls are over (the flight back has been ordered)
        self.pulls = 0  #: pulls committed
        self._attempt: Attempt | None = None
        self._tries = 0
        self._not_before = 0.0
        self._saw_stage1 = False  #: a peer in the thesis stage was seen since we started
        rec = shared.machine.stage1  # journaled before a restart
        if rec is not None and self.enabled:
            got = unpack(rec.owned)
            self.record = Stage1(np.asarray(rec.p, np.float64), np.asarray(rec.v, np.float64),
                                 np.zeros(0, np.int64) if got is None else got[0], rec.vision)
            self.stage1_vision = rec.vision
        ctx.coverage.on_stage.append(self._on_stage)

    def _on_stage(self, stage: int) -> None:
        """A stage began: the thesis stage ended (2), or the moves are over (the last)."""
        if stage == 2:
            self.record_stage1()
        elif stage == self.stages.final_stage:
            self.decide()

    def published(self) -> Mapping[str, Any]:
        """Our thesis-stage vision (eq. 3.8; -1: unknown) and whether we revert."""
        return {"stage1_vision": self.stage1_vision, "reverting": self.reverting}

    def terms(self, req: Offer) -> DecideFn | None:
        """A pull (``req.regroup.pull``), given in the coverage stages only to an agent whose
        last state says it reverts, of landmarks all ours."""
        g = req.regroup
        if g is None or not g.pull:
            return None
        entry = self.members.states.get(req.sender)
        return pull_decision(g) if self.s.stage >= 2 and entry is not None \
            and entry[0].reverting else None

    def record_stage1(self) -> None:
        """The thesis stage ended for us: keep our set, pose and vision
        (once)."""
        s = self.s
        if self.record is not None or not self.enabled:
            return
        if s.machine.incarnation > 1 and not self._saw_stage1:
            return  # restarted after the thesis stage: what it ended with is unknown here
        p, v, _ = self.pose_now()
        vis = self.vision()
        ids, vers = s.machine.owned_arrays()
        self.record = Stage1(np.asarray(p, np.float64).copy(), np.asarray(v, np.float64).copy(),
                             ids.copy(), vis)
        rec = StageRec(p=vec3(p), v=vec3(v), owned=pack_arrays(ids, vers), vision=vis)
        s.machine.apply(rec)
        s.persist([rec], sync=False)  # a restart keeps it (not for safety)
        self.stage1_vision = vis
        s.publish_soon()

    def team_scores(self) -> tuple[float, float] | None:
        """Σ of the live team's visions now and at the end of its thesis stage (eq. 3.10;
        ours and the peers' published ones); None if one is unknown."""
        s = self.s
        if self.record is None:
            return None
        now, then = self.vision(), self.record.vision
        for aid in sorted(self.members.live - s.machine.fenced - {s.id}):  # a loop over peers
            entry = self.members.states.get(aid)
            if entry is None:
                return None
            st = entry[0]
            if not (math.isfinite(st.vision) and math.isfinite(st.stage1_vision)) \
                    or st.stage1_vision < 0.0:
                return None
            now, then = now + st.vision, then + st.stage1_vision
        return now, then

    def decide(self) -> bool:
        """Entering the last stage: revert if the team's score is below its
        thesis-stage score; True if we now revert."""
        scores = self.team_scores()
        if scores is None:
            return False
        now, then = scores
        if now >= then - REVERT_TOL * abs(then):
            return False
        self._start(f"team score {now:.4f} below the thesis stage's {then:.4f}")
        return True

    def _start(self, why: str) -> None:
        s = self.s
        self.reverting = True
        s.publish_soon()
        _log.info("agent %s: reverting to its thesis-stage set and pose (%s)", s.id, why)

    def _follow(self) -> None:
        """In the last stage, a peer reverting makes us revert too."""
        s = self.s
        if self.reverting or self.record is None or s.stage < self.stages.final_stage:
            return
        for aid in sorted(self.members.live - {s.id}):  # a loop over peers
            entry = self.members.states.get(aid)
            if entry is not None and entry[0].reverting:
                self._start(f"{aid} reverts")
                return

    def step(self, now: float) -> Asking[bool]:
        """The move (the core's tick): :meth:`pull_step`, asking nothing."""
        yield from ()
        return self.pull_step(now)

    def pull_step(self, now: float) -> bool:
        """Drive the revert: the next pull, or the flight back once every landmark of the
        record is ours again; True while pulling (the agent holds its pose)."""
        s = self.s
        if s.stage == 1 and self.record is None and self.enabled:
            stages = {e[0].stage for a, e in self.members.states.items()
                      if a in self.members.live}
            self._saw_stage1 = self._saw_stage1 or 1 in stages
            if any(x >= 2 for x in stages):
                self.record_stage1()
        self._follow()
        if not self.reverting or self.pulled or self.record is None:
            return False
        att = self._attempt
        if att is not None:
            if s.attempt is att:
                return True
            self._attempt = None
            if s.machine.decided.get(att.trade_id) == "committed":
                self.pulls += 1
            else:
                self._retry(now)
        if now < self._not_before:
            return True
        if s.attempt is not None:
            return True  # an Algorithm 7 offer of ours is in flight
        ids = s.machine.owned_arrays()[0]
        missing = self.record.ids[~np.isin(self.record.ids, ids)]
        if missing.size == 0 or self._tries >= PULL_TRIES:
            return self._fly_back(missing.size)
        if not self._pull(missing, now):
            self._retry(now)
        return True

    def _retry(self, now: float) -> None:
        self._tries += 1
        self._not_before = now + self.s.cfg.backoff_s * 2.0 ** min(self._tries, 5)

    def _pull(self, missing: IntArray, now: float) -> bool:
        """Offer a pull to the first peer whose published set holds some of ``missing``
       ; False if none does."""
        s = self.s
        for aid in self.members.team_order():  # a loop over the team
            entry = self.members.states.get(aid)
            got = None if aid == s.id or entry is None else unpack(entry[0].owned)
            if got is None:
                continue
            take = np.isin(got[0], missing)
            if not take.any():
                continue
            p, v, _ = self.pose_now()
            step = s.machine.new_offer(aid, vec3(p), vec3(v), regroup=pull_terms(
                got[0][take], got[1][take], got[0], got[1]))
            s.journal(step)
            assert step.trade_id is not None
            self._attempt = Attempt(step.trade_id, aid,
                                    self.c_req.encode(step.request()), due=now,
                                    regroup=True)
            s.begin_offer(self._attempt)
            s.counters.offers_sent += 1
            return True
        return False

    def _fly_back(self, missing: int) -> bool:
        """Fly to the recorded pose and optimise there."""
        s, rec = self.s, self.record
        assert rec is not None
        self.pulled = True
        s.fly_to(Goal(rec.p, rec.v, rec.vision))
        s.success()
        _log.info("agent %s: %d pulls done (%d landmarks not back); flying to its thesis-stage "
                  "pose", s.id, self.pulls, missing)
        return False


MOVE = Revert
