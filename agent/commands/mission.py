"""``viscover land`` and ``viscover stop``: mission commands to the agents over Zenoh, repeated
until every target acknowledged (:func:`agent.mission.operator.send_command`)."""

from __future__ import annotations

import argparse
import os

from agent.commands import kit
from agent.errors import EXIT_FAILURE, EXIT_OK, UsageError
from agent.mission.operator import live_agents, send_command
from agent.wire import keys

_WHAT = {
    "land": "every targeted agent leaves the mission, flies home and lands (a kinematic "
            "agent exits)",
    "stop": "emergency: every targeted agent leaves at once and has its flight controller "
            "land where it is (the autopilot's LAND mode)",
}


def register(sub: kit.Subparsers) -> None:
    """Add ``land`` and ``stop``."""
    for name in ("land", "stop"):
        p = sub.add_parser(name, help=f"{name} the drones of a mission",
                           description=f"Send '{name}' to the agents: {_WHAT[name]}. Repeated "
                           "until each target acknowledges (exit 1 if one does not within "
                           "--timeout).")
        p.add_argument("--scenario", required=True, metavar="FILE.toml",
                       help="the mission's scenario file (the same on every machine)")
        who = p.add_mutually_exclusive_group(required=True)
        who.add_argument("--all", action="store_true", help="every live agent of the mission")
        who.add_argument("--id", metavar="A,B", help="these agents")
        kit.add_network_arguments(p)
        p.add_argument("--timeout", type=kit.positive, default=10.0, metavar="S",
                       help="give up waiting for acknowledgements after S s (default 10)")
        kit.add_log_level(p)
        p.set_defaults(func=cmd_mission, command_kind=name)


def cmd_mission(args: argparse.Namespace) -> int:
    """``viscover land|stop --scenario S.toml --all|--id A,B``."""
    kit.setup_logging(args.log_level, "operator")
    sc = kit.scenario_arg(args.scenario)
    mission = kit.mission_name(args.mission, sc)
    ids = [a.id for a in sc.agents]
    tp = kit.open_session(args, f"operator-{os.getpid()}")
    try:
        if args.all:
            targets = sorted(live_agents(tp, mission, 1.0) & set(ids))
            if not targets:
                print(f"viscover: no live agent on mission {mission}")
                return EXIT_OK
        else:
            targets = [x for x in args.id.split(",") if x]
            for x in targets:
                try:
                    keys.validate_id(x)
                except keys.KeyFormatError as e:
                    raise UsageError(f"--id: {e}") from None
            unknown = [x for x in targets if x not in ids]
            if unknown:
                raise UsageError(f"--id: {', '.join(unknown)} not agents of {args.scenario} "
                                 f"(agents: {', '.join(ids)})")
        acks = send_command(tp, mission, args.command_kind, targets, timeout_s=args.timeout)
    finally:
        tp.close()
    for aid, t in acks.items():
        print(f"{aid}: {args.command_kind} acknowledged after {t:.2f} s" if t is not None
              else f"{aid}: no acknowledgement within {args.timeout:g} s")
    return EXIT_OK if all(t is not None for t in acks.values()) else EXIT_FAILURE
