"""``viscover launch``: a whole mission from one command (:mod:`agent.mission.launcher`)."""

from __future__ import annotations

import argparse
import signal
import threading
from pathlib import Path
from types import FrameType

from agent.commands import kit
from agent.errors import UsageError
from agent.mission.launcher import ROLES, Launcher, LaunchPlan
from agent.mission.runfolder import check_resume, new_run_dir


def register(sub: kit.Subparsers) -> None:
    """Add ``launch``."""
    p = sub.add_parser(
        "launch", help="run a whole mission: router, ground station, agents; watch it",
        description="Start what a mission needs on this machine (a Zenoh router on a free port "
        "unless --router is given, the ground station with simulated vehicles for --flight, "
        "one agent process per drone), show its progress, keep every process's output and a "
        "recording (events.jsonl, recording.mcap) in a fresh run folder, and on Ctrl-C or "
        "SIGTERM land every drone and stop everything. "
        "Exit status: 0 complete, or ended by the operator (viscover land / stop), 1 "
        "violation or failure, 2 a user mistake (a run folder of another scenario, no router "
        "at --router), 3 not complete within --timeout, 130 interrupted (128 + the signal).")
    p.add_argument("scenario", metavar="SCENARIO.toml")
    p.add_argument("--flight", action="store_true",
                   help="fly simulated quadrotors over MAVLink (ground station + flying agents)")
    p.add_argument("--router", type=kit.endpoint, metavar="ENDPOINT",
                   help="use this running router instead of starting one")
    p.add_argument("--routers", type=int, default=1, metavar="N",
                   help="start N routers here, each linked to every other (a mesh, as when "
                   "drones and ground station are on different links), and spread the agents "
                   "over them, each with the others as fallbacks (default 1; at most "
                   f"{MAX_ROUTERS})")
    p.add_argument("--connect-wait", type=kit.non_negative, default=30.0, metavar="S",
                   help="wait up to S seconds for the --router to answer (default 30)")
    p.add_argument("--runs", default="runs", metavar="DIR",
                   help="where run folders are created (default ./runs)")
    p.add_argument("--resume", metavar="RUN_DIR",
                   help="resume the mission of an earlier run folder (its journals); refused "
                   "if the folder is of another scenario")
    p.add_argument("--only", default=",".join(ROLES), metavar="ROLES",
                   help="start only these here: router, groundstation, agents (comma-separated; "
                   "the rest runs elsewhere)")
    p.add_argument("--id", default="", metavar="A,B", help="start only these agents here")
    p.add_argument("--mission", help="mission name (key prefix); default: scenario name")
    p.add_argument("--restart", action="store_true",
                   help="restart a crashed agent with its journal (at most 5 times)")
    p.add_argument("--rate-scale", type=kit.positive, default=10.0, metavar="X",
                   help="kinematic agents run X times faster than real time (default 10)")
    p.add_argument("--time-scale", type=kit.positive, default=3.0, metavar="X",
                   help="the simulated fleet runs X times faster than real time (default 3)")
    p.add_argument("--timeout", type=kit.positive, default=None, metavar="S",
                   help="stop after S seconds if not complete (exit 3)")
    p.add_argument("--agent-arg", action="append", default=[], metavar="ARG",
                   help="extra option passed to every agent, e.g. --agent-arg=--drop=0.3")
    rec = p.add_mutually_exclusive_group()
    rec.add_argument("--record", metavar="DIR",
                     help="record the mission (events.jsonl, recording.mcap) into DIR "
                     "(default: the run folder)")
    rec.add_argument("--no-record", action="store_true", help="do not record the mission")
    p.add_argument("--live", type=int, default=None, metavar="PORT",
                   help="also serve the recording live to Foxglove on ws://127.0.0.1:PORT")
    p.add_argument("--outdoor", nargs="?", const="", default=None, metavar="LAT,LON,ALT",
                   help="with --flight: the simulated vehicles fly outdoors on RTK GNSS around "
                   "this geodetic origin (default PX4's SITL location) and the agents on their "
                   "autopilot's pose, with the mission space uploaded as a fence")
    p.add_argument("--battery-capacity", default="", metavar="ID=MAH,...",
                   help="with --flight: these simulated vehicles get their own pack [mAh] and "
                   "their agents are told its capacity (a battery hand-over rehearsed), e.g. "
                   "A=180")
    p.add_argument("--tls-dir", metavar="DIR", default=None,
                   help="secured profile: the team directory of deploy/make-certs.py (mutual "
                   "TLS, access control, signed trades) for every process started; default "
                   "$VISCOVER_TLS_DIR, unset: the open lab profile")
    p.set_defaults(func=cmd_launch)


def plan_of(args: argparse.Namespace) -> LaunchPlan:
    """The :class:`LaunchPlan` of parsed ``viscover launch`` arguments."""
    sc = kit.scenario_arg(args.scenario)
    only = frozenset(x for x in args.only.split(",") if x)
    bad = sorted(only - set(ROLES))
    if bad:
        raise UsageError(f"--only: unknown role {', '.join(bad)}; choose from "
                         f"{', '.join(ROLES)}")
    all_ids = [a.id for a in sc.agents]
    ids = tuple(x for x in args.id.split(",") if x) or tuple(all_ids)
    unknown = [x for x in ids if x not in all_ids]
    if unknown:
        raise UsageError(f"--id: {', '.join(unknown)} not agents of {args.scenario} "
                         f"(agents: {', '.join(all_ids)})")
    if "router" not in only and args.router is None:
        raise UsageError("--only without router: give the mission's router with --router")
    if not 1 <= args.routers <= MAX_ROUTERS:
        raise UsageError(f"--routers {args.routers}: give 1 to {MAX_ROUTERS} routers")
    if args.routers > 1 and (args.router is not None or "router" not in only):
        raise UsageError(f"--routers {args.routers} starts the routers here: drop --router "
                         "(or give every router's address to each agent with --only agents "
                         "--agent-arg=--connect=ENDPOINT)")
    if args.resume:
        run_dir = Path(args.resume)
        if not (run_dir / "state").is_dir():
            raise UsageError(f"--resume {run_dir}: not a run folder (no state/ inside)")
        check_resume(run_dir, sc, args.scenario)
    else:
        run_dir = new_run_dir(Path(args.runs), sc.name)
    record = None if args.no_record else Path(args.record) if args.record else run_dir
    if record is not None and record.exists() and not record.is_dir():
        raise UsageError(f"--record {record}: exists and is not a directory")
    if args.live is not None and record is None:
        raise UsageError("--live serves the recording: drop --no-record")
    packs = kit.battery_capacities(args.battery_capacity, all_ids)
    if packs and not args.flight:
        raise UsageError("--battery-capacity gives simulated vehicles their packs: add --flight")
    return LaunchPlan(
        scenario_path=args.scenario, scenario=sc, mission=kit.mission_name(args.mission, sc),
        run_dir=run_dir, resume=bool(args.resume), flight=args.flight, router=args.router,
        routers=args.routers,
        only=only, ids=ids, restart=args.restart, rate_scale=args.rate_scale,
        time_scale=args.time_scale, timeout_s=args.timeout,
        agent_args=tuple(args.agent_arg) + outdoor_agent_args(args),
        ground_args=outdoor_ground_args(args) + (
            ("--battery-capacity", args.battery_capacity) if packs else ()),
        own_args={a: ("--battery-capacity", f"{mah:g}") for a, mah in packs.items()},
        record=record, live=args.live, tls_dir=args.tls_dir,
        connect_wait_s=args.connect_wait)


#: Most routers ``--routers`` starts on one machine (a mesh of n links n(n-1)/2 pairs).
MAX_ROUTERS = 8


#: Where the simulated vehicles fly with ``--outdoor`` and no origin given: PX4's SITL start
#: location (latitude, longitude [deg], altitude [m AMSL]).
OUTDOOR_ORIGIN = "47.397742,8.545594,488.0"


def _outdoor(args: argparse.Namespace) -> str | None:
    """The geodetic origin of an ``--outdoor`` launch (None: indoors on mocap)."""
    if args.outdoor is None:
        return None
    if not args.flight:
        raise UsageError("--outdoor flies the simulated vehicles: add --flight")
    return str(args.outdoor or OUTDOOR_ORIGIN)


def outdoor_agent_args(args: argparse.Namespace) -> tuple[str, ...]:
    """The agents' options of an ``--outdoor`` launch: pose from the autopilot, the origin."""
    o = _outdoor(args)
    return () if o is None else ("--pose", "autopilot", "--origin", o)


def outdoor_ground_args(args: argparse.Namespace) -> tuple[str, ...]:
    """The ground station's options of an ``--outdoor`` launch: RTK receivers, the origin."""
    o = _outdoor(args)
    return () if o is None else ("--gnss", "rtk", "--origin", o)


def cmd_launch(args: argparse.Namespace) -> int:
    """``viscover launch SCENARIO.toml ...``."""
    kit.setup_logging(args.log_level, "launch")
    launcher = Launcher(plan_of(args))
    stop = threading.Event()
    got: list[int] = []

    def on_signal(signum: int, _frame: FrameType | None) -> None:
        # No printing here: the main thread may hold the print lock (the launcher says it).
        got.append(signum)
        stop.set()

    previous = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        return launcher.run(stop, got)  # 128 + the signal when interrupted
    finally:
        for s, h in previous.items():
            signal.signal(s, h)
