"""The responder checks the pose in an offer (issue 21, item 2): a drone holding a stolen
team certificate and signing key offers from a made-up pose in front of another drone's
landmark; the offer is refused and counted, and nothing is lost (real processes on the
secured router, an observer given the team's keys). The check itself: against the pose the
initiator publishes, and against the ground station's mocap of it where there is one."""

from __future__ import annotations

import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from agent.mission.observer import Observer, fence_keys
from agent.net.pki import TeamPlan, make_team
from agent.net.router import start_router_process, stop_router_process
from agent.net.security import TeamDir, drone_name, load_signing
from agent.net.security import client_config as secure_config
from agent.net.transport import ZenohTransport
from agent.runtime.core.shared import vec3
from agent.runtime.shell.runtime import AgentConfig
from agent.testing.memsim import MemoryMission
from agent.wire import keys
from agent.wire.codec import Codec
from agent.wire.ground import MOCAP_CODEC, MocapPose
from agent.wire.peer import Commit, Offer, Refused, Reply, Request, pack
from agent.wire.signed import REASON_STALE, Refusal, TradeSeal
from tests.agent_helpers import fixed_motion, random_scene, thesis
from tests.conftest import reap, repo_env, scenario_path, wait_until

REQ: Codec[Request] = Codec(Request)
REP: Codec[Reply] = Codec(Reply)
SC = thesis("hexagon_5_3")  # A owns 3 and 6


@pytest.fixture(scope="module")
def team(tmp_path_factory: pytest.TempPathFactory) -> TeamDir:
    return make_team(TeamPlan(tmp_path_factory.mktemp("team"), ["A", "B", "C"]))


@pytest.fixture
def secure_router(team: TeamDir) -> Iterator[str]:
    proc, endpoint = start_router_process(team=team)
    yield endpoint
    stop_router_process(proc)


def spawn(aid: str, endpoint: str, state: Path, team: TeamDir) -> subprocess.Popen[str]:
    cmd = [sys.executable, "-m", "agent.cli", "agent", "--id", aid, "--scenario",
           str(scenario_path("hexagon_5_3")), "--connect", endpoint, "--state-dir",
           str(state / aid), "--rate-scale", "10", "--request-timeout", "0.15", "--timeout",
           "120", "--tls-dir", str(team.path)]
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=repo_env())


def ask(tp: ZenohTransport, seal: TradeSeal, to: str, req: Request) -> Reply | None:
    """One signed request (asked again once if the receiver answers with its incarnation)."""
    for _ in range(2):
        data, nonce = seal.seal_request(REQ.encode(req), to)
        raw = tp.request(keys.trade_key(M, to), data, 1.0)
        if raw is None:
            return None
        body = seal.open_reply(raw, to, nonce)
        if isinstance(body, Refusal):
            if body.reason == REASON_STALE:
                continue
            return None
        return REP.decode(body)
    return None


M = "hexagon_5_3"


@pytest.mark.serial
# make test-long: make test runs the same insider (a drone's certificate and signing key) offering
# from made-up poses in test_hostile_insider.py, and the pose check alone in test_hostile_offers.py
@pytest.mark.long
def test_a_stolen_key_offering_from_a_made_up_pose_takes_nothing(
        team: TeamDir, secure_router: str, tmp_path: Path) -> None:
    obs_tp = ZenohTransport(secure_config(team, [secure_router], "observer"), None, "obs")
    ob = Observer(obs_tp, M, ["A", "B", "C"], list(SC.landmark_ids),
                  initial=SC.initial_sets(), fence_keys=fence_keys(team.path))
    thief = ZenohTransport(secure_config(team, [secure_router], drone_name("C")), None, "C2")
    seal = TradeSeal(load_signing(team, "C"), M)  # C's signing key, stolen
    procs: list[subprocess.Popen[str]] = []
    try:
        procs = [spawn(a, secure_router, tmp_path, team) for a in "ABC"]
        assert ob.done.wait(90.0), "the mission did not complete"
        a_owned = sorted(ob.latest_claims["A"][0])
        target = a_owned[0]
        j = SC.landmark_ids.index(target)
        p = SC.q[j] + SC.d_opt * SC.u[j]  # right in front of A's landmark, looking at it
        v = -SC.u[j]
        before = ob.latest["A"].counters.rejected
        offer = Offer(sender="C", trade_id="C:1:900", p=vec3(p), v=vec3(v), owned=pack({}))
        reply = None
        deadline = time.monotonic() + 10.0
        while reply is None and time.monotonic() < deadline:
            reply = ask(thief, seal, "A", offer)
        assert isinstance(reply, Refused) and reply.reason == "pose_mismatch", reply
        commit = ask(thief, seal, "A", Commit(sender="C", trade_id="C:1:900"))
        assert isinstance(commit, Refused), commit  # nothing was prepared: nothing to commit
        assert wait_until(lambda: ob.latest["A"].counters.rejected > before, 5.0)
        time.sleep(6.0)  # longer than the observer's "lost" bound (5 s)
        rep = ob.snapshot()
        assert rep.violations == [], rep.violations
        assert sorted(ob.latest_claims["A"][0]) == a_owned
        owners = sorted(lid for owned, _h in ob.latest_claims.values() for lid in owned)
        assert owners == sorted(SC.landmark_ids)  # each once
        for proc in procs:
            assert proc.poll() is None, "an agent left"
    finally:
        reap(procs)
        ob.close()
        obs_tp.close()
        thief.close()


def test_the_check_uses_published_poses_and_the_mocap(tmp_path: Path) -> None:
    """In memory: an offer within the tolerance of the pose its initiator publishes passes,
    one 2 m off is refused, one from an initiator never heard is asked again later; with a
    fresh mocap of the initiator, the mocap decides (a consistent forged publication does
    not help)."""
    sc = random_scene(3, 9, 2)
    m = MemoryMission(sc, tmp_path, motion=fixed_motion(2),
                      config=AgentConfig(mission="mem"))
    try:
        m.run(1.0, until=lambda _m: False)
        rt = m.agents["N0"]
        check = rt.core.server.poses
        with rt.turn:
            p1, v1, _ = rt.core.members.poses["N1"]
            now = m.net.now
            at = vec3(p1)
            off = vec3(p1 + np.array([2.0, 0.0, 0.0]))
            vv = vec3(v1)
            assert check.verdict("N1", at, vv, now) is None
            assert "2.00 m" in str(check.verdict("N1", off, vv, now))
            assert check.verdict("N9", at, vv, now) == "unknown"
            assert check.verdict("N1", at, vv, now + 100.0) == "unknown"
        mocap = MocapPose(drone="N1", seq=1, t=0.0, p=[float(x) for x in off],
                          q=[1.0, 0.0, 0.0, 0.0], v=[0.0, 0.0, 0.0])
        check.on_mocap(keys.mocap_key("mem", "N1"), MOCAP_CODEC.encode(mocap))
        with rt.turn:
            assert "mocap" in str(check.verdict("N1", at, vv, now))
            assert check.verdict("N1", off, vv, now) is None
        assert m.run(200.0)  # honest offers still pass: the mission completes
        assert m.violations == [] and m.final_violations() == []
        assert sum(rt.core.rejects.by_reason["pose_mismatch"] for rt in m.agents.values()) == 0
    finally:
        m.close()
