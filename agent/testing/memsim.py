"""A whole mission of :class:`AgentRuntime` s on one :class:`MemoryNetwork`, in one thread,
on virtual time: deterministic for a given seed, used by the protocol tests and the bench.

Every Δt each live agent ticks (in scenario order), then the network's virtual clock moves
Δt and delivers what became due. Agents can be crashed (their in-memory state discarded, the
transport killed so their liveliness token vanishes) and restarted from their journal.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from agent.clock import ManualClock
from agent.config.scenario import AgentSpec, Scenario
from agent.mission.invariants import VersionHistory, final_violations, snapshot_violations
from agent.net.faults import FaultConfig, FaultInjector
from agent.net.memory import MemoryNetwork, MemoryTransport
from agent.runtime.shell.runtime import AgentConfig, AgentRuntime, MotionFn
from agent.storage.journal import Journal
from agent.world.prepare import prepare_world


class MemoryMission:
    """All agents of ``scenario`` on a :class:`MemoryNetwork`.

    Args:
        scenario: the mission.
        state_root: directory holding one journal directory per agent.
        faults: fault model applied by every agent's transport (None: no faults).
        seed: fault seed (each agent's injector gets ``seed`` + its index).
        config: runtime constants (mission seconds).
        motion: planner replacement (see :data:`agent.runtime.shell.runtime.MotionFn`).
        check: called after every ledger change with the mission (invariant probes).
        journal_factory: wraps journals (crash tests).
        exit_on_complete: an agent leaves once :meth:`AgentRuntime.exit_due` (as ``viscover
            agent --exit-on-complete`` does); it is then in :attr:`exited`, with its last
            ledger.
    """

    def __init__(
        self,
        scenario: Scenario,
        state_root: str | Path,
        faults: FaultConfig | None = None,
        seed: int = 0,
        config: AgentConfig | None = None,
        motion: Callable[[str], MotionFn] | None = None,
        check: Callable[[MemoryMission], None] | None = None,
        journal_factory: Callable[[str, Path], Journal] | None = None,
        autostart: bool = True,
        exit_on_complete: bool = False,
    ) -> None:
        self.sc = scenario
        self.root = Path(state_root)
        self.faults = faults
        self.seed = seed
        self.cfg = config or AgentConfig(mission="mem")
        self.motion = motion
        self.check = check
        self.journal_factory = journal_factory or (lambda _aid, d: Journal(d))
        self.world = prepare_world(scenario)  #: prepared once for every agent
        self.net = MemoryNetwork()
        self.clock = ManualClock(source=lambda: self.net.now)
        self.agents: dict[str, AgentRuntime] = {}
        self.transports: dict[str, MemoryTransport] = {}
        self.journals: dict[str, Journal] = {}
        self.history = VersionHistory()
        self.violations: list[str] = []
        self.changes = 0
        self.restarts = 0
        self._forgotten: set[str] = set()
        self.joiners: dict[str, AgentSpec] = {}  #: drones not in the scenario that joined
        self.exit_on_complete = exit_on_complete
        #: agents that left a completed mission -> their ledger (owned) when they left
        self.exited: dict[str, dict[int, int]] = {}
        #: agents crashed or gone -> their position and camera direction [m; world ENU] then
        self.last_pose: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        if autostart:
            for a in scenario.agents:
                self.start(a.id)

    # -- membership ------------------------------------------------------------------------
    def join(self, aid: str, p0: Sequence[float], v0: Sequence[float]) -> AgentRuntime:
        """Start ``aid``, a drone not in the scenario, joining at position ``p0`` [m; world
        ENU] with unit camera direction ``v0`` and no landmark (restart it with :meth:`start`)."""
        self.joiners[aid] = AgentSpec(aid, np.asarray(p0, np.float64), np.asarray(v0, np.float64),
                                      np.zeros(0, dtype=np.intp))
        return self.start(aid)

    def start(self, aid: str) -> AgentRuntime:
        """Start (or restart, from its journal) agent ``aid``."""
        ids = [a.id for a in self.sc.agents] + list(self.joiners)
        idx = ids.index(aid)
        inj = None
        if self.faults is not None:
            inj = FaultInjector(self.faults, seed=self.seed * 1000 + idx + 17 * self.restarts,
                                keep_records=False)
        tp = self.net.transport(aid, inj)
        journal = self.journal_factory(aid, self.root / aid)
        self.transports[aid], self.journals[aid] = tp, journal
        try:
            rt = AgentRuntime(
                aid, self.sc, tp, journal, self.clock, config=self.cfg,
                motion=self.motion(aid) if self.motion is not None else None,
                on_change=self._on_change, join=self.joiners.get(aid), world=self.world,
            )
            self.agents[aid] = rt
            rt.start()
        except BaseException:
            self.crash(aid)
            raise
        self._on_change(rt)
        return rt

    def crash(self, aid: str) -> None:
        """Kill ``aid``: drop its runtime (in-memory state) and transport; keep its journal."""
        if aid not in self.transports:
            return
        rt = self.agents.pop(aid, None)
        if rt is not None:  # where it was when it went (final_state of a lost drone)
            p, v, _t = rt.pose.current()
            self.last_pose[aid] = (np.array(p, dtype=np.float64), np.array(v, dtype=np.float64))
        self.net.kill(aid)
        self.transports.pop(aid, None)
        j = self.journals.pop(aid, None)
        if j is not None:
            j.close()
        self.restarts += 1

    def close(self) -> None:
        """Close every journal."""
        for aid in list(self.agents):
            self.agents[aid].stop()
        for j in self.journals.values():
            j.close()

    # -- invariants ------------------------------------------------------------------------
    @property
    def fenced(self) -> set[str]:
        """Agents some live agent knows the team fenced out (lost; their claims are void)."""
        out: set[str] = set()
        for rt in self.agents.values():
            out |= rt.core.machine.fenced
        return out

    def team(self) -> list[str]:
        """Scenario agents and joiners not fenced out."""
        fenced = self.fenced
        return [a for a in [*(x.id for x in self.sc.agents), *self.joiners] if a not in fenced]

    def claims(self) -> dict[str, tuple[dict[int, int], dict[int, int]]]:
        """Current (consistent: single thread) ledgers of the live agents not fenced out."""
        fenced = self.fenced
        return {
            aid: (dict(rt.core.machine.owned),
                  {k: v for k, (v, _t) in rt.core.machine.held.items()})
            for aid, rt in self.agents.items() if aid not in fenced
        }

    def _on_change(self, _rt: AgentRuntime) -> None:
        self.changes += 1
        for aid in self.fenced - self._forgotten:
            self.history.forget(aid)
            self._forgotten.add(aid)
        claims = self.claims()
        for aid, (owned, held) in claims.items():
            self.violations.extend(self.history.add(aid, owned, held))
        if set(self.team()) <= set(self.agents):
            found = snapshot_violations(claims, self.sc.landmark_ids)
            if self.fenced:  # orphans wait for adoption; the final check finds any left
                found = [v for v in found if not v.endswith("no claim (lost)")]
            self.violations.extend(found)
        if self.check is not None:
            self.check(self)

    def final_violations(self) -> list[str]:
        """:func:`agent.mission.observer.final_violations` on the live agents' ledgers."""
        return final_violations(self.claims(), self.sc.landmark_ids, self.history.highest)

    # -- running ---------------------------------------------------------------------------
    def step(self) -> None:
        """Tick every live agent once, then advance virtual time by Δt."""
        for aid in [*(a.id for a in self.sc.agents), *self.joiners]:
            rt = self.agents.get(aid)
            if rt is not None:
                rt.tick()
                if self.exit_on_complete and rt.exit_due(self.net.now):
                    self.exited[aid] = dict(rt.core.machine.owned)
                    rt.stop()
                    self.crash(aid)
                    self.restarts -= 1  # a departure, not a crash
        self.net.advance(self.sc.params.dt)

    @property
    def complete(self) -> bool:
        """Every scenario agent not fenced out is live and reports completion."""
        team = self.team()
        return all(a in self.exited or (a in self.agents and self.agents[a].complete)
                   for a in team)

    def run(self, max_time: float, until: Callable[[MemoryMission], bool] | None = None) -> bool:
        """Step until complete (or ``until``) or ``max_time`` virtual seconds; True if done."""
        stop = until or (lambda m: m.complete)
        while self.net.now < max_time:
            self.step()
            if stop(self):
                return True
        return False

    def final_state(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The scenario agents' positions P and camera directions V (n, 3) [m; world ENU] (a
        crashed or departed agent: where it was last) and the owner row of each landmark
        (scenario order; -1: none owns it, or only a crashed or fenced agent did; an agent
        that left the completed mission owns what it left with)."""
        sc = self.sc
        owner = np.full(len(sc.landmark_ids), -1, dtype=np.intp)
        fenced = self.fenced
        ids = np.asarray(sc.landmark_ids, dtype=np.int64)
        P, V = np.zeros((len(sc.agents), 3)), np.zeros((len(sc.agents), 3))
        for i, a in enumerate(sc.agents):  # a loop over the drones
            rt = self.agents.get(a.id)
            if rt is None:  # crashed or gone: where it was last; what it left the mission with
                P[i], V[i] = self.last_pose.get(a.id, (a.p0, a.v0))
                if a.id in self.exited and a.id not in fenced:
                    owner[np.isin(ids, np.fromiter(self.exited[a.id], dtype=np.int64))] = i
                continue
            if a.id not in fenced:
                owner[rt.core.shared.geo.rows(rt.core.machine.owned_arrays()[0])] = i
            P[i], V[i] = rt.pose.current()[:2]
        return P, V, owner

    def coverage(self) -> float:
        """Sum of the live agents' visions (each landmark counted once, held ones not)."""
        return sum(rt.vision() for rt in self.agents.values())

    def owner_of(self) -> dict[int, str]:
        """Landmark id -> owning agent (live agents)."""
        return {lid: aid for aid, rt in self.agents.items() for lid in rt.core.machine.owned}
