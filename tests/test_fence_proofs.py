"""A fence is believed only with its proof (:mod:`agent.protocol.fence_proof`): one drone's
state naming peers fenced out, with no proof or a forged one, evicts nobody; the agents
ignore it (counted) and the observer reports it as unproven, not as a fence; real lost
drones are still fenced, with proofs every agent and the observer accept. In memory (open
profile: structural checks) and with real processes on the secured router (signed ballots)."""

from __future__ import annotations

import dataclasses
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import msgspec
import pytest
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey

from agent.config.parse import load_scenario
from agent.mission.observer import Observer, fence_keys
from agent.net.pki import TeamPlan, make_team
from agent.net.router import start_router_process, stop_router_process
from agent.net.security import TeamDir, drone_name, load_signing
from agent.net.security import client_config as secure_config
from agent.net.transport import ZenohTransport
from agent.protocol.fence_proof import ballot_checker, check_proof, make_proof
from agent.runtime.shell.runtime import AgentConfig
from agent.testing.memsim import MemoryMission
from agent.wire import keys
from agent.wire.ballots import sign_ballot
from agent.wire.codec import Codec
from agent.wire.peer import (
    AgentState,
    Counters,
    FenceBallot,
    FenceProof,
    Publication,
    pack,
)
from agent.wire.signed import SigningKeys
from tests.agent_helpers import fixed_motion, random_scene, random_scene_toml
from tests.conftest import reap, repo_env, wait_until
from tests.test_adoption_memory import LOST_AFTER, assert_every_landmark_owned_once

PUB: Codec[Publication] = Codec(Publication)
TEAM5 = ["N0", "N1", "N2", "N3", "N4"]
VICTIMS = ["N0", "N1"]  #: the hostile N4 says the team fenced these out


def ballot(voter: str, epoch: int = 8, coordinator: str = "N2",
           fenced: list[str] | None = None) -> FenceBallot:
    return FenceBallot(voter=voter, epoch=epoch, coordinator=coordinator,
                       fenced=VICTIMS if fenced is None else fenced)


def proof(*ballots: FenceBallot) -> FenceProof:
    return FenceProof(epoch=8, coordinator="N2", fenced=VICTIMS, ballots=list(ballots))


#: the forged proofs a hostile drone attaches to its claim (open profile: unsigned)
FORGED: dict[str, list[FenceProof]] = {
    "no_proof": [],
    "too_few_votes": [proof(ballot("N3"), ballot("N4"))],
    "votes_of_another_round": [proof(ballot("N2"), ballot("N3"), ballot("N4", epoch=7))],
    "duplicate_voters": [proof(ballot("N4"), ballot("N4"), ballot("N3"))],
    "voters_in_F": [proof(ballot("N0"), ballot("N3"), ballot("N4"))],
}


def test_check_proof_structure_and_signatures() -> None:
    """Every forged proof is refused, for its reason; a majority of distinct team members
    naming the round passes the open profile's structural check, and on the secured one only
    ballots signed by their voter's key count."""
    reasons = {k: check_proof(p[0], TEAM5, None) for k, p in FORGED.items() if p}
    assert reasons == {"too_few_votes": "2 valid votes of a team of 5: no majority",
                       "votes_of_another_round": "ballot of N4 for another round or fence",
                       "duplicate_voters": "a voter twice",
                       "voters_in_F": "a fenced agent votes"}
    good = proof(ballot("N2"), ballot("N3"), ballot("N4"))
    assert check_proof(good, TEAM5, None) is None
    assert "no majority" in str(check_proof(good, [*TEAM5, "N5", "N6"], None))
    priv = {a: Ed25519PrivateKey.generate() for a in TEAM5}
    team = {a: k.public_key() for a, k in priv.items()}
    check = ballot_checker(team, "m")

    def signed(voter: str, key_of: str) -> bytes:
        return sign_ballot(SigningKeys(voter, priv[key_of], team), "m", 8, "N2", VICTIMS)

    honest = make_proof(8, "N2", VICTIMS, {v: signed(v, v) for v in ("N2", "N3", "N4")})
    assert check_proof(honest, TEAM5, check) is None
    assert check_proof(honest, TEAM5, ballot_checker(team, "other mission")) is not None
    forged = make_proof(8, "N2", VICTIMS, {v: signed(v, "N4") for v in ("N2", "N3", "N4")})
    assert check_proof(forged, TEAM5, None) is None  # what the open profile cannot see
    assert check_proof(forged, TEAM5, check) == "1 valid votes of a team of 5: no majority"


@pytest.mark.parametrize("forgery", sorted(FORGED))
def test_a_hostile_state_naming_peers_fenced_evicts_nobody(tmp_path: Path,
                                                           forgery: str) -> None:
    """N4 publishes its genuine states with N0 and N1 named fenced out (and a forged proof)
    for 3 mission seconds: N0 and N1 keep their ledgers, nobody refuses them, the mission
    completes with every landmark owned once; the agents count the claim, the observer
    reports it as unproven and voids nothing."""
    sc = dataclasses.replace(random_scene(5, 25, 21), lost_after=LOST_AFTER)
    m = MemoryMission(sc, tmp_path, seed=21, motion=fixed_motion(21),
                      config=AgentConfig(mission="mem", seed=21))
    ob = Observer(m.net.transport("observer"), "mem", TEAM5, list(sc.landmark_ids))
    try:
        m.run(0.3, until=lambda _m: False)
        hostile = m.agents["N4"]
        while m.net.now < 3.3:
            st = msgspec.structs.replace(hostile.state_message(), fenced=VICTIMS,
                                         fence_epoch=8, fence_proofs=FORGED[forgery])
            m.transports["N4"].publish(keys.state_key("mem", "N4"), PUB.encode(st))
            m.step()
        assert all(m.agents[v].core.machine.fenced_out is None for v in VICTIMS)
        assert m.fenced == set()
        assert m.agents["N0"].core.rejects.by_reason["unproven_fence"] > 0
        assert m.run(400.0), f"not complete after {m.net.now:.0f} s"
        assert all(m.agents[v].core.machine.fenced_out is None and m.agents[v].core.machine.owned
                   for v in VICTIMS)
        assert m.fenced == set() and m.violations == [] and m.final_violations() == []
        assert_every_landmark_owned_once(m)
        m.run(m.net.now + 1.0, until=lambda _m: False)
        rep = ob.snapshot()
        assert rep.fenced == {} and rep.violations == [] and rep.complete
        assert rep.unproven == ["N4: N0", "N4: N1"]
    finally:
        ob.close()
        m.close()


def test_a_lost_agent_is_fenced_with_a_proof_in_memory(tmp_path: Path) -> None:
    """N3 of four dies: the survivors fence it with a proof (votes of three of four), each
    publishes it, the observer accepts it and reports nothing unproven."""
    sc = dataclasses.replace(random_scene(4, 16, 22), lost_after=LOST_AFTER)
    m = MemoryMission(sc, tmp_path, seed=22, motion=fixed_motion(22),
                      config=AgentConfig(mission="mem", seed=22))
    ob = Observer(m.net.transport("observer"), "mem", [a.id for a in sc.agents],
                  list(sc.landmark_ids))
    try:
        m.run(0.5, until=lambda _m: False)
        m.crash("N3")
        assert m.run(400.0)
        m.run(m.net.now + 1.0, until=lambda _m: False)
        for aid in ("N0", "N1", "N2"):
            st = m.agents[aid].state_message()
            assert st.fenced == ["N3"] and len(st.fence_proofs) == 1
            assert check_proof(st.fence_proofs[0], [a.id for a in sc.agents], None) is None
        rep = ob.snapshot()
        assert set(rep.fenced) == {"N3"} and rep.unproven == [] and rep.violations == []
    finally:
        ob.close()
        m.close()


# -- the secured profile, real processes --------------------------------------------------------

SECURE_LOST_AFTER = 20.0  #: [mission s] = 2 s at rate scale 10


@pytest.fixture(scope="module")
def team5(tmp_path_factory: pytest.TempPathFactory) -> TeamDir:
    return make_team(TeamPlan(tmp_path_factory.mktemp("team5"), TEAM5))


@pytest.fixture
def secure_router(team5: TeamDir) -> Iterator[str]:
    proc, endpoint = start_router_process(team=team5)
    yield endpoint
    stop_router_process(proc)


def spawn(aid: str, scene: Path, endpoint: str, state: Path, team: TeamDir) -> \
        subprocess.Popen[str]:
    cmd = [sys.executable, "-m", "agent.cli", "agent", "--id", aid, "--scenario", str(scene),
           "--connect", endpoint, "--state-dir", str(state / aid), "--rate-scale", "10",
           "--request-timeout", "0.15", "--timeout", "150", "--tls-dir", str(team.path)]
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=repo_env())


def forged_state(sc_initial: list[int], seq: int) -> AgentState:
    """N3's state as the hostile drone publishes it: its scenario set, converged, and N0, N1
    fenced out with a proof of three ballots all signed with N3's own key."""
    return AgentState(
        sender="N3", incarnation=1, seq=seq, t=0.0, p=(0.0, 0.0, 0.0), v=(1.0, 0.0, 0.0),
        phase="converged", owned=pack(dict.fromkeys(sc_initial, 0)), held=pack({}),
        vision=0.0, counters=Counters(), partners=[], pending=[], trades_with={},
        fenced=VICTIMS, fence_epoch=8, fence_proofs=[])


@pytest.mark.slow
@pytest.mark.serial
def test_secured_a_forged_fence_evicts_nobody_and_a_lost_drone_is_fenced_with_proof(
        team5: TeamDir, secure_router: str, tmp_path: Path) -> None:
    """Five drones on the secured router. N3 is never started as an agent: the test holds
    its certificate and signing key and publishes N3's states naming N0 and N1 fenced out,
    with a proof whose ballots of N2 and N4 are signed with N3's key. N4 runs and is killed
    mid-mission. Nobody believes N3's fence: N0 and N1 keep working to the end; N3 (gone
    since it never ran) and N4 are fenced by the real majority with proofs that the
    survivors publish and the observer (given the team's keys) accepts; N3's claim is
    reported as unproven; every landmark is owned once by N0, N1, N2."""
    scene = tmp_path / "scene.toml"
    scene.write_text(f"lost_after = {SECURE_LOST_AFTER}\n"
                     + random_scene_toml(5, 20, 23, dims=2))
    sc = load_scenario(scene)
    obs_tp = ZenohTransport(secure_config(team5, [secure_router], "observer"), None, "obs")
    ob = Observer(obs_tp, sc.name, TEAM5, list(sc.landmark_ids), initial=sc.initial_sets(),
                  fence_keys=fence_keys(team5.path))
    evil = ZenohTransport(secure_config(team5, [secure_router], drone_name("N3")), None, "N3")
    n3 = load_signing(team5, "N3")
    sigs = {v: sign_ballot(SigningKeys(v, n3.private, n3.team), sc.name, 8, "N2", VICTIMS)
            for v in ("N2", "N3", "N4")}
    forged_proof = make_proof(8, "N2", VICTIMS, sigs)
    initial = [int(x) for x in sc.initial_sets()["N3"]]
    stop = threading.Event()

    def forge() -> None:
        seq = 0
        while not stop.is_set():
            seq += 1
            st = msgspec.structs.replace(forged_state(initial, seq),
                                         fence_proofs=[forged_proof])
            evil.publish(keys.state_key(sc.name, "N3"), PUB.encode(st))
            stop.wait(0.1)

    forger = threading.Thread(target=forge, daemon=True)
    procs: list[subprocess.Popen[str]] = []
    try:
        procs = [spawn(a, scene, secure_router, tmp_path, team5) for a in ("N0", "N1", "N2")]
        victim = spawn("N4", scene, secure_router, tmp_path, team5)
        procs.append(victim)
        forger.start()
        assert wait_until(lambda: set(ob.latest) >= {"N0", "N1", "N2", "N4"}, 60.0)
        victim.send_signal(signal.SIGKILL)
        victim.wait()
        assert ob.done.wait(120.0), "the survivors did not complete"
        stop.set()
        forger.join()
        time.sleep(0.5)
        rep = ob.snapshot()
        assert rep.violations == []
        assert set(rep.fenced) == {"N3", "N4"}
        assert "N3: N0" in rep.unproven and "N3: N1" in rep.unproven
        assert sorted(rep.owners) == sorted(sc.landmark_ids)
        assert set(rep.owners.values()) <= {"N0", "N1", "N2"}
        assert {"N0", "N1"} <= set(rep.owners.values())
        for aid in ("N0", "N1", "N2"):  # every survivor accepted and publishes the proofs
            st = ob.latest[aid]
            assert set(st.fenced) == {"N3", "N4"} and st.fence_proofs
            assert st.counters.rejected > 0  # N3's claim, counted
        for p in procs[:3]:
            assert p.poll() is None, "a survivor left"
    finally:
        stop.set()
        for p in procs:
            if p.poll() is None:
                p.send_signal(signal.SIGTERM)
        reap(procs)
        ob.close()
        obs_tp.close()
        evil.close()
