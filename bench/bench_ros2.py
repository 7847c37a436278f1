"""ROS 2 bridge throughput: 20 drones × 100 Hz motion capture through ``viscover ros2-bridge``.

``run(out)`` starts a router on a free loopback port and the bridge as its own process
(``viscover ros2-bridge``, a 20-drone scenario written here), then publishes from this process
for ``--seconds``: every drone's mocap pose at 100 Hz and its agent pose at 10 Hz (and a state
at 2 Hz, what an observer hears). A raw Zenoh subscriber on ``0/**`` (the ROS domain) counts
what comes out and decodes each mocap PoseStamped (its x carries the sample's number, so its
latency from publication to arrival is known). Rows (JSON lines):

* ``ros2_bridge_20x100hz``: mocap samples published and delivered as ROS messages, the ROS
  messages out per second (PoseStamped, TFMessage, frusta, status...), latency publication →
  ROS arrival (median, p99, max) [ms], and the bridge process's CPU time per wall second
  (``cpu_cores``; 1.0 = one core busy) and per mocap sample [µs], from ``/proc``.
* ``ros2_convert``: in-process cost of one mocap sample's conversion (two messages built and
  serialised with rosbags) [µs], no network.

Everything shares one 2-core machine (router, bridge, publisher, reader): the latency includes
that contention. Run: ``python -m bench.bench_ros2 [--seconds 10]``.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any, TextIO

import zenoh
from rosbags.typesys.stores.ros2_jazzy import geometry_msgs__msg__PoseStamped as PoseStamped

from agent.config.parse import parse_scenario
from agent.net.router import client_config, start_router_process, stop_router_process
from agent.net.transport import ZenohTransport
from agent.wire import keys
from agent.wire.codec import Codec
from agent.wire.ground import MOCAP_CODEC, MocapPose
from agent.wire.peer import AgentState, Counters, Pose, Publication, pack
from groundstation.ros2 import typesupport as ts
from groundstation.ros2.model import MissionRos
from groundstation.ros2.names import Names

ROOT = Path(__file__).resolve().parents[1]
DRONES = 20
MOCAP_HZ = 100.0
MISSION = "bench_ros2"
PUB: Codec[Publication] = Codec(Publication)


def scenario_toml(n: int = DRONES, landmarks: int = 200) -> str:
    """A planar scenario: ``n`` drones on a circle of radius 8 m around ``landmarks`` facing out."""
    lines = [f'name = "{MISSION}"', "dims = 2", "seed = 0", "d_opt = 1.0", "duration = 60.0",
             "", "[space]", "lo = [-12.0, -12.0]", "hi = [12.0, 12.0]", ""]
    for k in range(landmarks):
        a = 2 * math.pi * k / landmarks
        lines += ["[[landmarks]]", f"id = {k + 1}",
                  f"position = [{3 * math.cos(a)!r}, {3 * math.sin(a)!r}]",
                  f"normal = [{math.cos(a)!r}, {math.sin(a)!r}]", ""]
    for i in range(n):
        a = 2 * math.pi * i / n
        own = list(range(i + 1, landmarks + 1, n))
        lines += ["[[agents]]", f'id = "D{i}"',
                  f"position = [{8 * math.cos(a)!r}, {8 * math.sin(a)!r}]",
                  f"yaw = {a + math.pi!r}", f"landmarks = {own}", ""]
    return "\n".join(lines)


def _emit(out: TextIO, record: dict[str, Any]) -> None:
    out.write(json.dumps(record) + "\n")
    out.flush()


def _pct(xs: list[float], q: float) -> float:
    s = sorted(xs)
    return s[min(len(s) - 1, max(0, round(q * (len(s) - 1))))]


def bench_convert(n: int = 20_000) -> float:
    """Mean cost [µs] of one mocap sample's messages: built and serialised."""
    m = MissionRos(parse_scenario(scenario_toml(), "bench"), Names())
    m.pose("D0", (1.0, 2.0, 0.0), (1.0, 0.0, 0.0), 1)
    t0 = time.perf_counter()
    for k in range(n):
        for o in m.mocap("D0", (1.0, 2.0, 0.1), (1.0, 0.0, 0.0, 0.0), 10 + k):
            ts.serialize(o.msg, o.typename)
    return (time.perf_counter() - t0) / n * 1e6


class Reader:
    """Counts every ROS sample of domain 0 and times the mocap ones (x = sample number)."""

    def __init__(self, endpoint: str, sent: dict[int, float]) -> None:
        self._zenoh = contextlib.ExitStack()  # the session and its subscriber
        self.session = self._zenoh.enter_context(zenoh.open(client_config(endpoint)))
        self.sent, self.count, self.mocap = sent, 0, 0
        self.lat: list[float] = []
        self._lock = threading.Lock()
        self.sub = self._zenoh.enter_context(self.session.declare_subscriber("0/**", self._on))

    def _on(self, s: zenoh.Sample) -> None:
        now = time.perf_counter()
        key = str(s.key_expr)
        with self._lock:
            self.count += 1
        if "/mocap/" not in key:
            return
        msg = ts.deserialize(s.payload.to_bytes(), ts.POSE_STAMPED)
        assert isinstance(msg, PoseStamped)
        t = self.sent.get(int(msg.pose.position.x))
        with self._lock:
            self.mocap += 1
            if t is not None:
                self.lat.append(now - t)

    def close(self) -> None:
        self._zenoh.close()  # undeclares the subscriber, then closes the session


def _cpu_s(pid: int) -> float:
    """CPU time [s] (user + system) process ``pid`` used so far (Linux /proc)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def bench_bridge(seconds: float, hz: float = MOCAP_HZ) -> dict[str, Any]:
    """The 20 drones × ``hz`` run (module docstring)."""
    router, endpoint = start_router_process()
    tmp = tempfile.TemporaryDirectory(prefix="bench-ros2-")
    scenario = Path(tmp.name) / "bench_ros2.toml"
    scenario.write_text(scenario_toml())
    sc = parse_scenario(scenario.read_text(), str(scenario))
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, [str(ROOT),
                                                                    os.environ.get("PYTHONPATH")])))
    bridge = subprocess.Popen(
        [sys.executable, "-m", "agent.cli", "ros2-bridge", "--scenario", str(scenario),
         "--connect", endpoint, "--duration", str(seconds + 4.0)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    sent: dict[int, float] = {}
    tp = ZenohTransport(client_config(endpoint), node_id="bench-gs")
    reader = Reader(endpoint, sent)
    try:
        assert bridge.stdout is not None
        ready = bridge.stdout.readline()
        if "ready" not in ready:
            raise RuntimeError(f"bridge did not start: {ready!r}")
        time.sleep(1.0)  # the bridge's subscriptions reach the router
        ids = [a.id for a in sc.agents]
        sets = sc.initial_sets()
        n = 0
        period = 1.0 / hz
        cpu0 = _cpu_s(bridge.pid)
        t0 = time.perf_counter()
        tick = 0
        while time.perf_counter() - t0 < seconds:
            tick += 1
            for i, aid in enumerate(ids):
                n += 1
                sent[n] = time.perf_counter()
                tp.publish(keys.mocap_key(MISSION, aid), MOCAP_CODEC.encode(MocapPose(
                    drone=aid, seq=tick, t=tick * period, p=[float(n), float(i), 1.0],
                    q=[1.0, 0.0, 0.0, 0.0], v=[0.0, 0.0, 0.0])))
                if tick % 10 == i % 10:
                    tp.publish(keys.pose_key(MISSION, aid), PUB.encode(Pose(
                        sender=aid, seq=tick, t=tick * period, p=(0.0, float(i), 1.0),
                        v=(1.0, 0.0, 0.0))))
                if tick % 50 == i % 50:
                    tp.publish(keys.state_key(MISSION, aid), PUB.encode(AgentState(
                        sender=aid, incarnation=1, seq=tick, t=tick * period,
                        p=(0.0, float(i), 1.0), v=(1.0, 0.0, 0.0), phase="optimising",
                        owned=pack(dict.fromkeys(sets[aid], 0)), held=pack({}), vision=0.5,
                        counters=Counters(), partners=[], pending=[], trades_with={})))
            time.sleep(max(0.0, t0 + tick * period - time.perf_counter()))
        wall = time.perf_counter() - t0
        time.sleep(1.0)  # what is in flight arrives
        cpu = _cpu_s(bridge.pid) - cpu0  # the load's CPU, start-up left out
        out_count, delivered, lat = reader.count, reader.mocap, list(reader.lat)
    finally:
        reader.close()
        tp.close()
        _out, err = bridge.communicate(timeout=30)
        stop_router_process(router)
        tmp.cleanup()
    return {
        "bench": f"ros2_bridge_{DRONES}x{hz:g}hz", "drones": DRONES, "mocap_hz": hz,
        "seconds": round(wall, 2), "mocap_published": n, "mocap_delivered": delivered,
        "delivered_fraction": round(delivered / n, 4) if n else None,
        "mocap_in_per_s": round(n / wall, 1), "ros_msgs_out_per_s": round(out_count / wall, 1),
        "latency_ms_median": round(statistics.median(lat) * 1e3, 2) if lat else None,
        "latency_ms_p99": round(_pct(lat, 0.99) * 1e3, 2) if lat else None,
        "latency_ms_max": round(max(lat) * 1e3, 2) if lat else None,
        "cpu_cores": round(cpu / (wall + 1.0), 3),
        "cpu_us_per_mocap": round(cpu / n * 1e6, 1) if n else None,
        "bridge_summary": err.strip().splitlines()[-1:] if err else [],
        "note": "bridge process CPU (/proc) over the load and the second after it, per wall "
                "second and per mocap sample (poses and states included); router, bridge, "
                "publisher and reader share one 2-core machine",
    }


def run(out: TextIO, seconds: float = 10.0) -> None:
    """Both rows (module docstring)."""
    _emit(out, {"bench": "ros2_convert", "us_per_mocap": round(bench_convert(), 2),
                "note": "PoseStamped + TFMessage built and serialised (rosbags), in process"})
    _emit(out, bench_bridge(seconds))


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seconds", type=float, default=10.0)
    p.add_argument("--hz", type=float, default=None,
                   help="only the bridge run, at this mocap rate per drone (a load probe)")
    args = p.parse_args(argv)
    if args.hz is not None:
        _emit(sys.stdout, bench_bridge(args.seconds, args.hz))
        return 0
    run(sys.stdout, args.seconds)
    return 0


if __name__ == "__main__":
    sys.exit(main())
