"""``viscover preflight``: read a flight controller's parameters over MAVLink and say whether
it would take our forwarded mocap and our attitude set-points (the rules of
:mod:`agent.flight.preflight`; the flying agent runs the same check before every take-off).

``--pose autopilot`` checks a vehicle that flies on its own (GNSS/RTK) estimate: the rules
that make its EKF fuse forwarded motion capture are skipped. ``--fence`` adds the fence
rules (ArduPilot FENCE_ENABLE, FENCE_ACTION, FENCE_TYPE; PX4 GF_ACTION).

Prints one line per problem (the parameter, its value, what it needs and the fix), the
battery if the vehicle reported it (``viscover-preflight battery: 80 %, 15.80 V, 12.0 A``),
then ``viscover-preflight ok: ...`` or ``viscover-preflight refused: ...``. Exit statuses: 0
ok (warnings allowed); 1 a fatal problem, or no vehicle answered; 2 a user mistake.
"""

from __future__ import annotations

import argparse
import sys

from agent.clock import WallClock
from agent.commands import kit
from agent.errors import EXIT_FAILURE, EXIT_OK, UsageError
from agent.flight.autopilot_check import check_autopilot
from agent.flight.battery import BatteryReader
from agent.flight.controllers import FlightController
from agent.flight.driver_types import DriverConfig, FlightError
from agent.flight.flavours import flavour_names, flavour_of_heartbeat
from agent.flight.mavlink_driver import MavlinkDriver
from agent.flight.preflight import problem_line


def register(sub: kit.Subparsers) -> None:
    """Add ``preflight``."""
    p = sub.add_parser("preflight", help="check a flight controller's configuration",
                       description="Read the autopilot's parameters over MAVLink and refuse, "
                       "with a one-line fix each, when it would ignore forwarded mocap or "
                       "attitude set-points. Nothing is armed or changed.")
    p.add_argument("--mavlink", required=True, metavar="CONN",
                   help="pymavlink connection string, e.g. udpout:127.0.0.1:14560 or "
                   "/dev/ttyAMA0,921600")
    p.add_argument("--autopilot", choices=flavour_names(), default=None,
                   help="flavour (default: from the vehicle's HEARTBEAT)")
    p.add_argument("--pose", choices=["mocap", "autopilot"], default="mocap",
                   help="what the flight will fly on: forwarded motion capture (default) or "
                   "the autopilot's own GNSS/RTK estimate")
    p.add_argument("--fence", action="store_true",
                   help="also check that the autopilot enforces an uploaded fence")
    p.add_argument("--timeout", type=kit.positive, default=3.0, metavar="S",
                   help="wait this long for the vehicle's HEARTBEAT [s] (default 3)")
    kit.add_log_level(p)
    p.set_defaults(func=cmd_preflight)


def _open(conn: str, autopilot: str, timeout_s: float) -> MavlinkDriver:
    """A started driver (heartbeats only, never a set-point) that has heard the vehicle."""
    try:
        drv = MavlinkDriver(conn, lambda: None, FlightController(),
                            DriverConfig(autopilot=autopilot, heartbeat_timeout_s=timeout_s,
                                         ack_timeout_s=1.0, forward="none"), WallClock())
    except FlightError as e:
        raise UsageError(f"--mavlink: {e}") from None
    drv.start()
    try:
        drv.wait_heartbeat()
    except BaseException:
        drv.close()
        raise
    return drv


def cmd_preflight(args: argparse.Namespace) -> int:
    """``viscover preflight --mavlink CONN [--autopilot ardupilot|px4]``."""
    kit.setup_logging(args.log_level, "preflight")
    try:
        drv = _open(args.mavlink, args.autopilot or "ardupilot", args.timeout)
    except FlightError as e:
        print(f"viscover-preflight refused: {e}", file=sys.stderr)
        return EXIT_FAILURE
    battery = BatteryReader(drv.link)
    try:
        known = flavour_of_heartbeat(drv.vehicle.autopilot)
        seen = None if known is None else known.name
        if args.autopilot is not None and seen is not None and seen != args.autopilot:
            raise UsageError(f"--autopilot {args.autopilot}: the vehicle's HEARTBEAT says "
                             f"{seen}")
        if seen is None and args.autopilot is None:
            raise UsageError(f"unknown autopilot {drv.vehicle.autopilot} in the HEARTBEAT; "
                             f"give --autopilot ({', '.join(flavour_names())})")
        drv.cfg.autopilot = args.autopilot or seen or drv.cfg.autopilot
        report = check_autopilot(drv, drv.controller.model.hover_thrust, args.pose, args.fence)
        power = battery.state
    finally:
        battery.close()
        drv.close()
    for p in report.problems:
        print(problem_line(p))
    if power.source:
        print(f"viscover-preflight battery: {power.summary()}")
    if report.fatal:
        print(f"viscover-preflight refused: {report.refusal()}")
        return EXIT_FAILURE
    print(f"viscover-preflight ok: {report.summary()}")
    return EXIT_OK
