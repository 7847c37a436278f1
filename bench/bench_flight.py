"""Flight benchmarks. ``run(out)`` prints one JSON line per measurement:

* ``setpoint_stream``: a driver streaming SET_ATTITUDE_TARGET at 50 Hz to a simulated vehicle
  while hovering, deployed as in a mission (router process, ground-station process with the
  simulator publishing mocap at 100 Hz, the driver here fed over Zenoh); p99 of
  |period − 20 ms| (target < 5 ms), from the driver's send times.
* ``mocap_to_setpoint``: wall time from a pose reaching the driver's process (Zenoh sample
  handed to the subscriber) to the set-point it produced leaving the socket; median
  (target < 5 ms) and p99.
* ``sim_realtime_20``: 20 simulated quadrotors at time scale 1, each armed in GUIDED_NOGPS
  and fed SET_ATTITUDE_TARGET at 50 Hz over UDP, telemetry out at 30 Hz: real-time factor
  (simulated / wall seconds; 1.0 = keeps real time), largest lag behind the clock, simulated
  time given up to overload (``slipped_s``, 0 when it keeps up), and the process's CPU share.
* ``sim_physics_capacity_20``: the same fleet stepped without I/O as fast as possible:
  simulated seconds per wall second.

Times in seconds. Run: ``python -m bench.bench_flight [--seconds 10]``.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any, TextIO

import numpy as np

from agent.clock import ManualClock, WallClock
from agent.flight.controllers import FlightConfig, FlightController
from agent.flight.driver_types import DriverConfig
from agent.flight.frames import quat_from_euler
from agent.flight.mavlink_driver import MavlinkDriver
from agent.flight.vehicle_pose import ZenohMocapFeed
from agent.net.clocksync import RemoteClock
from agent.net.router import client_config, start_router_process, stop_router_process
from agent.net.transport import ZenohTransport
from agent.wire.mavlink import mavutil
from groundstation.vehicle.fleet import SimFleet
from groundstation.vehicle.params import VehicleParams

REPO = Path(__file__).resolve().parents[1]


def _percentile(xs: list[float], q: float) -> float:
    s = sorted(xs)
    return s[min(len(s) - 1, max(0, round(q * (len(s) - 1))))]


def _emit(out: TextIO, record: dict[str, Any]) -> None:
    out.write(json.dumps(record) + "\n")
    out.flush()


def bench_stream(out: TextIO, seconds: float) -> None:
    """Set-point period jitter and mocap-to-set-point latency, deployed as in a mission: a
    router process, a ground-station process (simulator + mocap at 100 Hz), and the driver
    here, fed by Zenoh."""
    router, endpoint = start_router_process()
    env = dict(os.environ, PYTHONPATH=str(REPO))
    gs = subprocess.Popen(
        [sys.executable, "-m", "agent.cli", "groundstation", "--scenario",
         str(REPO / "scenarios" / "cube_6_2.toml"), "--connect", endpoint, "--mission", "bench",
         "--ports", "A=0,B=0,C=0", "--rate", "100"],
        stdout=subprocess.PIPE, text=True, env=env)
    ag_t = None
    feed = None
    driver = None
    try:
        assert gs.stdout is not None
        ready = gs.stdout.readline()
        port = int(ready.split("A=udp:")[1].split()[0].rsplit(":", 1)[1])
        ag_t = ZenohTransport(client_config(endpoint), None, "A")
        clock = RemoteClock(ag_t, "bench")  # the ground station's simulation clock
        if not clock.wait_synced(10.0):
            raise RuntimeError("no clock from the ground station")
        ctl = FlightController(FlightConfig(lo=(-2, -2, 0), hi=(2, 2, 3)))
        holder: list[MavlinkDriver] = []
        feed = ZenohMocapFeed(ag_t, "bench", "A", on_pose=lambda: holder[0].notify_pose())
        driver = MavlinkDriver(f"udpout:127.0.0.1:{port}", feed, ctl, DriverConfig(rate_hz=50.0),
                               clock)
        holder.append(driver)
        driver.start()
        driver.engage()
        p0 = feed()
        ctl.set_hold([p0.p[0], p0.p[1], 1.0] if p0 is not None else None, None)
        time.sleep(3.0)  # take off
        n0 = len(driver.stats.send_wall)
        l0 = len(driver.stats.latency)
        time.sleep(seconds)
        sends = list(driver.stats.send_wall)[n0:]
        lat = list(driver.stats.latency)[l0:]
        periods = np.diff(sends)
        jitter = [abs(p - 0.02) for p in periods]
        _emit(out, {"bench": "setpoint_stream", "rate_hz": 50.0, "n": len(periods),
                    "mean_period_s": float(np.mean(periods)),
                    "p99_jitter_s": _percentile(jitter, 0.99),
                    "max_jitter_s": max(jitter), "target_p99_jitter_s": 0.005})
        _emit(out, {"bench": "mocap_to_setpoint", "n": len(lat),
                    "median_s": statistics.median(lat), "p99_s": _percentile(lat, 0.99),
                    "target_median_s": 0.005,
                    "path": "zenoh sample in -> SET_ATTITUDE_TARGET out"})
        driver.land(timeout_s=15.0)
    finally:
        if driver is not None:
            driver.close()
        if feed is not None:
            feed.close()
        if ag_t is not None:
            ag_t.close()
        gs.terminate()
        try:
            gs.wait(10)
        except subprocess.TimeoutExpired:
            gs.kill()
            gs.wait(5)
        if gs.stdout is not None:
            gs.stdout.close()
        stop_router_process(router)


def bench_sim_realtime(out: TextIO, seconds: float, n: int = 20) -> None:
    """20 vehicles at time scale 1 with a 50 Hz set-point stream each."""
    clock = WallClock(1.0)
    params = VehicleParams(setpoint_timeout=1.0)
    start = np.array([[i % 5 * 1.0, i // 5 * 1.0, 0.0] for i in range(n)])
    fleet = SimFleet([f"d{i}" for i in range(n)], clock, params, start=start)
    conns = [mavutil.mavlink_connection(f"udpout:127.0.0.1:{q.port}", source_system=i + 1,
                                        source_component=191)
             for i, q in enumerate(fleet.quads)]
    for q in fleet.quads:
        q.armed, q.mode = True, 20
        q.params_table["GUID_OPTIONS"] = 8
    stop = threading.Event()
    qd = [float(a) for a in quat_from_euler(0.02, -0.02, 0.0)]

    def feeder() -> None:
        nxt = time.monotonic()
        while not stop.is_set():
            for i, c in enumerate(conns):
                c.mav.set_attitude_target_send(0, i + 1, 1, 7, qd, 0.0, 0.0, 0.0, 0.52)
            nxt += 0.02
            stop.wait(max(0.0, nxt - time.monotonic()))

    th = threading.Thread(target=feeder, daemon=True)
    try:
        fleet.start()
        th.start()
        time.sleep(1.0)
        fleet.max_lag, fleet.slipped = 0.0, 0.0
        t0, w0, c0 = fleet.t, time.monotonic(), time.process_time()
        time.sleep(seconds)
        t1, w1, c1 = fleet.t, time.monotonic(), time.process_time()
        flying = sum(1 for i in range(n) if fleet.p[i, 2] < -0.5)
        _emit(out, {"bench": "sim_realtime_20", "drones": n, "rtf": (t1 - t0) / (w1 - w0),
                    "max_lag_s": fleet.max_lag, "slipped_s": fleet.slipped,
                    "cpu_share": (c1 - c0) / (w1 - w0),
                    "setpoints_rx": sum(q.log.setpoints for q in fleet.quads),
                    "flying": flying, "seconds": seconds})
    finally:
        stop.set()
        th.join(2.0)
        fleet.close()
        for c in conns:
            c.close()


def bench_sim_capacity(out: TextIO, sim_seconds: float = 10.0, n: int = 20) -> None:
    """Physics only (no sockets polled): simulated seconds per wall second."""
    fleet = SimFleet([f"d{i}" for i in range(n)], ManualClock(), VehicleParams())
    try:
        for q in fleet.quads:
            q.armed, q.mode, q.sp_t, q.sp_thrust = True, 20, float("inf"), 0.52
            q.params_table["GUID_OPTIONS"] = 8
        w0 = time.perf_counter()
        fleet.step_to(sim_seconds)
        wall = time.perf_counter() - w0
        _emit(out, {"bench": "sim_physics_capacity_20", "drones": n,
                    "sim_s_per_wall_s": sim_seconds / wall, "dt_s": fleet.dt})
    finally:
        fleet.close()


def run(out: TextIO = sys.stdout, seconds: float = 10.0) -> None:
    """Run every flight benchmark, one JSON line each."""
    bench_stream(out, seconds)
    bench_sim_realtime(out, seconds)
    bench_sim_capacity(out)


def main(argv: list[str] | None = None) -> int:
    """``python -m bench.bench_flight [--seconds S]``."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=10.0)
    args = ap.parse_args(argv)
    run(sys.stdout, args.seconds)
    return 0


if __name__ == "__main__":
    sys.exit(main())
