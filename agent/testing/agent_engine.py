"""The simulator driving the agents' own decisions: ``viscover simulate`` (its default engine,
``--engine agents``).

One :class:`~agent.runtime.shell.runtime.AgentRuntime` per drone on the in-memory network
(:class:`~agent.testing.memsim.MemoryMission`), in virtual time, without loss (or, with
:func:`rehearse`, under seeded faults and watched by an observer:
:mod:`agent.testing.rehearsal`): the decision
code of the agent processes, kinematic and flying (planner steps, Algorithm 7 over the trade
protocol, the coverage moves of ``potential``, an inspection's tours and re-splits), recorded
tick by tick into the simulator's :class:`~agent.sim.result.SimResult`, so that the report,
the plots and ``viscover replay`` read it as they read the simulator's. Where the lockstep
engines (:mod:`agent.sim`, ``--engine lockstep``) and the agents could differ, this shows
what the drones will do; ``bench.bench_decisions`` measures how far the two are apart.

Differences from the simulator's record: a trade's ``gain`` is computed here from the pair's
sets before and after it at the poses it was made from (the agents do not report it), and
time runs until every agent reports the mission complete (the agents' completion condition,
which holds a few state periods after the simulator's). An inspection's end is the agents':
what they captured, and what they gave up (each agent's view merged,
:mod:`agent.protocol.inspection_end`); it is complete only with every capturable landmark
captured, else (the team stopped, or the duration ran out) incomplete, and ``complete`` and
``t_complete`` of the result say so.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from agent.config.scenario import Scenario
from agent.core.vision import per_landmark
from agent.protocol.inspection_end import merge_given_up
from agent.protocol.records import CaptureRec
from agent.runtime.shell.runtime import AgentConfig
from agent.sim.kinematic import ProgressFn, record_run
from agent.sim.result import CaptureEvent, SimResult, TradeEvent
from agent.sim.run_inspection import inspection_summary
from agent.storage.journal import Journal
from agent.testing.memsim import MemoryMission
from agent.testing.rehearsal import MissionFaults, Outcome, Rehearsal
from agent.wire.peer import unpack
from agent.world.structure import coverage_by_model, resolve_structure, structure_model

Array = NDArray[np.float64]
#: The mission name (key prefix) of a simulated mission's agents.
MISSION = "simulate"


class AgentsSim:
    """A :class:`MemoryMission` seen as the simulator's drivers are (``t``, ``tick``, poses,
    visions, ``owner``), collecting the initiators' committed trades as it goes."""

    def __init__(self, scenario: Scenario, state_root: Path,
                 faults: MissionFaults | None = None) -> None:
        self.sc = scenario
        seed = scenario.seed if faults is None else faults.seed
        self.mm = MemoryMission(scenario, state_root, seed=seed,
                                faults=None if faults is None else faults.network(),
                                config=AgentConfig(mission=MISSION, seed=scenario.seed))
        #: the faults applied as it runs and the observer watching it (None: lossless)
        self.rehearsal = None if faults is None else Rehearsal(self.mm, faults, MISSION)
        self.trades: list[TradeEvent] = []
        self._seen: set[str] = set()
        self._model = None if scenario.structure is None else structure_model(scenario.structure)
        self._state: tuple[float, tuple[Array, Array, NDArray[np.intp]]] | None = None

    def _final(self) -> tuple[Array, Array, NDArray[np.intp]]:
        """Positions, directions and owners now (once per virtual time)."""
        if self._state is None or self._state[0] != self.t:
            self._state = (self.t, self.mm.final_state())
        return self._state[1]

    @property
    def t(self) -> float:
        """Virtual mission time [s]."""
        return float(self.mm.net.now)

    @property
    def done(self) -> bool:
        """Every agent reports the mission complete."""
        return self.mm.complete

    @property
    def owner(self) -> NDArray[np.intp]:
        """Owning agent index of each landmark (scenario order; -1: none)."""
        return self._final()[2]

    def positions(self) -> Array:
        """Positions (n, 3) [m; world ENU]."""
        return np.asarray(self._final()[0], dtype=np.float64)

    def directions(self) -> Array:
        """Camera directions (n, 3), unit [world ENU]."""
        return np.asarray(self._final()[1], dtype=np.float64)

    def visions(self) -> Array:
        """Each agent's vision of its own set (n,), eq. 3.4 (as the agent computes it)."""
        live = self.mm.agents
        return np.array([live[a.id].vision() if a.id in live else 0.0 for a in self.sc.agents])

    def coverage_by_model(self) -> tuple[float, float] | None:
        """Eq. 3.10 under (facing, occlusion) visibility; None without a structure."""
        if self._model is None:
            return None
        P, V, owner = self._final()
        return coverage_by_model(self._model, P, V, self.sc.q, self.sc.u, owner,
                                 self.sc.d_opt)

    def tick(self) -> None:
        """Every agent ticks once, then virtual time moves Δt; new trades are recorded with
        their gain: the pair's vision (eq. 3.8) of its sets after the trade minus before, at
        the poses after the tick (as Algorithm 7 judges a trade, at fixed poses)."""
        before = self.owner.copy()
        if self.rehearsal is not None:
            self.rehearsal.tick()
        self.mm.step()
        if self.rehearsal is not None:
            self.rehearsal.done(self.mm.complete)
        P, V, after = self._final()
        index = {a.id: i for i, a in enumerate(self.sc.agents)}
        for aid, rt in self.mm.agents.items():  # a loop over the drones
            for terms in rt.core.machine.recent:
                if terms.role != "initiator" or terms.trade_id in self._seen:
                    continue
                self._seen.add(terms.trade_id)
                given, gained = unpack(terms.given), unpack(terms.gained)
                pair = [index[aid], index.get(terms.partner, -1)]
                self.trades.append(TradeEvent(
                    t=round(self.t, 9), initiator=aid, partner=terms.partner,
                    to_partner=[] if given is None else given[0].tolist(),
                    to_initiator=[] if gained is None else gained[0].tolist(),
                    gain=self._pair_vision(P, V, after, pair)
                    - self._pair_vision(P, V, before, pair)))

    def _pair_vision(self, P: Array, V: Array, owner: NDArray[np.intp],
                     pair: list[int]) -> float:
        """Σ eq. 3.1 of each agent in ``pair`` (indices; -1: none) over its own landmarks
        under ``owner``, at poses P, V (n, 3) [m; world ENU]."""
        total = 0.0
        for i in pair:  # two drones
            if i >= 0 and (mine := owner == i).any():
                total += float(per_landmark(P[i], V[i], self.sc.q[mine], self.sc.u[mine],
                                            self.sc.d_opt).sum())
        return total

    def given_up(self) -> NDArray[np.int8]:
        """The landmarks the agents gave up (codes per landmark row of
        :mod:`agent.protocol.inspection_end`), every agent's view merged."""
        out = np.zeros(len(self.sc.landmark_ids), dtype=np.int8)
        for rt in self.mm.agents.values():  # a loop over the drones
            if (ins := rt.core.planning.inspecting) is not None:
                out = merge_given_up(out, ins.given_up)
        return out

    def captures(self) -> list[CaptureEvent]:
        """Every capture the agents journaled, in time order."""
        out = []
        for a in self.sc.agents:  # one journal per drone
            j = Journal(self.mm.root / a.id)
            try:
                out += [CaptureEvent(t=r.t, agent=a.id, landmarks=list(r.ids),
                                     position=list(r.p), direction=list(r.v),
                                     right=list(r.right), quality=list(r.quality))
                        for r in j.replay() if isinstance(r, CaptureRec)]
            finally:
                j.close()
        return sorted(out, key=lambda c: c.t)


def simulate_agents(scenario: Scenario, progress: ProgressFn | None = None) -> SimResult:
    """Run ``scenario`` with its agents' decision code in virtual time (see the module
    docstring) until every agent reports it complete or ``scenario.duration`` [s]."""
    return _run(scenario, progress, None)[0]


def rehearse(scenario: Scenario, faults: MissionFaults, progress: ProgressFn | None = None
             ) -> tuple[SimResult, Outcome]:
    """:func:`simulate_agents` under ``faults`` (:mod:`agent.testing.rehearsal`: messages
    lost, duplicated and delayed, drones lost for good), watched by an observer as a process
    mission is: the result, and the invariants and end the observer and the ledgers saw.
    Deterministic for a given scenario and ``faults`` (seed included)."""
    faults.check(scenario)
    result, outcome = _run(faults.scenario(scenario), progress, faults)
    assert outcome is not None
    return result, outcome


def _run(scenario: Scenario, progress: ProgressFn | None, faults: MissionFaults | None
         ) -> tuple[SimResult, Outcome | None]:
    sc = resolve_structure(scenario)
    outcome = None
    with tempfile.TemporaryDirectory(prefix="viscover-simulate-") as d:
        sim = AgentsSim(sc, Path(d), faults)
        try:
            result = record_run(sim, sc, progress, lambda: sim.done, sim.trades)
            given_up = sim.given_up()
            if sim.rehearsal is not None:
                outcome = sim.rehearsal.outcome()
                sim.rehearsal.close()
        finally:
            sim.mm.close()
        if sc.inspection is not None:
            result.captures = sim.captures()
            result.inspection = inspection_summary(sc, result.captures, given_up)
            if not result.inspection.complete:  # the team stopped, or the time ran out
                result.complete, result.t_complete = False, None
    return result, outcome
