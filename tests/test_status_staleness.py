"""``viscover status`` says how old what it shows is, and when the mesh is gone: the age of
each drone's last state, and a last line once the session lost its router (or, where that
cannot be asked, nothing was heard for ``MESH_GONE_S``); ``--once`` then exits 1."""

from __future__ import annotations

import queue
import re
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable

from agent.clock import ManualClock
from agent.config.parse import load_scenario
from agent.mission.status import render_plain
from agent.mission.watch import MESH_GONE_S, MissionWatch
from agent.net.memory import MemoryNetwork
from agent.net.router import client_config, start_router_process, stop_router_process
from agent.net.transport import ZenohTransport
from agent.wire import keys
from agent.wire.ground import STATUS_CODEC, MocapStatus
from tests.conftest import reap, repo_env, scenario_path, wait_until
from tests.test_status_identity import PUB, state

HEX = str(scenario_path("hexagon_5_3"))


def test_ages_and_a_silent_mesh_in_memory() -> None:
    """No session to ask (in memory): the mesh is gone once nothing came for MESH_GONE_S."""
    clock = ManualClock()
    net = MemoryNetwork()
    watch = MissionWatch(net.transport("status"), "m", load_scenario(HEX), clock=clock)
    net.transport("A").publish(keys.state_key("m", "A"), PUB.encode(
        state("A", 1, 0.0, {3: 0, 6: 0}, complete=True)))
    clock.advance(3.2)
    view = watch.view()
    assert [(r.id, r.link, r.heard) for r in view.rows] == [
        ("A", "stale", "3.2 s ago"), ("B", "not heard yet", "-"), ("C", "not heard yet", "-")]
    assert (view.mesh_gone_s, view.mesh) == (None, "")
    clock.advance(MESH_GONE_S)
    view = watch.view()
    assert view.mesh_gone_s is not None
    assert render_plain(view).splitlines()[-1] == "mesh gone: no router/peers heard for 13 s"
    watch.close()


def _lines(proc: subprocess.Popen[str]) -> queue.Queue[str]:
    """Every line ``proc`` prints, as it comes."""
    q: queue.Queue[str] = queue.Queue()
    out = proc.stdout
    assert out is not None

    def pump() -> None:
        for line in out:
            q.put(line)

    threading.Thread(target=pump, daemon=True).start()
    return q


def _until(q: queue.Queue[str], pred: Callable[[str], bool], timeout_s: float = 30.0) -> str:
    """The first line read from ``q`` for which ``pred`` holds (within ``timeout_s``)."""
    deadline = time.monotonic() + timeout_s
    seen = []
    while time.monotonic() < deadline:
        try:
            line = q.get(timeout=0.2)
        except queue.Empty:
            continue
        seen.append(line)
        if pred(line):
            return line
    raise AssertionError("".join(seen))


def test_status_says_the_mesh_is_gone_when_its_router_dies() -> None:
    """A complete mission with mocap ok, then its router stops: the live view (and --once)
    says so in its last line within a refresh; --once exits 1, Ctrl-C 130."""
    router, ep = start_router_process()
    net = ["--scenario", HEX, "--connect", ep, "--plain"]
    tp = ZenohTransport(client_config([ep]), None, "mission")
    procs = [subprocess.Popen([sys.executable, "-m", "agent.cli", "status", *net, *extra],
                              stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                              env=repo_env())
             for extra in (["--period", "0.2", "--wait", "0"], ["--once", "--wait", "6"])]
    live, once = procs
    try:
        lines = _lines(live)
        mocap = STATUS_CODEC.encode(MocapStatus(drone="A", state="ok", age=0.0, t=0.0))
        seq = iter(range(1, 10_000))

        def publish() -> None:  # mocap ok and a complete state, every 0.1 s
            tp.publish(keys.mocap_status_key("hexagon_5_3", "A"), mocap)
            k = next(seq)
            tp.publish(keys.state_key("hexagon_5_3", "A"), PUB.encode(
                state("A", k, 0.1 * k, {3: 0, 6: 0}, phase="converged", complete=True)))

        assert wait_until(lambda: any(re.match(r"A +converged done .* ago +ok ", x)
                                      for x in list(lines.queue)), 30.0, 0.1, publish)
        stop_router_process(router)
        gone = _until(lines, lambda x: x.startswith("mesh gone"), 10.0)
        found = re.fullmatch(r"mesh gone: no router/peers heard for (\d+) s\n", gone)
        assert found is not None and int(found[1]) <= 2, gone
        live.send_signal(signal.SIGINT)
        assert live.wait(30) == 130
        out, _ = once.communicate(timeout=30)
        assert once.returncode == 1, out
        assert out.splitlines()[-1].startswith("mesh gone: no router/peers heard for ")
    finally:
        tp.close()
        reap(procs)
        if router.poll() is None:
            stop_router_process(router)
