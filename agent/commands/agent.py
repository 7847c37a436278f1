"""``viscover agent``: one drone's agent (parse the options, then
:func:`agent.runners.process.run_agent` or, with ``--mavlink``/``--flight``,
:func:`agent.runners.flying.run_flying_agent`)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from agent.commands import kit
from agent.commands.export_plan import origin
from agent.config.scenario import AgentSpec, Scenario
from agent.errors import UsageError
from agent.net.faults import FaultConfig
from agent.net.security import drone_name
from agent.runners.process import AgentOptions, run_agent
from agent.wire import keys

if TYPE_CHECKING:  # a kinematic agent does not load the flight stack (pymavlink): start-up
    from agent.runners.flying import FlightOptions


def register(sub: kit.Subparsers) -> None:
    """Add ``agent``."""
    a = sub.add_parser("agent", help="run one drone agent",
                       description="Run one agent: planner, landmark trading over Zenoh, "
                       "journal. Kinematic by default; flies a quadcopter over MAVLink with "
                       "--mavlink or --flight. Stops on SIGINT/SIGTERM (a flying agent lands "
                       "first); a kinematic agent then exits 130 after SIGINT (Ctrl-C), 0 after "
                       "SIGTERM (a service manager's stop).")
    a.add_argument("--id", required=True, help="agent id (as in the scenario)")
    a.add_argument("--scenario", required=True, metavar="FILE.toml",
                   help="the mission's scenario file (the same on every machine)")
    kit.add_network_arguments(a)
    a.add_argument("--state-dir", metavar="DIR", help="journal directory (default "
                   "~/.local/state/viscover/<mission>/<id>)")
    a.add_argument("--rate-scale", type=kit.positive, default=1.0, metavar="X",
                   help="run the mission clock X times faster than real time")
    a.add_argument("--exit-on-complete", action="store_true",
                   help="exit once the mission is complete")
    a.add_argument("--timeout", type=kit.positive, default=None, metavar="S",
                   help="give up after S real seconds (exit 3)")
    a.add_argument("--request-timeout", type=kit.positive, default=0.3, metavar="S",
                   help="real seconds a trade query waits for its reply (default 0.3)")
    a.add_argument("--join-at", metavar="X,Y[,Z]", default=None,
                   help="join a running mission as a drone not in the scenario (--id not in "
                   "it), starting here [m; world ENU] with no landmark; it trades once a "
                   "majority of the scenario's agents admitted it")
    a.add_argument("--join-yaw", type=kit.number, default=None, metavar="DEG",
                   help="camera heading of a joining drone [deg from +x, counter-clockwise] "
                   "(default: towards the centre of the landmarks)")
    f = a.add_argument_group("fault injection (seeded, logged)")
    f.add_argument("--drop", type=kit.probability, default=0.0, metavar="P",
                   help="drop probability of every message, both directions")
    f.add_argument("--drop-kind", type=kit.kind_probability, action="append", default=[],
                   metavar="KIND=P", help="drop probability for one kind (pose, state, trade, "
                   "trade.reply, alive...), both directions; repeatable")
    f.add_argument("--delay", type=kit.non_negative, default=0.0, metavar="S",
                   help="fixed delay [s]")
    f.add_argument("--jitter", type=kit.non_negative, default=0.0, metavar="S",
                   help="extra uniform delay in [0, S) [s]")
    f.add_argument("--dup", type=kit.probability, default=0.0, metavar="P",
                   help="duplication probability")
    f.add_argument("--partition", default="", metavar="A,B",
                   help="agent ids this agent cannot reach")
    f.add_argument("--fault-seed", type=int, default=0, metavar="N",
                   help="seed of the injected faults' random draws (default 0: a run replays)")
    f.add_argument("--fault-log", metavar="PATH", help="JSONL log of injected faults")
    kit.add_log_level(a)
    add_flight_arguments(a)
    a.set_defaults(func=cmd_agent)


def add_flight_arguments(p: argparse.ArgumentParser) -> None:
    """The flight options (flying iff ``--mavlink`` or ``--flight`` is given)."""
    g = p.add_argument_group("flight (fly a quadcopter over MAVLink; follows the ground "
                             "station's clock)")
    g.add_argument("--flight", metavar="FILE.toml", default=None,
                   help="flight settings (default: <scenario>.flight.toml if present)")
    g.add_argument("--mavlink", metavar="CONN", default=None,
                   help="pymavlink connection string of the vehicle, e.g. "
                   "udpout:127.0.0.1:14560 or /dev/ttyAMA0,921600 (default: this drone's port "
                   "from the flight settings)")
    g.add_argument("--setpoint-rate", type=kit.positive, default=50.0, metavar="HZ",
                   help="SET_ATTITUDE_TARGET rate [Hz, simulation time] (default 50)")
    g.add_argument("--mocap-stale", type=kit.positive, default=0.2, metavar="S",
                   help="mocap older than this [s sim] triggers the failsafe (default 0.2)")
    g.add_argument("--takeoff-timeout", type=kit.positive, default=60.0, metavar="S",
                   help="time allowed to reach the initial pose [s sim] (default 60)")
    g.add_argument("--settle-window", type=kit.positive, default=2.0, metavar="S",
                   help="converged once the measured pose stayed settled for S [s sim] "
                   "(default 2) ...")
    g.add_argument("--settle-radius", type=kit.positive, default=0.1, metavar="M",
                   help="... within M metres of its mean (default 0.1) ...")
    g.add_argument("--settle-angle", type=kit.positive, default=0.05, metavar="RAD",
                   help="... and the camera within RAD of its mean direction (default 0.05)")
    g.add_argument("--landing", choices=["home", "here"], default="home",
                   help="after the mission: 'home' flies at its height back above the launch "
                   "point, keeping R_s from the other drones (section 4.3), then lands; 'here' "
                   "lands where it is (default home)")
    g.add_argument("--home-timeout", type=kit.positive, default=120.0, metavar="S",
                   help="time allowed to get home before landing where it is [s sim] "
                   "(default 120)")
    g.add_argument("--clock-timeout", type=kit.positive, default=10.0, metavar="S",
                   help="wall seconds to wait for the ground station's clock (default 10)")
    g.add_argument("--link-timeout", type=kit.positive, default=3.0, metavar="S",
                   help="no HEARTBEAT from the vehicle for S [s sim]: the link is lost and "
                   "the agent leaves the mission (default 3)")
    g.add_argument("--battery-critical", type=percent, default=15.0,
                   metavar="PCT", help="battery remaining at or below PCT %%: the agent "
                   "leaves the mission and, still in its mode, lands (default 15)")
    g.add_argument("--battery-capacity", type=kit.positive, default=None, metavar="MAH",
                   help="the pack's capacity [mAh]: with the current drawn, how long the "
                   "battery lasts (default: the autopilot's own estimate, else 30 %% left)")
    g.add_argument("--no-hand-over", dest="hand_over", action="store_false",
                   help="do not hand the work over to the team when the battery will not "
                   "last through it and the way home")
    g.add_argument("--pose", choices=["mocap", "autopilot"], default="mocap",
                   help="fly on motion capture (default) or the autopilot's own (GNSS/RTK) "
                   "estimate")
    g.add_argument("--origin", metavar="LAT,LON,ALT", type=origin, default=None,
                   help="the mission's geodetic origin shared by every drone (degrees, "
                   "degrees, metres; with --pose autopilot): the world frame's (0, 0, 0), and "
                   "the mission space less 1 m is uploaded as the autopilot's fence")


def percent(text: str) -> float:
    """A percentage in [0, 100]."""
    x = kit.number(text)
    if not 0.0 <= x <= 100.0:
        raise argparse.ArgumentTypeError(f"{text} is not a percentage in [0, 100]")
    return x


def fault_config(args: argparse.Namespace) -> FaultConfig | None:
    """The fault model of the fault flags (None without faults)."""
    kinds = dict(args.drop_kind)
    partition = [x for x in args.partition.split(",") if x]
    for x in partition:
        try:
            keys.validate_id(x)
        except keys.KeyFormatError as e:
            raise UsageError(f"--partition: {e}") from None
    if not (args.drop or kinds or args.delay or args.jitter or args.dup or partition):
        return None
    return FaultConfig(drop_out=kinds, drop_in=dict(kinds), drop_default=args.drop,
                       delay_s=args.delay, jitter_s=args.jitter, duplicate=args.dup,
                       partition=partition)


def join_spec(args: argparse.Namespace, sc: Scenario) -> AgentSpec | None:
    """The joining drone of ``--join-at`` / ``--join-yaw`` (None: a scenario agent)."""
    if args.join_at is None:
        if args.join_yaw is not None:
            raise UsageError("--join-yaw: only with --join-at")
        kit.agent_spec(sc, args.id, args.scenario)
        return None
    if any(a.id == args.id for a in sc.agents):
        raise UsageError(f"--join-at: {args.id} is an agent of {args.scenario}; a joining "
                         "drone needs an id that is not in the scenario")
    try:
        xyz = [float(x) for x in args.join_at.split(",")]
    except ValueError:
        xyz = []
    dims = 2 if sc.planar else 3
    if len(xyz) != dims or not np.isfinite(xyz).all():
        raise UsageError(f"--join-at {args.join_at}: expected {dims} numbers X,Y"
                         f"{',Z' if dims == 3 else ''} [m] for this {dims}-D scenario")
    p0 = np.array([*xyz, 0.0][:3], dtype=np.float64)
    if not sc.space.contains(p0):
        raise UsageError(f"--join-at {args.join_at}: outside the mission space of "
                         f"{args.scenario}")
    if args.join_yaw is not None:
        yaw = np.radians(args.join_yaw)
    else:
        c = sc.q.mean(axis=0) - p0
        yaw = float(np.arctan2(c[1], c[0]))
    v0 = np.array([np.cos(yaw), np.sin(yaw), 0.0])
    return AgentSpec(args.id, p0, v0, np.zeros(0, dtype=np.intp))


def agent_options(args: argparse.Namespace) -> AgentOptions:
    """The :class:`AgentOptions` of parsed ``viscover agent`` arguments."""
    sc = kit.scenario_arg(args.scenario)
    join = join_spec(args, sc)
    return AgentOptions(join=join,
        agent_id=args.id, scenario=sc, mission=kit.mission_name(args.mission, sc),
        zenoh=kit.zenoh_config(args, drone_name(args.id)),
        signing=kit.signing_keys(args, args.id),
        state_dir=Path(args.state_dir) if args.state_dir else None,
        rate_scale=args.rate_scale, exit_on_complete=args.exit_on_complete,
        timeout_s=args.timeout, connect_wait_s=args.connect_wait,
        request_timeout_s=args.request_timeout, faults=fault_config(args),
        fault_seed=args.fault_seed, fault_log=args.fault_log)


def flight_options(args: argparse.Namespace) -> FlightOptions:
    """The :class:`FlightOptions` of parsed flight arguments."""
    from agent.commands.fly import field_options
    from agent.runners.flying import FlightOptions

    return FlightOptions(
        flight_file=args.flight, scenario_path=args.scenario, mavlink=args.mavlink,
        setpoint_rate_hz=args.setpoint_rate, mocap_stale_s=args.mocap_stale,
        takeoff_timeout_s=args.takeoff_timeout, settle_window_s=args.settle_window,
        settle_radius_m=args.settle_radius, settle_angle_rad=args.settle_angle,
        landing=args.landing, home_timeout_s=args.home_timeout,
        clock_timeout_s=args.clock_timeout, link_timeout_s=args.link_timeout,
        battery_critical_pct=args.battery_critical,
        battery_capacity_mah=args.battery_capacity, hand_over=args.hand_over,
        **field_options(args))


def cmd_agent(args: argparse.Namespace) -> int:
    """``viscover agent --id A --scenario S.toml ...``."""
    kit.setup_logging(args.log_level, args.id)
    opts = agent_options(args)
    if args.mavlink is not None or args.flight is not None:
        if opts.join is not None:
            raise UsageError("--join-at: a flown drone cannot join a running mission yet; "
                             "join with a kinematic agent, or list the drone in the scenario")
        from agent.runners.flying import run_flying_agent

        return run_flying_agent(opts, flight_options(args))
    return run_agent(opts)
