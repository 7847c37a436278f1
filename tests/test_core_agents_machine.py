"""Stateful property test of whole agent cores (issue 19): three
:class:`~agent.runtime.core.AgentCore` s of a random scene stepped by hand over the model
network of :mod:`agent.testing.core_net`, with no transport, thread or journal file.

Rules: an agent ticks (its asks' queries and replies lost or duplicated, its publications lost
or duplicated, each by the rule's own chances); time passes; any query or publication ever
sent is delivered again; an agent crashes and restarts from its journal (a process crash, or a
power loss that drops the records not fsynced).

After every step: the ownership invariants hold on the cores' ledgers (no landmark lost or
owned twice, one claimant at the highest version, each (landmark, version) created once), and
every step's effects put the records to persist before any message. At the end the network
heals: the team completes with every landmark owned by exactly one agent.
"""

from __future__ import annotations

import random

from hypothesis import HealthCheck, event, settings
from hypothesis import strategies as st
from hypothesis.stateful import RuleBasedStateMachine, initialize, invariant, rule

from agent.mission.invariants import final_violations
from agent.runtime.shared import AgentConfig
from agent.testing.core_net import LOSSLESS, CoreNet, Fate
from tests.agent_helpers import fixed_motion, random_scene

AGENTS = ("N0", "N1", "N2")
AGENT = st.sampled_from(AGENTS)
INDEX = st.integers(min_value=0, max_value=255)
CHANCE = st.sampled_from([0.0, 0.0, 0.3, 0.7])
#: mission seconds until the healed team must have completed
HEAL_S = 120.0


class AgentCores(RuleBasedStateMachine):
    """Cores, network and faults as rules; ownership invariants as invariants."""

    net: CoreNet

    @initialize(seed=st.integers(min_value=0, max_value=3), ticks=st.integers(0, 3))
    def start(self, seed: int, ticks: int) -> None:
        sc = random_scene(len(AGENTS), 9, seed)
        self.net = CoreNet(sc, AgentConfig(mission="m", seed=seed),
                           motion=fixed_motion(seed, max_ticks=ticks))

    @rule(aid=AGENT, seed=INDEX, loss=CHANCE, dup=CHANCE)
    def tick(self, aid: str, seed: int, loss: float, dup: float) -> None:
        self.net.tick(aid, Fate(random.Random(seed), loss, dup))

    @rule(dt=st.sampled_from([0.1, 0.5, 2.0]))
    def time_passes(self, dt: float) -> None:
        self.net.clock.advance(dt)

    @rule(aid=AGENT, power=st.booleans())
    def crash(self, aid: str, power: bool) -> None:
        self.net.crash(aid, power)

    @rule(index=INDEX)
    def replay_query(self, index: int) -> None:
        self.net.replay_query(index)

    @rule(index=INDEX)
    def replay_sample(self, index: int) -> None:
        self.net.replay_sample(index)

    @invariant()
    def ownership(self) -> None:
        assert self.net.violations() == []

    def teardown(self) -> None:
        net = getattr(self, "net", None)
        if net is None:
            return
        dt = net.sc.params.dt
        end = net.clock.now() + HEAL_S
        while net.clock.now() < end and not all(c.completion.complete
                                                for c in net.cores.values()):
            for aid in AGENTS:
                net.tick(aid, LOSSLESS)
            net.clock.advance(dt)
        assert all(c.completion.complete for c in net.cores.values()), {
            aid: c.completion_blocker(net.clock.now()) for aid, c in net.cores.items()}
        assert final_violations(net.claims(), net.sc.landmark_ids, net.history.highest) == []
        assert net.order_violations == []
        machines = [c.shared.machine for c in net.cores.values()]
        event(f"trades committed: {min(3, sum(m.ok for m in machines))}+")
        event(f"restarts: {min(2, sum(m.incarnation - 1 for m in machines))}+")


AgentCores.TestCase.settings = settings(
    max_examples=25, stateful_step_count=30, deadline=None,
    suppress_health_check=[HealthCheck.too_slow])
test_agent_cores = AgentCores.TestCase
