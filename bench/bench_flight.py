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

* ``altitude_hold``: one drone through the real driver and a simulated ArduCopter whose true
  hover thrust is 0.2, 0.35, 0.5 or 0.7 (its MOT_THST_HOVER seeds the estimate), holding
  1 m: the largest altitude error [m] from mocap over 4 s after 8 s of settling, and again
  after a +30 % mass step (not for 0.7: 0.91 is beyond the thrust limit 0.9); plus a seed the
  autopilot never learnt (MOT_THST_HOVER 0.35 on a 0.2 and a 0.45 airframe).
* ``link_loss_detection``: the vehicle's link goes silent mid-flight; simulation seconds from
  its last HEARTBEAT and from the cut to the driver's verdict (bound: heartbeat timeout 3 s +
  one check period after the last HEARTBEAT, i.e. ≤ 4 s + a period after the cut).

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
from agent.flight.autopilot_check import check_autopilot, seed_hover_thrust
from agent.flight.controllers import FlightConfig, FlightController
from agent.flight.driver_types import DriverConfig, PoseSample
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
        [sys.executable, "-m", "agent.cli", "groundstation", "--source", "sim", "--scenario",
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
        jitter = [abs(float(p) - 0.02) for p in periods]
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


class FlightRig:
    """One simulated vehicle flown by the real driver at ``scale`` times real time, mocap fed
    to it at 100 Hz (sim) from the simulator's truth; the autopilot's parameters read and the
    hover thrust seeded as the flying agent does (:func:`check_autopilot`)."""

    def __init__(self, params: VehicleParams, scale: float = 3.0,
                 cfg: DriverConfig | None = None) -> None:
        self.clock = WallClock(scale)
        self.fleet = SimFleet(["A"], self.clock, params, start=np.zeros((1, 3)))
        self.quad = self.fleet.quads[0]
        self.feeding = True
        self._latest: PoseSample | None = None
        self.controller = FlightController(FlightConfig(lo=(-2.0, -2.0, 0.0),
                                                        hi=(2.0, 2.0, 3.0)))
        self.driver = MavlinkDriver(
            f"udpout:127.0.0.1:{self.quad.port}", lambda: self._latest, self.controller,
            cfg or DriverConfig(autopilot=params.autopilot, mocap_stale_s=0.5), self.clock)
        self._stop = threading.Event()
        self._feed = threading.Thread(target=self._feed_loop, daemon=True)

    def _feed_loop(self) -> None:
        while not self._stop.is_set():
            if self.feeding:
                s = self.fleet.mocap(0)
                self._latest = PoseSample(s.t, s.p, s.v, s.q, time.monotonic())
                self.driver.notify_pose()
            self._stop.wait(self.clock.wall(0.01))

    def __enter__(self) -> FlightRig:
        self.fleet.start()
        self._feed.start()
        self.driver.start()
        self.driver.wait_heartbeat()
        seed_hover_thrust(self.driver, check_autopilot(self.driver, 0.5))
        return self

    def __exit__(self, *_exc: object) -> None:
        self._stop.set()
        self._feed.join(2.0)
        self.driver.close()
        self.fleet.close()

    def run_for(self, dt: float) -> None:
        """Let dt simulation seconds pass."""
        end = self.clock.now() + dt
        while self.clock.now() < end:
            time.sleep(self.clock.wall(0.02))

    def heights(self, dt: float) -> list[float]:
        """Mocap heights [m] over the next dt simulation seconds, every 20 ms (sim)."""
        zs: list[float] = []
        end = self.clock.now() + dt
        while self.clock.now() < end:
            if self._latest is not None:
                zs.append(float(self._latest.p[2]))
            time.sleep(self.clock.wall(0.02))
        return zs

    def take_off(self, z: float) -> None:
        """Engage and hold (0, 0, z) [m; ENU]."""
        self.driver.engage()
        self.controller.set_hold([0.0, 0.0, z], 0.0)


def altitude_errors(hover_true: float, seed: float | None = None, mass_step: bool = True,
                    z: float = 1.0, settle_s: float = 8.0, window_s: float = 4.0,
                    step_settle_s: float = 10.0) -> dict[str, float]:
    """Hold z [m] with a simulated vehicle of true hover thrust ``hover_true`` whose autopilot
    reports ``seed`` (None: the truth) as its hover thrust; the largest |z − target| [m] over
    ``window_s`` after ``settle_s`` [s sim], then (``mass_step``) after a +30 % mass step and
    ``step_settle_s``; and the final hover-thrust estimates."""
    params = VehicleParams(hover_thrust=hover_true,
                           params={} if seed is None else {"MOT_THST_HOVER": seed})
    with FlightRig(params) as rig:
        rig.take_off(z)
        rig.run_for(settle_s)
        zs = rig.heights(window_s)
        out = {"hover_true": hover_true, "seed": hover_true if seed is None else seed,
               "err_m": max(abs(h - z) for h in zs),
               "estimate": rig.controller.model.hover_thrust}
        if mass_step:
            rig.fleet.set_mass(0, rig.fleet.physics.mass[0] * 1.3)
            rig.run_for(step_settle_s)
            zs = rig.heights(window_s)
            out.update(hover_after_step=rig.fleet.true_hover_thrust(0),
                       err_after_step_m=max(abs(h - z) for h in zs),
                       estimate_after_step=rig.controller.model.hover_thrust)
        out["setpoints_blocked"] = float(rig.driver.stats.blocked)
        return out


def link_loss_latency() -> dict[str, float]:
    """Hover, then silence the vehicle's link (it sends nothing more); simulation seconds from
    its last HEARTBEAT and from the cut to the driver's verdict, and whether the set-point
    stream stopped."""
    with FlightRig(VehicleParams()) as rig:
        rig.take_off(0.8)
        rig.run_for(3.0)
        link = rig.quad.link
        t_cut = rig.clock.now()
        link.write = lambda _buf: None
        while rig.driver.released is None and rig.clock.now() < t_cut + 10.0:
            time.sleep(rig.clock.wall(0.01))
        r = rig.driver.released
        mon = rig.driver.monitor
        assert r is not None and mon is not None and mon.last_heartbeat is not None
        return {"code_ok": float(r.code == "link_lost"), "from_cut_s": r.t - t_cut,
                "from_last_heartbeat_s": r.t - mon.last_heartbeat,
                "streaming": float(rig.driver.streaming)}


def bench_altitude(out: TextIO) -> None:
    """``altitude_hold`` rows (module docstring)."""
    for h in (0.2, 0.35, 0.5, 0.7):
        _emit(out, {"bench": "altitude_hold", **altitude_errors(h, mass_step=h < 0.6)})
    for h in (0.2, 0.45):
        _emit(out, {"bench": "altitude_hold", **altitude_errors(h, seed=0.35, mass_step=False)})
    # Heavier than its seed: lifts off only through the lift-off search (about 5 s sim).
    _emit(out, {"bench": "altitude_hold", **altitude_errors(0.75, seed=0.35, mass_step=False,
                                                            settle_s=10.0)})


def bench_link_loss(out: TextIO) -> None:
    """``link_loss_detection`` row (module docstring)."""
    _emit(out, {"bench": "link_loss_detection", "heartbeat_timeout_s": 3.0,
                **link_loss_latency()})


def run(out: TextIO = sys.stdout, seconds: float = 10.0) -> None:
    """Run every flight benchmark, one JSON line each."""
    bench_stream(out, seconds)
    bench_sim_realtime(out, seconds)
    bench_sim_capacity(out)
    bench_altitude(out)
    bench_link_loss(out)


def main(argv: list[str] | None = None) -> int:
    """``python -m bench.bench_flight [--seconds S]``."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=10.0)
    args = ap.parse_args(argv)
    run(sys.stdout, args.seconds)
    return 0


if __name__ == "__main__":
    sys.exit(main())
