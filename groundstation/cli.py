"""``viscover groundstation``: mocap poses, landmark set and simulation clock on Zenoh.

:func:`register` adds the subcommand to the ``viscover`` parser (:mod:`agent.cli` calls it).

Sources (``--source`` has no default: a field install must never publish simulated poses to
real drones, so a missing or empty ``--source`` is refused in one line, exit 2):
``--source sim`` runs one simulated quadrotor per scenario agent, each a MAVLink 2 endpoint
on its own UDP port (``udpin``; connect a driver with ``udpout:HOST:PORT``), starting on the
ground below the agent's initial position; ``--source motioncapture`` reads real motion
capture (``--mocap-type``, ``--mocap-host``, rigid-body map from the flight file's
``[flight.mocap] bodies``; needs the ``mocap`` extra, ``pip install 'viscover[mocap]'``).
With the simulator every vehicle carries the flight file's pack (``flight.vehicle.battery_mah``)
unless ``--battery-capacity ID=MAH,...`` gives some their own (a battery hand-over rehearsed
with one small pack); a bad entry is refused in one line naming it.

Clock: with the simulator, the mission clock published on ``viscover/<m>/clock`` is the
physics' own time, paced at ``--time-scale`` (and dilated, never jumping, when the machine
cannot keep up); with real mocap it is the wall clock. It is published by the station's tick
right after that tick's poses (a publisher thread of its own only during the start-up check):
see :mod:`groundstation.station` for why. Processes that fly drones must follow
it (:class:`agent.net.clocksync.RemoteClock`) so pose timestamps and their clock agree.

Once running it prints one line on stdout:
``viscover-groundstation ready mission=M time_scale=X A=udp:127.0.0.1:14560 ...``.
Before that line it checks that the router passes its clock (a second session must hear it,
:mod:`groundstation.selfcheck`): a ground station whose certificate may not publish (e.g.
``--identity drone-A``) stops with one line instead. Exit codes: 0 ok (stopped by
SIGINT/SIGTERM or ``--duration``); 2 a user mistake, as one line on stderr.
"""

from __future__ import annotations

import argparse
import threading
from typing import Any

import msgspec
import numpy as np

from agent.clock import Clock, WallClock
from agent.commands import kit
from agent.commands.export_plan import origin
from agent.config.flight import FlightSection, drone_ports, load_flight
from agent.config.scenario import Scenario
from agent.errors import UsageError
from agent.net import security
from agent.net.clocksync import ClockPublisher, clock_heard
from agent.runners.process import open_transport, stop_on_signals
from agent.wire import keys
from groundstation.mocap import (
    MOCAP_TYPES,
    MocapError,
    MocapSource,
    MotionCaptureSource,
    SimMocapSource,
    import_motioncapture,
)
from groundstation.selfcheck import require_clock_passes
from groundstation.station import Station, landmark_set
from groundstation.vehicle.flavours import sim_flavour
from groundstation.vehicle.fleet import FleetClock, SimFleet
from groundstation.vehicle.params import VehicleParams

#: The pose sources ``--source`` may name.
SOURCES = ("sim", "motioncapture")

#: The refusal when ``--source`` is missing or empty (e.g. ``VISCOVER_GS_SOURCE`` unset in the
#: systemd unit's environment file): one line, exit 2.
NO_SOURCE = ("--source is required: sim (simulated vehicles, rehearsals) or motioncapture "
             "(real drones); the systemd unit takes it from VISCOVER_GS_SOURCE in "
             "/etc/viscover/viscover.env")


def source_of(value: str | None) -> str:
    """The ``--source`` value, checked: a :class:`UsageError` (one line) when it is missing,
    empty or not one of :data:`SOURCES` (never a default)."""
    if not value:
        raise UsageError(NO_SOURCE)
    if value not in SOURCES:
        raise UsageError(f"--source {value!r}: unknown source; choose sim or motioncapture")
    return value


def _ports(text: str) -> dict[str, int]:
    out: dict[str, int] = {}
    for item in filter(None, text.split(",")):
        drone, sep, port = item.partition("=")
        if not sep or not port.isdigit() or not 0 <= int(port) <= 65535:
            raise argparse.ArgumentTypeError(f"{item!r}: expected ID=PORT, e.g. A=14560")
        out[drone.strip()] = int(port)
    return out


def register(sub: kit.Subparsers) -> None:
    """Add ``groundstation``."""
    g = sub.add_parser(
        "groundstation", help="publish mocap poses, landmarks and the clock (sim or real mocap)",
        description="Publish each drone's motion-capture pose, the mission's landmark set and "
        "the simulation clock on Zenoh. Flight settings come from <scenario>.flight.toml or "
        "--flight.")
    g.add_argument("--scenario", required=True, metavar="FILE.toml",
                   help="the mission's scenario file (the same on every machine)")
    g.add_argument("--flight", metavar="FILE.toml",
                   help="flight settings (default: <scenario>.flight.toml if present)")
    kit.add_network_arguments(g)
    g.add_argument("--rate", type=kit.positive, default=None, metavar="HZ",
                   help="mocap publish rate [Hz, simulation time] (default 100)")
    # Checked by source_of (not argparse's choices) so that a missing or empty value, as an
    # unset VISCOVER_GS_SOURCE gives the systemd unit, is refused in one line.
    kit.required_option(g, "--source", missing=NO_SOURCE, metavar="{sim,motioncapture}",
                        help="where poses come from (no default): sim = simulated vehicles "
                        "(rehearsals), motioncapture = real mocap (needs viscover[mocap])")
    g.add_argument("--mocap-type", choices=MOCAP_TYPES, default=None,
                   help="motion-capture system (default: the flight file's)")
    g.add_argument("--mocap-host", default=None, metavar="HOST",
                   help="motioncapture source: the host (name or IP address) of the motion "
                   "capture server (default: flight.mocap.host of the flight file)")
    g.add_argument("--time-scale", type=kit.positive, default=1.0, metavar="X",
                   help="simulation seconds per wall second (sim source only)")
    g.add_argument("--ports", type=_ports, default={}, metavar="ID=PORT,...",
                   help="UDP port of each simulated vehicle (overrides the flight file)")
    g.add_argument("--duration", type=kit.positive, default=None, metavar="S",
                   help="stop after S simulation seconds")
    g.add_argument("--battery-capacity", default="", metavar="ID=MAH,...",
                   help="sim source: these vehicles' own battery packs [mAh] (the others "
                   "keep the flight file's flight.vehicle.battery_mah)")
    g.add_argument("--gnss", choices=["rtk", "3d"], default=None,
                   help="sim source: the vehicles fly outdoors with this GNSS receiver (their "
                   "EKF estimate, not mocap, is what they report; agents fly with --pose "
                   "autopilot; no mocap is published)")
    g.add_argument("--origin", type=origin, default=None, metavar="LAT,LON,ALT",
                   help="with --gnss: the vehicles' EKF origin, the mission's geodetic origin "
                   "(default: the autopilot's SITL start location)")
    kit.add_log_level(g)
    g.set_defaults(func=cmd_groundstation)


def _motioncapture(args: argparse.Namespace, scenario: Scenario, flight: FlightSection,
                   clock: Clock) -> MocapSource:
    ids = [a.id for a in scenario.agents]
    m = flight.mocap
    bodies = m.bodies or {d: d for d in ids}
    unknown = sorted(set(bodies.values()) - set(ids))
    if unknown:
        raise UsageError(f"flight.mocap.bodies: drone ids {', '.join(unknown)} are not "
                         "agents of the scenario")
    mtype = args.mocap_type or m.type
    options: dict[str, str] = {}
    if mtype == "mock":
        options["rigid_bodies"] = m.mock_bodies or ";".join(
            f"{b}({a.p0[0]},{a.p0[1]},{a.p0[2]},1,0,0,0)"
            for b, d in bodies.items() for a in scenario.agents if a.id == d)
    try:
        return MotionCaptureSource(mtype, bodies, clock, host=args.mocap_host or m.host,
                                   options=options)
    except MocapError as e:
        raise UsageError(str(e)) from None


def _sim_fleet(args: argparse.Namespace, scenario: Scenario, flight: FlightSection,
               clock: Clock) -> SimFleet:
    ids = [a.id for a in scenario.agents]
    ports = drone_ports(flight, ids)
    bad = sorted(set(args.ports) - set(ids))
    if bad:
        raise UsageError(f"--ports: {', '.join(bad)} not agents of the scenario")
    ports.update(args.ports)
    if args.origin is not None and args.gnss is None:
        raise UsageError("--origin goes with --gnss (indoor vehicles fly in the room's frame)")
    try:
        params = VehicleParams.from_section(flight.vehicle, flight.autopilot,
                                            indoor=args.gnss is None, gnss=args.gnss)
    except ValueError as e:
        raise UsageError(f"flight.vehicle: {e}") from None
    if args.origin is not None:
        params = msgspec.structs.replace(params, origin=(args.origin.lat, args.origin.lon,
                                                     args.origin.alt))
    if args.gnss is not None:
        # Set up for the field as its flavour's pre-flight check asks (ArduPilot: the
        # uploaded fence enforced, FENCE_ENABLE 1; it never acts on a fence with 0).
        params = msgspec.structs.replace(params, params={
            **sim_flavour(params.autopilot).field_params, **params.params})
    start = np.array([[a.p0[0], a.p0[1], 0.0] for a in scenario.agents])
    yaw0 = [float(np.arctan2(a.v0[1], a.v0[0])) for a in scenario.agents]
    packs = kit.battery_capacities(args.battery_capacity, ids)
    each = [msgspec.structs.replace(params, battery_mah=packs[d]) if d in packs else params
            for d in ids]
    try:
        return SimFleet(ids, clock, each, [ports[d] for d in ids], start, yaw0,
                        host=flight.host, seed=flight.seed)
    except OSError as e:
        raise UsageError(f"cannot open the simulated vehicles' UDP ports "
                         f"{sorted(ports.values())}: {e.strerror or e}") from None


def _identity(args: argparse.Namespace) -> str | None:
    """The certificate the ground station presents (None: the open profile)."""
    if security.team_dir(getattr(args, "tls_dir", None)) is None:
        return None
    return args.identity or security.GROUND


def cmd_groundstation(args: argparse.Namespace) -> int:
    """Run the ground station until SIGINT/SIGTERM or ``--duration``."""
    kit.setup_logging(args.log_level, "groundstation")
    args.source = source_of(args.source)
    if args.source == "motioncapture":
        try:
            import_motioncapture()  # before anything else: say at once what is missing
        except MocapError as e:
            raise UsageError(str(e)) from None
    scenario = kit.scenario_arg(args.scenario)
    flight = load_flight(args.scenario, args.flight)
    mission = kit.mission_name(args.mission, scenario)
    if args.source == "motioncapture" and args.time_scale != 1.0:
        raise UsageError("--time-scale applies to the simulator only (real mocap runs in real "
                         "time)")
    if args.source == "motioncapture" and args.battery_capacity:
        raise UsageError("--battery-capacity applies to the simulator only (a real drone's "
                         "pack is its own)")
    if args.source == "motioncapture" and args.gnss is not None:
        raise UsageError("--gnss applies to the simulator only (real drones outdoors need no "
                         "ground station pose: run the agents with --pose autopilot)")
    pace = WallClock(args.time_scale)
    cfg = kit.zenoh_config(args)
    stop = threading.Event()
    fleet: SimFleet | None = None
    source: Any = None
    transport = publisher = None
    with stop_on_signals(stop):
        try:
            if args.source == "motioncapture":
                source = _motioncapture(args, scenario, flight, pace)
                clock: Clock = pace  # real mocap: the wall clock
            else:
                fleet = _sim_fleet(args, scenario, flight, pace)
                source = SimMocapSource(fleet.start())
                clock = FleetClock(fleet)  # simulation: the physics' own time
            transport = open_transport(cfg, None, "groundstation", args.connect_wait, stop)
            if clock_heard(transport, mission):
                raise UsageError(f"a ground station is already running for mission {mission} "
                                 f"(its clock is on {keys.clock_key(mission)}): stop it "
                                 "first, or use another --mission")
            publisher = ClockPublisher(transport, mission, clock).start()  # for the check
            require_clock_passes(cfg, mission, _identity(args))
            publisher.stop()  # from now on the station's tick publishes it, after its poses
            lms = landmark_set(mission, scenario.landmark_ids, scenario.q, scenario.u)
            station = Station(transport, mission, source, clock, args.rate or flight.rate,
                              flight.stale_s, lms, flight.landmarks_period_s, pace=pace,
                              clock_period_s=publisher.period_s, clock_seq=publisher.seq,
                              mocap=args.gnss is None)  # outdoors: no mocap to publish
            quads = fleet.quads if fleet is not None else []
            where = " ".join(f"{q.name}=udp:{flight.host}:{q.port}" for q in quads)
            print(f"viscover-groundstation ready mission={mission} "
                  f"time_scale={clock.time_scale:g} {where}".rstrip(), flush=True)
            station.run(stop, args.duration)
            return 0
        finally:
            if publisher is not None:
                publisher.stop()
            if source is not None:
                source.close()
            elif fleet is not None:
                fleet.close()
            if transport is not None:
                transport.close()
