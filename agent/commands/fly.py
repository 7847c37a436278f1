"""``viscover fly``: a first flight test of one drone: take off to its initial pose, hold,
land (:func:`agent.runners.flying.run_hover`); no planner, no trading.

``--pose autopilot`` flies on the autopilot's own (GNSS/RTK) estimate instead of motion
capture (:mod:`agent.flight.autopilot_pose`), placed in the world frame at ``--origin``, the
mission's shared geodetic origin (``FlightOptions.pose``, ``FlightOptions.origin``); with an
origin the mission space less a margin is uploaded as the autopilot's fence.
"""

from __future__ import annotations

import argparse
from typing import Any

from agent.commands import kit
from agent.commands.export_plan import origin
from agent.errors import UsageError
from agent.net.security import drone_name
from agent.runners.flying import FlightOptions, run_hover


def register(sub: kit.Subparsers) -> None:
    """Add ``fly``."""
    p = sub.add_parser("fly", help="take off, hold the initial pose, land (flight test)",
                       description="Fly one drone to its initial pose from the scenario, hold "
                       "it until SIGINT/SIGTERM or --duration, then land. Follows the ground "
                       "station's clock and mocap. Prints 'viscover-fly hovering id=A' on "
                       "station.")
    p.add_argument("--scenario", required=True, metavar="FILE.toml",
                   help="the mission's scenario file (the same on every machine)")
    p.add_argument("--id", required=True, help="agent / drone id")
    p.add_argument("--mavlink", metavar="CONN", default=None,
                   help="pymavlink connection string (default: this drone's port from the "
                   "flight settings)")
    p.add_argument("--flight", metavar="FILE.toml", default=None,
                   help="flight settings (default: <scenario>.flight.toml if present)")
    kit.add_network_arguments(p)
    p.add_argument("--rate", type=kit.positive, default=50.0, help="set-point rate [Hz]")
    p.add_argument("--duration", type=kit.positive, default=None, help="hold time [s sim]")
    p.add_argument("--mocap-stale", type=kit.positive, default=0.2, metavar="S",
                   help="a pose older than this [s sim] triggers the failsafe (default 0.2)")
    p.add_argument("--pose", choices=["mocap", "autopilot"], default="mocap",
                   help="fly on motion capture (default) or the autopilot's own estimate")
    p.add_argument("--origin", metavar="LAT,LON,ALT", type=origin, default=None,
                   help="the mission's geodetic origin (degrees, degrees, metres) shared by "
                   "all drones; with --pose autopilot")
    kit.add_log_level(p)
    p.set_defaults(func=cmd_fly)


def cmd_fly(args: argparse.Namespace) -> int:
    """``viscover fly --scenario S.toml --id A ...``."""
    kit.setup_logging(args.log_level, args.id)
    sc = kit.scenario_arg(args.scenario)
    kit.agent_spec(sc, args.id, args.scenario)
    fopts = FlightOptions(flight_file=args.flight, scenario_path=args.scenario,
                          mavlink=args.mavlink, setpoint_rate_hz=args.rate,
                          mocap_stale_s=args.mocap_stale, **field_options(args))
    return run_hover(args.id, sc, kit.mission_name(args.mission, sc),
                     kit.zenoh_config(args, drone_name(args.id)),
                     fopts, args.duration)


def field_options(args: argparse.Namespace) -> dict[str, Any]:
    """``--pose``/``--origin`` as FlightOptions fields (``--origin`` only with the autopilot's
    pose: motion capture flies in the room's frame)."""
    if args.origin is not None and args.pose != "autopilot":
        raise UsageError("--origin goes with --pose autopilot (mocap flies in the room's frame)")
    return {"pose": args.pose, "origin": args.origin}
