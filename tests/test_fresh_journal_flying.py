"""A flying agent whose journal is new, while the run it was in is under way, is refused in
one line before it touches its vehicle or waits for the clock, as a kinematic agent is
(:mod:`agent.runners.recovery`): its landmarks went with its old journal."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

from agent.config.parse import load_scenario
from agent.net.router import client_config
from agent.net.transport import ZenohTransport
from agent.runners.recovery import fence_record
from tests.agent_helpers import random_scene_toml
from tests.conftest import reap, repo_env, wait_until
from tests.test_adoption_processes import spawn
from tests.test_agent_processes import RouterBox, router_box

__all__ = ["router_box"]


def test_a_flying_agent_with_a_new_journal_mid_run_is_refused(
        router_box: RouterBox, tmp_path: Path) -> None:
    scene = tmp_path / "scene.toml"
    scene.write_text("lost_after = 60.0\n" + random_scene_toml(3, 12, 5, dims=2))
    sc = load_scenario(scene)
    ep = router_box["endpoint"]
    procs = [spawn(a.id, scene, ep, tmp_path, "--rate-scale", "0.5") for a in sc.agents]
    tp = ZenohTransport(client_config([ep]), None, "probe")
    try:
        def all_under_way() -> bool:  # N2 heard while N0 and N1 are live (on a loaded
            # machine they may come up after N2: then N2's run is not theirs)
            rec = fence_record(tp, sc.name, 0.5)
            return rec is not None and {"N0", "N1", "N2"} <= set(rec.seen) \
                and {"N0", "N1"} <= set(rec.alive_for)
        assert wait_until(all_under_way, 60.0)
        time.sleep(0.5)  # longer than the record's slack (OVERLAP_SLACK_S) for N0, N1
        procs[2].send_signal(signal.SIGKILL)
        procs[2].wait(10)

        t0 = time.monotonic()
        fly = subprocess.run(
            [sys.executable, "-m", "agent.cli", "agent", "--scenario", str(scene), "--id", "N2",
             "--connect", ep, "--state-dir", str(tmp_path / "new" / "N2"),
             "--mavlink", "udpout:127.0.0.1:9"],
            capture_output=True, text=True, env=repo_env(), timeout=60)
        assert procs[0].poll() is None and procs[1].poll() is None  # the run is under way
        assert fly.returncode == 2, fly.stderr[-3000:]
        rec_now = fence_record(tp, sc.name, 0.5)
        errors = [x for x in fly.stderr.splitlines() if x.startswith("viscover: error:")]
        assert len(errors) == 1 and "already heard N2 (incarnation" in errors[0], \
            (fly.stderr, rec_now)
        assert "Traceback" not in fly.stderr
        assert "vehicle" not in fly.stderr.lower().replace(errors[0].lower(), "")
        assert time.monotonic() - t0 < 30.0
    finally:
        tp.close()
        for p in procs:
            if p.poll() is None:
                p.send_signal(signal.SIGTERM)
        reap(procs)
