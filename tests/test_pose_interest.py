"""What a drone's link carries in a large team (issue 34, traffic per drone): an agent hears
the pose streams of its neighbours only (and of a moving initiator it must judge), and the
states of a team larger than STATE_PEERS + 1 come at most 2·STATE_PEERS per unstretched state
period (:mod:`agent.runtime.ends.pose_interest`, :meth:`AgentConfig.for_team`)."""

from __future__ import annotations

import msgspec
import numpy as np

from agent.config.parse import parse_scenario
from agent.runtime.core.events import Tick
from agent.runtime.core.shared import STATE_PEERS, AgentConfig
from agent.runtime.ends.pose_interest import HYSTERESIS, NEAR_MIN_M, PoseInterest
from agent.runtime.shell.pose import fix_of
from agent.testing.core_net import CoreNet
from agent.testing.memsim import MemoryMission
from agent.wire import keys
from bench.bench_trade import swarm_scene_toml
from tests.agent_helpers import fixed_motion

BASE = AgentConfig(mission="m", seed=1)


def ring(n: int, r: float, ticks: int = 0) -> CoreNet:
    """n cores standing on a circle of radius r + 3 m (the swarm scene), converged at once
    (``ticks`` 0) or optimising for ``ticks`` ticks."""
    sc = parse_scenario(swarm_scene_toml(n, 2 * n, seed=1, r=r), "<ring>")
    return CoreNet(sc, BASE, motion=fixed_motion(1, max_ticks=ticks))


def run(net: CoreNet, seconds: float) -> None:
    for _ in range(round(seconds / 0.1)):
        for aid in list(net.cores):
            net.tick(aid)
        net.clock.advance(0.1)


def starts(net: CoreNet) -> dict[str, np.ndarray]:
    return {a.id: np.asarray(a.p0, dtype=np.float64) for a in net.sc.agents}


def test_an_agent_listens_to_the_pose_streams_of_its_neighbours_only() -> None:
    net = ring(12, 13.0)  # 16 m from the centre: neighbours 8.3 m apart, the next 16 m
    run(net, 1.0)
    p0 = starts(net)
    for aid, core in net.cores.items():
        r = core.interest.radius()
        assert r == NEAR_MIN_M  # slow drones: the floor
        near = {b for b in p0 if b != aid and np.linalg.norm(p0[b] - p0[aid]) <= r}
        assert len(near) == 2 and near <= net.listening[aid], (aid, net.listening[aid])
        # the others: initiators whose offers needed their stream (their first state said
        # they moved)
        assert net.listening[aid] - near <= set(core.interest.wanted), aid


class _Peers:
    """A membership stand-in: peers' last known positions [m; world ENU]."""

    def __init__(self) -> None:
        self.others_pos: dict[str, np.ndarray] = {}


def test_a_neighbour_leaves_only_beyond_the_hysteresis_and_unchanged_sets_are_not_resent(
        ) -> None:
    core = ring(3, 8.0).cores["N0"]
    peers = _Peers()
    pi = PoseInterest(core.shared, peers)  # type: ignore[arg-type]
    r = pi.radius()
    me = np.zeros(3)
    peers.others_pos = {"A": np.array([0.9 * r, 0, 0]), "B": np.array([2.0 * r, 0, 0])}
    assert pi.update(me, 0.0) == frozenset({"A"})
    assert pi.update(me, 0.1) is None  # unchanged: no new Listen
    peers.others_pos["A"] = np.array([1.2 * r, 0, 0])  # beyond r, within 1.5 r: kept
    assert pi.update(me, 0.2) is None
    peers.others_pos["A"] = np.array([(HYSTERESIS + 0.1) * r, 0, 0])
    assert pi.update(me, 0.3) == frozenset()
    pi.want("B", 0.4)  # an offer to judge: heard although 2 r away
    assert pi.update(me, 0.4) == frozenset({"B"})
    assert pi.update(me, 0.4 + BASE.fresh_periods * BASE.state_period_s + 0.01) == frozenset()


def test_a_far_initiator_that_moves_is_asked_for_its_pose_stream_one_standing_still_is_not(
        ) -> None:
    net = ring(12, 13.0)
    run(net, 1.0)
    a = net.cores["N0"]
    far = next(b for b in net.cores if b != "N0" and b not in net.listening["N0"])
    st, at = a.members.states[far]
    now = net.clock.now()
    p, v = st.p, st.v
    assert a.server.poses.verdict(far, p, v, now) is None  # converged: its state's pose holds
    a.members.book.states[far] = (msgspec.structs.replace(st, phase="optimising"), at)
    assert a.server.poses.verdict(far, p, v, now) == "unknown"  # Busy: hear its stream first
    net.tick("N0")
    assert far in net.listening["N0"]


def test_the_state_period_of_a_large_team_stretches_and_states_keep_a_gap() -> None:
    assert BASE.for_team(STATE_PEERS + 1) is BASE
    big = BASE.for_team(21)
    k = 20 / STATE_PEERS
    assert np.isclose(big.state_period_s, BASE.state_period_s * k)
    assert np.isclose(big.state_gap_s, BASE.state_period_s * k / 2)


def test_a_drone_of_a_twenty_drone_team_hears_a_bounded_number_of_states() -> None:
    net = ring(20, 32.0, ticks=30)  # optimising 3 s, then trading: states change often
    run(net, 12.0)
    states = [s for s in net.samples if keys.kind_of(s.key) == "state"]
    per_sender = {aid: sum(keys.agent_of(s.key) == aid for s in states) for aid in net.cores}
    cfg = next(iter(net.cores.values())).cfg
    assert cfg.state_gap_s > 0
    for aid, n in per_sender.items():  # never two states closer than the gap
        assert n <= 12.0 / cfg.state_gap_s + 1, (aid, n)
    heard = (len(states) - min(per_sender.values())) / 12.0  # by any one drone, per second
    assert heard <= 2 * STATE_PEERS / BASE.state_period_s + 20 / 12.0, heard


def test_the_runtime_holds_a_subscription_for_exactly_the_peers_its_core_listens_to(
        tmp_path: object) -> None:
    sc = parse_scenario(swarm_scene_toml(12, 24, seed=1, r=13.0), "<ring>")
    mm = MemoryMission(sc, tmp_path, config=BASE)  # type: ignore[arg-type]
    try:
        for _ in range(10):
            mm.step()
        for aid, rt in mm.agents.items():
            assert set(rt._pose_subs) == rt.core.interest.listening, aid
            assert 0 < len(rt._pose_subs) < 11
        rt = mm.agents["N0"]
        rt.stop()
        assert rt._pose_subs == {}
        rt.step(Tick(mm.clock.now(), fix_of(rt.pose)))  # a tick after stop subscribes nothing
        assert rt._pose_subs == {}
    finally:
        mm.close()
