"""Fly one drone to its initial pose and hold it there: the flight stack as a process.

``python -m agent.flight.fly --scenario S.toml --id A --mavlink udpout:127.0.0.1:14560
--connect tcp/127.0.0.1:7447`` follows the ground station's clock (``viscover/<m>/clock``),
reads drone A's mocap (``viscover/<m>/mocap/A``), engages the vehicle, flies to the agent's
initial position and yaw from the scenario (figure 6.2: initial positioning) and holds until
SIGINT/SIGTERM or ``--duration``; then it lands and exits. This is the wiring an agent process
uses with :class:`~agent.flight.pose_source.MavlinkPoseSource` in place of the kinematic pose.

Prints ``viscover-fly hovering id=A`` once at the initial pose. Exit codes: 0 landed;
1 flight failure (handshake refused, landing not confirmed); 2 a user mistake (one line).
"""

from __future__ import annotations

import argparse
import logging
import math
import sys
import time

EXIT_FLIGHT = 1
EXIT_USAGE = 2


def build_parser() -> argparse.ArgumentParser:
    """The command line."""
    p = argparse.ArgumentParser(prog="python -m agent.flight.fly", description=__doc__)
    p.add_argument("--scenario", required=True, metavar="FILE.toml")
    p.add_argument("--id", required=True, help="agent / drone id")
    p.add_argument("--mavlink", required=True, metavar="CONN",
                   help="pymavlink connection string, e.g. udpout:127.0.0.1:14560")
    p.add_argument("--connect", action="append", default=[], metavar="ENDPOINT",
                   help="Zenoh router endpoint (default tcp/127.0.0.1:7447)")
    p.add_argument("--mission", help="mission name; default: the scenario's name")
    p.add_argument("--autopilot", choices=("ardupilot", "px4"), default="ardupilot")
    p.add_argument("--rate", type=float, default=50.0, help="set-point rate [Hz]")
    p.add_argument("--duration", type=float, default=None, help="hold time [s sim]")
    p.add_argument("--mocap-stale", type=float, default=0.2, metavar="S",
                   help="mocap older than this [s sim] triggers the failsafe (default 0.2)")
    p.add_argument("--log-level", default="WARNING")
    return p


def main(argv: list[str] | None = None) -> int:
    """Run; see the module docstring."""
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=getattr(logging, str(args.log_level).upper(), logging.WARNING))
    from agent.config.scenario import ScenarioError, load_scenario
    from agent.flight.attitude import ThrustModel
    from agent.flight.controllers import FlightConfig, FlightController
    from agent.flight.mavlink_driver import (
        DriverConfig,
        FlightError,
        MavlinkDriver,
        land_on_signals,
    )
    from agent.flight.pose_source import MavlinkPoseSource, ZenohMocapFeed
    from agent.net.clocksync import RemoteClock
    from agent.net.router import client_config
    from agent.net.transport import ZenohTransport
    from agent.wire import keys

    def fail(msg: str, code: int = EXIT_USAGE) -> int:
        print(f"viscover: error: {msg}", file=sys.stderr)
        return code

    try:
        sc = load_scenario(args.scenario)
        spec = next((a for a in sc.agents if a.id == args.id), None)
        if spec is None:
            return fail(f"--id {args.id}: not an agent of {args.scenario}")
        mission = keys.validate_id(args.mission or sc.name, "mission")
    except (ScenarioError, keys.KeyFormatError) as e:
        return fail(str(e))
    transport = ZenohTransport(client_config(args.connect or ["tcp/127.0.0.1:7447"]), None,
                               f"fly-{args.id}")
    clock = RemoteClock(transport, mission)
    driver = None
    feed = None
    try:
        if not clock.wait_synced(10.0):
            return fail(f"no clock on {keys.clock_key(mission)}: is the ground station running?")
        ctl = FlightController(FlightConfig(model=ThrustModel(), lo=sc.space.lo, hi=sc.space.hi))
        holder: list[MavlinkDriver] = []
        feed = ZenohMocapFeed(transport, mission, args.id,
                              on_pose=lambda: holder[0].notify_pose() if holder else None)
        try:
            driver = MavlinkDriver(args.mavlink, feed, ctl,
                                   DriverConfig(autopilot=args.autopilot, rate_hz=args.rate,
                                                mocap_stale_s=args.mocap_stale),
                                   clock)
        except FlightError as e:
            return fail(str(e))
        holder.append(driver)
        driver.start()
        source = MavlinkPoseSource(driver, feed)
        yaw = math.atan2(float(spec.v0[1]), float(spec.v0[0]))
        try:
            with land_on_signals(driver):
                driver.engage()
                if not source.goto(spec.p0, yaw, tol=0.1, timeout_s=60.0):
                    return fail("initial pose not reached within 60 s", EXIT_FLIGHT)
                print(f"viscover-fly hovering id={args.id}", flush=True)
                t_end = math.inf if args.duration is None else clock.now() + args.duration
                while clock.now() < t_end:
                    time.sleep(clock.wall(0.1))
        except FlightError as e:
            return fail(str(e), EXIT_FLIGHT)
        return 0 if driver.phase == "landed" else fail("landing not confirmed", EXIT_FLIGHT)
    finally:
        if driver is not None:
            driver.close()
        if feed is not None:
            feed.close()
        clock.close()
        transport.close()


if __name__ == "__main__":
    sys.exit(main())
