"""Lost drones with real agent processes on a real Zenoh router: one agent is SIGKILLed for
good in the middle of the mission (0 and 30 % loss); the others fence it out, adopt its
landmarks and complete with every landmark owned once (checked by an observer on every
state); the lost agent, restarted late from its journal, learns it was fenced, holds nothing
and leaves with one line."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from agent.cli import main
from agent.config.parse import load_scenario
from tests.agent_helpers import random_scene_toml
from tests.conftest import reap, repo_env
from tests.test_agent_processes import InTestObserver, RouterBox, router_box

pytestmark = [pytest.mark.slow, pytest.mark.serial]
__all__ = ["router_box"]

LOST_AFTER = 20.0  #: [mission s] = 2 s at rate scale 10


def spawn(aid: str, scene: Path, endpoint: str, state: Path, *extra: str) -> subprocess.Popen[str]:
    cmd = [sys.executable, "-m", "agent.cli", "agent", "--id", aid, "--scenario", str(scene),
           "--connect", endpoint, "--state-dir", str(state / aid), "--rate-scale", "10",
           "--request-timeout", "0.15", "--timeout", "150", *extra]
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=repo_env())


@pytest.mark.parametrize(("drop", "seed"), [
    pytest.param("0.0", 3, marks=pytest.mark.long),  # make test: [0.3-4], the same but lossy
    ("0.3", 4)])
def test_agent_killed_for_good_is_adopted_and_its_late_return_resurrects_nothing(
        router_box: RouterBox, tmp_path: Path, drop: str, seed: int) -> None:
    scene = tmp_path / "scene.toml"
    scene.write_text(f"lost_after = {LOST_AFTER}\n" + random_scene_toml(4, 16, seed, dims=2))
    sc = load_scenario(scene)
    ep = router_box["endpoint"]
    ob = InTestObserver(ep, sc, sc.name)
    procs: list[subprocess.Popen[str]] = []
    try:
        survivors = [spawn(a.id, scene, ep, tmp_path, "--drop", drop, "--fault-seed",
                           str(10 * seed + i)) for i, a in enumerate(sc.agents[:3])]
        victim = spawn("N3", scene, ep, tmp_path, "--drop", drop)
        procs = [*survivors, victim]
        deadline = time.monotonic() + 60.0
        while time.monotonic() < deadline:  # every agent publishing: mid-mission
            st = ob.obs.latest.get("N3")
            if len(ob.obs.latest) == 4 and st is not None and st.counters.ok + \
                    st.counters.failed >= 1:
                break
            time.sleep(0.01)
        assert len(ob.obs.latest) == 4 and not ob.obs.done.is_set()
        victim.send_signal(signal.SIGKILL)
        victim.wait()
        assert ob.wait(120.0), "the survivors did not complete"
        rep = ob.obs.snapshot()
        assert rep.violations == []
        assert set(rep.fenced) == {"N3"}
        assert sorted(rep.owners) == sorted(sc.landmark_ids)
        assert set(rep.owners.values()) <= {"N0", "N1", "N2"}
        # The lost agent comes back from its journal: it learns the fence from the others'
        # states and leaves holding nothing; nothing it had comes back.
        back = spawn("N3", scene, ep, tmp_path)
        procs.append(back)
        _out, err = back.communicate(timeout=60)
        assert back.returncode == 0, err[-2000:]
        assert "the team declared it lost" in err
        time.sleep(0.5)
        rep = ob.obs.snapshot()
        assert rep.violations == []
        for p in survivors:
            assert p.poll() is None, "a survivor left early"
    finally:
        for p in procs:
            if p.poll() is None:
                p.send_signal(signal.SIGTERM)
        reap(procs)
        ob.close()


@pytest.mark.parametrize("stop_s", [
    0.5,
    # make test-long: make test stops the drone 0.5 s, the same seam (a peer frozen mid-trade)
    pytest.param(5.0, marks=pytest.mark.long)])
def test_sigstop_mid_trade_then_sigcont(router_box: RouterBox, tmp_path: Path,
                                        stop_s: float) -> None:
    """N3 is frozen by SIGSTOP while it has a trade pending, for less than the link lease
    (0.5 s: it stays live) and longer than ``lost_after`` (5 s: fenced while stopped). The
    mission completes every time with every landmark owned once; N3 either finishes it or
    learns it was fenced and leaves holding nothing."""
    scene = tmp_path / "scene.toml"
    scene.write_text(f"lost_after = {LOST_AFTER * 1.5}\n" + random_scene_toml(4, 16, 5, dims=2))
    sc = load_scenario(scene)
    ep = router_box["endpoint"]
    ob = InTestObserver(ep, sc, sc.name)
    procs: list[subprocess.Popen[str]] = []
    try:
        slow = ("--delay", "0.04")  # trades last a few hundred ms
        survivors = [spawn(a.id, scene, ep, tmp_path, *slow) for a in sc.agents[:3]]
        victim = spawn("N3", scene, ep, tmp_path, *slow, "--exit-on-complete")
        procs = [*survivors, victim]
        deadline = time.monotonic() + 60.0
        while time.monotonic() < deadline:
            st = ob.obs.latest.get("N3")
            if st is not None and (st.pending or st.phase in ("trading", "in_doubt")):
                break
            time.sleep(0.005)
        victim.send_signal(signal.SIGSTOP)
        time.sleep(stop_s)
        victim.send_signal(signal.SIGCONT)
        _out, err = victim.communicate(timeout=120)
        assert victim.returncode == 0, err[-2000:]
        assert ob.wait(60.0), "not complete"
        time.sleep(0.5)
        rep = ob.obs.snapshot()
        assert rep.violations == []
        fenced = "the team declared it lost" in err
        assert set(rep.fenced) == ({"N3"} if fenced else set())
        if stop_s < 1.0:
            assert not fenced
        if stop_s > 2 * LOST_AFTER * 1.5 / 10:  # well beyond lost_after [real s]
            assert fenced, err[-2000:]
        owners = rep.owners
        assert sorted(owners) == sorted(sc.landmark_ids)
        assert not fenced or "N3" not in owners.values()
    finally:
        for p in procs:
            if p.poll() is None:
                p.send_signal(signal.SIGCONT)
                p.send_signal(signal.SIGTERM)
        reap(procs)
        ob.close()


def test_a_drone_joins_a_running_mission_and_ends_with_landmarks(
        router_box: RouterBox, tmp_path: Path) -> None:
    """``viscover agent --id S1 --join-at X,Y`` while three scenario agents work: admitted by a
    majority, it trades and owns landmarks at the end; the observer sees no violation."""
    scene = tmp_path / "scene.toml"
    scene.write_text(random_scene_toml(3, 12, 6, dims=2))
    sc = load_scenario(scene)
    ep = router_box["endpoint"]
    ob = InTestObserver(ep, sc, sc.name)
    procs: list[subprocess.Popen[str]] = []
    try:
        procs = [spawn(a.id, scene, ep, tmp_path) for a in sc.agents]  # stay after completing
        deadline = time.monotonic() + 30.0
        while len(ob.obs.latest) < 3 and time.monotonic() < deadline:
            time.sleep(0.01)
        joiner = spawn("S1", scene, ep, tmp_path, "--join-at", "3.2,2.4", "--exit-on-complete")
        procs.append(joiner)
        out, err = joiner.communicate(timeout=120)
        assert joiner.returncode == 0, err[-2000:]
        s1 = json.loads(out.strip().splitlines()[-1])
        assert s1["agent"] == "S1" and len(s1["owned"]) > 0, s1
        time.sleep(0.5)
        rep = ob.obs.snapshot()
        assert rep.violations == [] and rep.joiners == ["S1"]
        with ob.obs._lock:
            claims = {a: owned for a, (owned, _held) in ob.obs.latest_claims.items()}
        owners = sorted(lid for owned in claims.values() for lid in owned)
        assert owners == sorted(sc.landmark_ids)  # each once, S1's included
        assert sorted(claims["S1"]) == sorted(s1["owned"])
    finally:
        reap(procs)
        ob.close()


def test_join_at_errors_are_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]
                                    ) -> None:
    """(``viscover agent`` called in-process: its arguments are refused before it connects.)"""
    scene = tmp_path / "scene.toml"
    scene.write_text(random_scene_toml(3, 6, 1, dims=2))
    cases = {
        ("--id", "N0", "--join-at", "1,1"): "--join-at: N0 is an agent of",
        ("--id", "S1", "--join-at", "1,1,1"): "expected 2 numbers X,Y [m] for this 2-D",
        ("--id", "S1", "--join-at", "99,0"): "outside the mission space",
        ("--id", "S1",): "--id S1: not an agent of",
    }
    for args, want in cases.items():
        status = main(["agent", "--scenario", str(scene), *args])
        err = capsys.readouterr().err
        assert status == 2, err
        lines = err.strip().splitlines()
        assert len(lines) == 1 and want in lines[0], err
