"""A flying agent: the agent runtime with a quadcopter as its pose source (thesis chapter 6).

``python -m agent.runtime.flight_agent --id A --scenario S.toml --connect tcp/HOST:7447
[--flight F.toml] [--mavlink udpout:127.0.0.1:14560] [fault flags] [--state-dir D]
[--exit-on-complete]`` runs the same :class:`~agent.runtime.agent.AgentRuntime` as
``viscover agent`` (same options, same trade protocol, same journal), with three differences:

* **clock**: the ground station's shared simulation clock (``viscover/<m>/clock``, followed by
  :class:`agent.net.clocksync.RemoteClock`), never the process's
  own wall clock, so the mocap timestamps and the runtime agree and the whole mission may run
  faster than real time (``viscover groundstation --time-scale X``). ``--rate-scale`` is
  refused.
* **pose**: :class:`~agent.flight.pose_source.MavlinkPoseSource`: position and yaw from motion
  capture (``viscover/<m>/mocap/<id>``), the camera latitude simulated (section 6.1), velocity
  commands of the planner flown by :class:`~agent.flight.controllers.FlightController` through
  a :class:`~agent.flight.mavlink_driver.MavlinkDriver` (SET_ATTITUDE_TARGET over MAVLink).
* **convergence**: a flown vehicle circles its optimum by a few centimetres instead of landing
  on it, so besides section 4.4's test the agent also converges once its measured pose has
  settled (:class:`Settling`, ``--settle-window/-radius/-angle``).

Sequence: wait for the clock; engage the vehicle (HEARTBEAT, mode, arm) and fly from the ground
to the agent's initial pose (figure 6.2: initial positioning; after a restart, to the last
journaled pose instead); then run the planner / trade loop every Δt of simulation time. While
the agent is not optimising (converged, trading) the vehicle holds position and yaw. On
completion (``--exit-on-complete``) the drone flies home (``--landing home``, the default:
at its height to above its launch point, keeping R_s from the other drones' mocap positions,
:func:`fly_home`) and lands; on SIGINT/SIGTERM, ``--timeout`` or a flight failure the runtime
stops and the drone lands where it is before the process exits.

The fault flags act on this process's Zenoh traffic (trade queries and replies, states, poses,
and also the incoming mocap ``mocap`` and clock ``clock`` samples) and on the MAVLink set-points
(kind ``setpoint``). For trade-message loss only: ``--drop-kind trade=P --drop-kind
trade.reply=P``.

The vehicle's connection: ``--mavlink`` (any pymavlink string), or by default
``udpout:<host>:<port>`` of this drone from the flight settings (``--flight`` or the scenario's
sibling ``.flight.toml``), the port the ground station's simulated vehicle listens on.

Prints ``viscover-flight-agent hovering id=A t=T`` once at the initial pose, and with
``--exit-on-complete`` one JSON line (as ``viscover agent`` does, plus flight counters) once
the mission is complete. Exit codes: 0 done and landed; 1 flight failure (handshake refused,
initial pose not reached, failsafe landing, landing not confirmed); 2 a user mistake (one
line on stderr); 3 not complete within ``--timeout``.
"""

from __future__ import annotations

import argparse
import logging
import math
import sys
import threading
import time
from typing import Any

EXIT_FLIGHT = 1
EXIT_USAGE = 2
EXIT_INCOMPLETE = 3

_log = logging.getLogger("viscover.flight_agent")


def add_flight_arguments(p: argparse.ArgumentParser) -> None:
    """The flight options, added to ``viscover agent``'s parser (flying iff ``--mavlink`` or
    ``--flight`` is given)."""
    g = p.add_argument_group("flight (fly a quadcopter over MAVLink; follows the ground "
                             "station's clock)")
    g.add_argument("--flight", metavar="FILE.toml", default=None,
                   help="flight settings (default: <scenario>.flight.toml if present)")
    g.add_argument("--mavlink", metavar="CONN", default=None,
                   help="pymavlink connection string of the vehicle, e.g. "
                   "udpout:127.0.0.1:14560 (default: this drone's port from the flight settings)")
    g.add_argument("--setpoint-rate", type=float, default=50.0, metavar="HZ",
                   help="SET_ATTITUDE_TARGET rate [Hz, simulation time] (default 50)")
    g.add_argument("--mocap-stale", type=float, default=0.2, metavar="S",
                   help="mocap older than this [s sim] triggers the failsafe (default 0.2)")
    g.add_argument("--takeoff-timeout", type=float, default=60.0, metavar="S",
                   help="time allowed to reach the initial pose [s sim] (default 60)")
    g.add_argument("--settle-window", type=float, default=2.0, metavar="S",
                   help="converged once the measured pose stayed settled for S [s sim] "
                   "(default 2; see Settling) ...")
    g.add_argument("--settle-radius", type=float, default=0.1, metavar="M",
                   help="... within M metres of its mean (default 0.1) ...")
    g.add_argument("--settle-angle", type=float, default=0.05, metavar="RAD",
                   help="... and the camera within RAD of its mean direction (default 0.05)")
    g.add_argument("--landing", choices=["home", "here"], default="home",
                   help="after the mission: 'home' flies at its height back above the launch "
                   "point, keeping R_s from the other drones (section 4.3), then lands; 'here' "
                   "lands where it is (default home)")
    g.add_argument("--home-timeout", type=float, default=120.0, metavar="S",
                   help="time allowed to get home before landing where it is [s sim] "
                   "(default 120)")
    g.add_argument("--clock-timeout", type=float, default=10.0, metavar="S",
                   help="wall seconds to wait for the ground station's clock (default 10)")


def build_parser() -> argparse.ArgumentParser:
    """``viscover agent``'s parser (every option of the runtime) plus the flight options."""
    from agent.runtime.cli_commands import register

    top = argparse.ArgumentParser(prog="viscover")
    sub = top.add_subparsers(dest="command")
    register(sub)
    p: argparse.ArgumentParser = sub.choices["agent"]
    p.prog = "python -m agent.runtime.flight_agent"
    p.description = __doc__.split("\n\n", 1)[0] if __doc__ else None
    if "--mavlink" not in p._option_string_actions:  # not yet wired into the CLI
        add_flight_arguments(p)
    return p


def _connection(args: argparse.Namespace, flight: Any, drone_ids: list[str]) -> str:
    """``--mavlink`` or ``udpout:<host>:<port>`` of this drone from the flight settings."""
    from agent.config.flight import drone_ports
    from agent.config.scenario import ScenarioError
    from agent.runtime.cli_commands import UsageError

    if args.mavlink:
        return str(args.mavlink)
    try:
        port = drone_ports(flight, drone_ids)[args.id]
    except ScenarioError as e:
        raise UsageError(str(e)) from None
    if not port:
        raise UsageError("--mavlink is required: the flight settings give no fixed port for "
                          f"drone {args.id}")
    return f"udpout:{flight.host}:{port}"


class Settling:
    """Convergence test (:class:`agent.runtime.agent.SettleTest`) that tolerates a real vehicle.

    Section 4.4 declares convergence when the line search accepts no step at all. A flown
    vehicle never sits exactly on the optimum: each step is a velocity held for Δt, the vehicle
    answers it with a lag, overshoots by centimetres, and the planner sends it back: a limit
    cycle of a few centimetres around the optimum (about ±5 cm at 0.3 m/s with the default
    controllers) in which the line search always finds an improving step, so the agent would
    never stop optimising and never trade. Here the agent also counts as converged once its
    measured pose has *settled*: over the last ``window_s`` seconds every position lay within
    ``radius`` [m] of their mean and every camera direction within ``angle`` [rad] of theirs.
    The runtime then holds the mean position and direction (figure 6.2), the centre of the
    cycle, i.e. the optimum up to the cycle's asymmetry.
    """

    def __init__(self, window_s: float = 2.0, radius: float = 0.1, angle: float = 0.05) -> None:
        self.window_s, self.radius, self.angle = window_s, radius, angle
        self.hist: list[tuple[float, Any, Any]] = []
        self.settled = 0  #: convergences declared by this test (not by section 4.4)

    def reset(self) -> None:
        """The planner converged by itself: start a new window."""
        self.hist.clear()

    def update(self, t: float, p: Any, v: Any) -> tuple[Any, Any] | None:
        """Record the measured pose at mission time t [s]; (mean p, mean v) once settled."""
        import numpy as np

        self.hist.append((float(t), np.asarray(p, dtype=np.float64).copy(),
                          np.asarray(v, dtype=np.float64).copy()))
        t0 = self.hist[-1][0] - self.window_s
        if self.hist[0][0] > t0:
            return None
        self.hist = [h for h in self.hist if h[0] >= t0 - 1e-9]
        ps = np.array([h[1] for h in self.hist])
        vs = np.array([h[2] for h in self.hist])
        pm, vm = ps.mean(axis=0), vs.mean(axis=0)
        vm = vm / np.linalg.norm(vm)
        if np.max(np.linalg.norm(ps - pm, axis=1)) > self.radius:
            return None
        if np.min(vs @ vm) < math.cos(self.angle):
            return None
        self.hist.clear()
        self.settled += 1
        return pm, vm


def run_flight_agent(args: argparse.Namespace) -> int:
    """Run one flying agent from parsed ``viscover agent`` + flight arguments (see the module
    docstring). Raises ``agent.runtime.cli_commands.UsageError`` on a user mistake."""
    import numpy as np

    from agent.config.flight import load_flight
    from agent.config.scenario import ScenarioError
    from agent.core.orientation import angles_from_direction
    from agent.flight.attitude import ThrustModel
    from agent.flight.controllers import FlightConfig, FlightController
    from agent.flight.mavlink_driver import (
        DriverConfig,
        FlightError,
        MavlinkDriver,
        land_on_signals,
    )
    from agent.flight.pose_source import MavlinkPoseSource, MocapNeighbours, ZenohMocapFeed
    from agent.net.clocksync import RemoteClock
    from agent.runtime.agent import AgentConfig
    from agent.runtime.cli_commands import (
        UsageError,
        fault_injector,
        install_signals,
        load_scenario_arg,
        mission_name,
        new_runtime,
        open_journal,
        open_transport,
        restore_signals,
        zenoh_config,
    )
    from agent.wire import keys

    logging.basicConfig(level=str(args.log_level).upper(),
                        format=f"%(asctime)s {args.id} %(name)s %(levelname)s %(message)s")
    if getattr(args, "rate_scale", 1.0) != 1.0:
        raise UsageError("--rate-scale: a flying agent follows the ground station's clock; "
                          "speed it up with `viscover groundstation --time-scale X`")
    for name in ("setpoint_rate", "mocap_stale", "takeoff_timeout", "clock_timeout",
                 "home_timeout", "settle_window", "settle_radius", "settle_angle"):
        x = getattr(args, name)
        if not (math.isfinite(x) and x > 0):
            raise UsageError(f"--{name.replace('_', '-')} must be a finite number > 0")
    sc = load_scenario_arg(args.scenario)
    ids = [a.id for a in sc.agents]
    if args.id not in ids:
        raise UsageError(f"--id {args.id}: not an agent of {args.scenario} "
                          f"(agents: {', '.join(ids)})")
    spec = next(a for a in sc.agents if a.id == args.id)
    mission = mission_name(args, sc)
    try:
        flight = load_flight(args.scenario, args.flight)
    except ScenarioError as e:
        raise UsageError(str(e)) from None
    conn = _connection(args, flight, ids)
    zcfg = zenoh_config(args)
    faults = fault_injector(args)
    journal = open_journal(args, mission)

    tp = remote = feed = neighbours = driver = rt = None
    try:
        tp = open_transport(zcfg, faults, args.id)
        remote = RemoteClock(tp, mission)
        if not remote.wait_synced(args.clock_timeout):
            raise UsageError(f"no clock on {keys.clock_key(mission)} within "
                              f"{args.clock_timeout:g} s: is the ground station running?")
        clock = remote
        scale = float(clock.time_scale)
        cfg = AgentConfig(mission=mission, seed=args.fault_seed,
                          request_timeout_s=args.request_timeout)
        for name in ("backoff_s", "backoff_cap_s", "doubt_delay_s", "state_period_s",
                     "pose_journal_period_s"):  # real-time behaviour, mission units
            setattr(cfg, name, getattr(cfg, name) * scale)
        ctl = FlightController(FlightConfig(model=ThrustModel(), lo=sc.space.lo, hi=sc.space.hi))
        holder: list[MavlinkDriver] = []
        feed = ZenohMocapFeed(tp, mission, args.id,
                              on_pose=lambda: holder[0].notify_pose() if holder else None)
        try:
            driver = MavlinkDriver(conn, feed, ctl,
                                   DriverConfig(autopilot=flight.autopilot,
                                                rate_hz=args.setpoint_rate,
                                                mocap_stale_s=args.mocap_stale),
                                   clock, faults=faults)
        except FlightError as e:
            raise UsageError(str(e)) from None
        holder.append(driver)
        neighbours = MocapNeighbours(tp, mission, args.id)
        driver.start()
        # The runtime first (journal replay, new incarnation), then the vehicle.
        source = MavlinkPoseSource(driver, feed)
        settle = Settling(args.settle_window, args.settle_radius, args.settle_angle)
        rt = new_runtime(args.id, sc, tp, journal, clock, pose=source, config=cfg,
                         settle=settle)
        p0, v0 = spec.p0, spec.v0
        lp = rt.machine.last_pose
        if lp is not None and sc.space.contains(np.asarray(lp.p, dtype=np.float64)):
            p0, v0 = lp.p, lp.v  # a restart resumes where the journal left it
        p0 = np.asarray(p0, dtype=np.float64)
        lat0, yaw0 = angles_from_direction(np.asarray(v0, dtype=np.float64))
        lim = source.latitude.lat_max
        source.latitude.theta = min(max(lat0, -lim), lim)
        code = 0  # SIGINT/SIGTERM before the loop: landed, exit 0
        with land_on_signals(driver):
            try:
                driver.engage()
            except FlightError as e:
                print(f"viscover: error: {args.id}: {e}", file=sys.stderr)
                return EXIT_FLIGHT
            home = _launch_point(feed(), spec.p0)
            t_takeoff = clock.now()
            if not source.goto(p0, yaw0, tol=0.1, timeout_s=args.takeoff_timeout):
                print(f"viscover: error: {args.id}: initial pose not reached within "
                      f"{args.takeoff_timeout:g} s", file=sys.stderr)
                return EXIT_FLIGHT
            t_hover = clock.now()
            print(f"viscover-flight-agent hovering id={args.id} t={t_hover:.2f}", flush=True)
            stop = threading.Event()
            previous = install_signals(stop)  # within the loop: a clean stop, then land
            try:
                code = _loop(args, rt, source, driver, clock, stop, t_takeoff, t_hover)
            finally:
                restore_signals(previous)
                rt.stop()
            if code == 0 and rt.complete and args.landing == "home" \
                    and not fly_home(source, neighbours, home, sc, clock, args.home_timeout):
                print(f"viscover: warning: {args.id}: not home within {args.home_timeout:g} s; "
                      "landing where it is", file=sys.stderr)
        if code == 0 and driver.phase != "landed":
            print(f"viscover: error: {args.id}: landing not confirmed", file=sys.stderr)
            return EXIT_FLIGHT
        return code
    finally:
        if rt is not None:
            rt.stop()
        if driver is not None:
            driver.close()
        if feed is not None:
            feed.close()
        if neighbours is not None:
            neighbours.close()
        if remote is not None:
            remote.close()
        if tp is not None:
            tp.close()
        journal.close()
        if faults is not None:
            faults.close()


def _launch_point(sample: Any, p0: Any) -> Any:
    """Where the drone took off [m, ENU]: its mocap position while still on the ground, or
    (already airborne, e.g. after a restart) the ground below its initial scenario pose."""
    import numpy as np

    if sample is not None and float(sample.p[2]) < 0.3:
        return np.array(sample.p, dtype=np.float64)
    return np.array([p0[0], p0[1], 0.0])


def fly_home(source: Any, neighbours: Any, home: Any, sc: Any, clock: Any, timeout_s: float,
             arrive_m: float = 0.1, still_mps: float = 0.05) -> bool:
    """After the mission: fly at the current height to above the launch point ``home`` with
    :func:`agent.core.homing.homing_velocity` (walls, R_s from the other drones' mocap positions,
    R_s/2 from the landmarks' bounding box), then hold there until the vehicle is still (the
    autopilot's LAND mode would carry any residual speed sideways). True once within
    ``arrive_m`` metres (horizontally) and slower than ``still_mps``; False after
    ``timeout_s`` [s sim]."""
    import numpy as np

    from agent.core.homing import homing_velocity

    p = source.current()[0]
    target = np.array([home[0], home[1], p[2]])
    structure = (sc.q.min(axis=0), sc.q.max(axis=0))  # the landmarks' bounding box
    dt = sc.params.dt
    t_end = clock.now() + timeout_s
    holding = False
    while clock.now() < t_end:
        sample = source.pose()  # mocap: position p, velocity v (there is one: see above)
        near = float(np.hypot(*(target - sample.p)[:2])) <= arrive_m
        if near and not holding:
            source.hold(target)
            holding = True
        if holding:
            if near and float(np.linalg.norm(sample.v)) <= still_mps:
                return True
        else:
            p = sample.p
            vel = homing_velocity(p, target, sc.params, sc.space, neighbours.positions(),
                                  structure=structure)
            if np.any(vel):
                source.command(vel, np.zeros(3), dt)
            else:
                source.hold()  # blocked for now: hold and look again
        time.sleep(clock.wall(dt))
    source.hold()
    return False


def _loop(args: argparse.Namespace, rt: Any, source: Any, driver: Any, clock: Any,
          stop: threading.Event, t_takeoff: float, t_hover: float) -> int:
    """The runtime's loop at Δt of simulation time (as ``viscover agent``'s); returns the exit
    code. Holds position whenever the agent is not optimising."""
    from agent.runtime.cli_commands import agent_loop

    rt.start()

    def each_tick() -> int | None:
        if rt.phase != "optimising" and source.controller.mode != "hold":
            source.hold()  # figure 6.2: position and angle hold while trading
        if driver.phase in ("landing", "landed"):  # the stale-mocap failsafe landed it
            print(f"viscover: error: {args.id}: the vehicle is {driver.phase} (mocap lost?)",
                  file=sys.stderr)
            return EXIT_FLIGHT
        return None

    def report() -> dict[str, Any]:
        s = driver.stats
        return {"takeoff_at_s": t_takeoff, "hover_at_s": t_hover,
                "time_scale": clock.time_scale, "setpoints": s.sent,
                "setpoints_dropped": s.dropped, "setpoints_blocked": s.blocked,
                "failsafes": s.failsafes, "commands_rejected": source.rejected,
                "settled": getattr(rt.settle, "settled", None)}

    return agent_loop(rt, args, clock, stop, each_tick=each_tick, report=report)


def main(argv: list[str] | None = None) -> int:
    """Entry point (see the module docstring)."""
    from agent.runtime.cli_commands import UsageError, fail

    try:
        args = build_parser().parse_args(argv)
    except SystemExit as e:
        return e.code if isinstance(e.code, int) else EXIT_USAGE
    try:
        return run_flight_agent(args)
    except UsageError as e:
        return fail(str(e))
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
