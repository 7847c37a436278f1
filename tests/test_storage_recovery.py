"""Storage faults with real processes (issue 21, item 7): a real full disk (a small tmpfs
mounted in a private mount namespace) at start and in the middle of the mission ends the
agent in one line with its exit status, never an ``OSError`` traceback; a journal whose last
complete record is damaged is refused (not taken for a torn write), and so is a drone whose
journal was moved away: it stays out, the team fences it and adopts its landmarks, and the
observer sees nothing lost or doubled."""

from __future__ import annotations

import os
import shlex
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from agent.config.parse import load_scenario
from tests.agent_helpers import random_scene_toml
from tests.conftest import reap, repo_env, wait_until
from tests.test_adoption_processes import spawn
from tests.test_agent_processes import InTestObserver, RouterBox, router_box

pytestmark = [pytest.mark.serial]
__all__ = ["router_box"]

LOST_AFTER = 20.0  #: [mission s] = 2 s at rate scale 10


def _namespace() -> list[str]:
    """The ``unshare`` prefix that gives a private mount namespace (skip if there is none)."""
    unshare = shutil.which("unshare")
    if unshare is None:
        pytest.skip("no unshare: cannot mount a tmpfs")
    pre = [unshare, "--mount", "--propagation", "private"] if os.geteuid() == 0 else \
        [unshare, "--user", "--map-root-user", "--mount"]
    probe = subprocess.run([*pre, "sh", "-c", "mount -t tmpfs -o size=64k tmpfs /mnt"],
                           capture_output=True, text=True)
    if probe.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {probe.stderr.strip()}")
    return pre


def agent_on_tmpfs(disk: Path, aid: str, scene: Path, endpoint: str, trigger: Path | None,
                   *extra: str) -> subprocess.Popen[str]:
    """Agent ``aid`` with its journal on a 256 KiB tmpfs at ``disk``, mounted in a private
    namespace; the disk is filled before it starts (``trigger`` None) or once the file
    ``trigger`` appears (mid-mission)."""
    state = disk / aid
    agent = [sys.executable, "-m", "agent.cli", "agent", "--id", aid, "--scenario", str(scene),
             "--connect", endpoint, "--state-dir", str(state), "--rate-scale", "10",
             "--request-timeout", "0.15", "--timeout", "60", *extra]
    fill = f"dd if=/dev/zero of={disk}/fill bs=4k 2>/dev/null"
    run = shlex.join(agent)
    if trigger is None:
        body = f"mkdir -p {state} && {fill}; exec {run}"
    else:
        body = (f"{run} & pid=$!; while [ ! -e {trigger} ]; do sleep 0.05; done; {fill}; "
                "wait $pid")
    script = f"mount -t tmpfs -o size=256k tmpfs {disk} && {body}"
    disk.mkdir(parents=True, exist_ok=True)
    return subprocess.Popen([*_namespace(), "sh", "-c", script], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=repo_env())


def _one_line_error(err: str, want: str) -> None:
    assert "Traceback" not in err and "OSError" not in err, err[-3000:]
    errors = [x for x in err.splitlines() if x.startswith("viscover: error:")]
    assert len(errors) == 1 and want in errors[0], err[-3000:]


def test_a_full_disk_at_start_is_one_line(router_box: RouterBox, tmp_path: Path) -> None:
    scene = tmp_path / "scene.toml"
    scene.write_text(random_scene_toml(3, 9, 1, dims=2))
    p = agent_on_tmpfs(tmp_path / "disk", "N0", scene, router_box["endpoint"], None)
    _out, err = p.communicate(timeout=60)
    assert p.returncode == 2, err[-3000:]
    _one_line_error(err, "cannot write its header (No space left on device)")


@pytest.mark.long  # ~25 s waiting for the journal's last tmpfs page to fill: make test-long
def test_a_disk_filling_mid_mission_is_one_line_and_loses_nothing(
        router_box: RouterBox, tmp_path: Path) -> None:
    """N3's disk fills in the middle of the mission: it leaves with one line (exit 1); the
    others fence it after lost_after and adopt its landmarks; nothing lost or doubled."""
    scene = tmp_path / "scene.toml"
    scene.write_text(f"lost_after = {LOST_AFTER}\n" + random_scene_toml(4, 16, 7, dims=2))
    sc = load_scenario(scene)
    ep = router_box["endpoint"]
    ob = InTestObserver(ep, sc, sc.name)
    trigger = tmp_path / "fill-now"
    procs: list[subprocess.Popen[str]] = []
    try:
        victim = agent_on_tmpfs(tmp_path / "disk", "N3", scene, ep, trigger)
        procs = [victim, *(spawn(a.id, scene, ep, tmp_path, "--exit-on-complete")
                           for a in sc.agents[:3])]
        assert wait_until(lambda: len(ob.obs.latest) == 4, 60.0)
        trigger.touch()
        _out, err = victim.communicate(timeout=60)
        assert victim.returncode == 1, err[-3000:]
        _one_line_error(err, "cannot write (No space left on device)")
        for p in procs[1:]:
            _o, e = p.communicate(timeout=90)
            assert p.returncode == 0, e[-2000:]
        rep = ob.obs.snapshot()
        assert rep.complete and rep.violations == [], rep.violations
        owners = rep.owners
        assert sorted(owners) == sorted(sc.landmark_ids)  # each landmark owned once
        assert set(rep.fenced) <= {"N3"} and (not rep.fenced or "N3" not in owners.values())
    finally:
        reap(procs)
        ob.close()


def _last_frame(data: bytes) -> int:
    pos = last = 0
    while pos + 8 <= len(data):
        last = pos
        pos += 8 + int.from_bytes(data[pos:pos + 4], "little")
    return last


def test_a_damaged_journal_keeps_the_drone_out_and_the_team_adopts(
        router_box: RouterBox, tmp_path: Path) -> None:
    """N3 traded, then died; a bit of its last (complete) journal record flips. Restarted,
    it refuses in one line (not a torn write: never dropped); moved away, the journal's
    replacement is refused too (the router heard N3). N3 stays out: the team fences it and
    adopts its landmarks; every landmark owned once, no violation."""
    scene = tmp_path / "scene.toml"
    scene.write_text(f"lost_after = {LOST_AFTER}\n" + random_scene_toml(4, 16, 3, dims=2))
    sc = load_scenario(scene)
    ep = router_box["endpoint"]
    ob = InTestObserver(ep, sc, sc.name)
    procs: list[subprocess.Popen[str]] = []
    try:
        survivors = [spawn(a.id, scene, ep, tmp_path) for a in sc.agents[:3]]
        victim = spawn("N3", scene, ep, tmp_path)
        procs = [*survivors, victim]

        def traded() -> bool:  # mid-mission: N3 made or refused an offer
            st = ob.obs.latest.get("N3")
            return st is not None and st.counters.ok + st.counters.failed >= 1

        assert wait_until(traded, 60.0) and not ob.obs.done.is_set()
        victim.send_signal(signal.SIGKILL)
        victim.wait()
        journal = tmp_path / "N3" / "journal.bin"
        data = bytearray(journal.read_bytes())
        data[_last_frame(bytes(data)) + 9] ^= 0x04  # a complete record, one bit
        journal.write_bytes(bytes(data))
        back = spawn("N3", scene, ep, tmp_path)
        procs.append(back)
        _out, err = back.communicate(timeout=60)
        assert back.returncode == 2, err[-3000:]
        _one_line_error(err, "the last one, is complete but damaged")
        assert journal.read_bytes() == bytes(data)  # kept as it was
        # Moved away, as the old advice said: the new journal is refused too.
        journal.rename(tmp_path / "N3" / "journal.damaged")
        again = spawn("N3", scene, ep, tmp_path)
        procs.append(again)
        _out, err = again.communicate(timeout=60)
        assert again.returncode == 2, err[-3000:]
        _one_line_error(err, "already heard N3 (incarnation")
        assert ob.wait(90.0), "the team did not complete"
        time.sleep(0.5)
        rep = ob.obs.snapshot()
        assert rep.violations == [] and set(rep.fenced) == {"N3"}
        assert sorted(rep.owners) == sorted(sc.landmark_ids)
        assert set(rep.owners.values()) <= {"N0", "N1", "N2"}
    finally:
        for p in procs:
            if p.poll() is None:
                p.send_signal(signal.SIGTERM)
        reap(procs)
        ob.close()
