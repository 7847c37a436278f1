"""The flight stack as separate processes: router, ground station (simulator) and one
``viscover fly`` process; SIGTERM makes the drone land before the process exits."""

from __future__ import annotations

import signal
import subprocess
import sys
import time

from agent.net.router import client_config, start_router_process, stop_router_process
from agent.net.transport import ZenohTransport
from agent.wire.ground import MOCAP_CODEC, MocapPose
from tests.conftest import repo_env, scenario_path

CUBE = scenario_path("cube_6_2")


def _stop(proc: subprocess.Popen[str]) -> None:
    if proc.poll() is None:
        proc.kill()
        proc.wait(5)
    for stream in (proc.stdout, proc.stderr):
        if stream is not None:
            stream.close()


def test_sigterm_lands_the_drone_before_the_process_exits() -> None:
    router, endpoint = start_router_process()
    env = repo_env()
    gs = subprocess.Popen(
        [sys.executable, "-m", "agent.cli", "groundstation", "--source", "sim", "--scenario",
         str(CUBE), "--connect", endpoint, "--time-scale", "3", "--ports", "A=0,B=0,C=0"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    procs = [gs]
    obs = None
    try:
        assert gs.stdout is not None
        ready = gs.stdout.readline()
        port = int(ready.split("A=udp:")[1].split()[0].rsplit(":", 1)[1])
        obs = ZenohTransport(client_config(endpoint), None, "observer")
        poses: list[MocapPose] = []

        def on_pose(k: str, p: bytes) -> None:
            msg = MOCAP_CODEC.decode(p, k)
            if msg is not None:
                poses.append(msg)

        obs.subscribe("viscover/cube_6_2/mocap/A", on_pose)
        fly = subprocess.Popen(
            [sys.executable, "-m", "agent.cli", "fly", "--scenario", str(CUBE), "--id", "A",
             "--mavlink", f"udpout:127.0.0.1:{port}", "--connect", endpoint,
             "--mocap-stale", "0.5"],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
        procs.append(fly)
        assert fly.stdout is not None
        line = fly.stdout.readline()
        assert line.strip() == "viscover-fly hovering id=A", fly.stderr.read() if fly.stderr else ""
        p = poses[-1].p
        assert abs(p[0] + 1.0) < 0.15 and abs(p[1] + 1.0) < 0.15 and abs(p[2] - 0.75) < 0.15
        fly.send_signal(signal.SIGTERM)
        assert fly.wait(30) == 0
        time.sleep(0.2)
        assert poses[-1].p[2] < 0.02  # on the ground when the process had exited
        assert max(pp.p[2] for pp in poses) < 1.0  # and never far above its target
    finally:
        if obs is not None:
            obs.close()
        for proc in procs:
            if proc is gs and gs.poll() is None:
                gs.terminate()
                gs.wait(10)
            _stop(proc)
        stop_router_process(router)
