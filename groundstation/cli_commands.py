"""``viscover groundstation``: mocap poses, landmark set and simulation clock on Zenoh.

:func:`register` adds the subcommand to the ``viscover`` parser (``agent.cli`` calls it);
``python -m groundstation.cli_commands groundstation ...`` runs it standalone.

Sources: ``--source sim`` (default) runs one simulated quadrotor per scenario agent, each a
MAVLink 2 endpoint on its own UDP port (``udpin``; connect a driver with
``udpout:HOST:PORT``), starting on the ground below the agent's initial position;
``--source motioncapture`` reads real motion capture (``--mocap-type``, ``--mocap-host``,
rigid-body map from the flight file's ``[flight.mocap] bodies``).

Clock: with the simulator, the mission clock published on ``viscover/<m>/clock`` is the
physics' own time, paced at ``--time-scale`` (and dilated, never jumping, when the machine
cannot keep up); with real mocap it is the wall clock. Processes that fly drones must follow
it (``groundstation.clock.RemoteClock``) so pose timestamps and their clock agree.

Once running it prints one line on stdout:
``viscover-groundstation ready mission=M time_scale=X A=udp:127.0.0.1:14560 ...``.
Exit codes: 0 ok (stopped by SIGINT/SIGTERM or ``--duration``); 2 a user mistake, as one line
on stderr.
"""

from __future__ import annotations

import argparse
import logging
import math
import signal
import sys
import threading
from types import FrameType
from typing import Any

EXIT_USAGE = 2
_log = logging.getLogger("viscover.groundstation")


class _UsageError(Exception):
    """A mistake the user can fix (one line, exit 2)."""


def _positive(text: str) -> float:
    try:
        x = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not (x > 0 and math.isfinite(x)):
        raise argparse.ArgumentTypeError(f"{text} must be a finite number > 0")
    return x


def _ports(text: str) -> dict[str, int]:
    out: dict[str, int] = {}
    for item in filter(None, text.split(",")):
        drone, sep, port = item.partition("=")
        if not sep or not port.isdigit() or not 0 <= int(port) <= 65535:
            raise argparse.ArgumentTypeError(f"{item!r}: expected ID=PORT, e.g. A=14560")
        out[drone.strip()] = int(port)
    return out


def add_parser(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add ``groundstation`` to ``subparsers``."""
    g = subparsers.add_parser(
        "groundstation", help="publish mocap poses, landmarks and the clock (sim or real mocap)",
        description="Publish each drone's motion-capture pose, the mission's landmark set and "
        "the simulation clock on Zenoh. Flight settings come from <scenario>.flight.toml or "
        "--flight.")
    g.add_argument("--scenario", required=True, metavar="FILE.toml")
    g.add_argument("--flight", metavar="FILE.toml",
                   help="flight settings (default: <scenario>.flight.toml if present)")
    g.add_argument("--zenoh", metavar="FILE", help="Zenoh client config (json5)")
    g.add_argument("--connect", metavar="ENDPOINT", action="append", default=[],
                   help="router endpoint, e.g. tcp/127.0.0.1:7447 (repeatable)")
    g.add_argument("--mission", help="mission name (key prefix); default: scenario name")
    g.add_argument("--rate", type=_positive, default=None, metavar="HZ",
                   help="mocap publish rate [Hz, simulation time] (default 100)")
    g.add_argument("--source", choices=("sim", "motioncapture"), default="sim")
    g.add_argument("--mocap-type", choices=("mock", "vicon", "optitrack", "qualisys", "vrpn"),
                   default=None, help="motion-capture system (default: the flight file's)")
    g.add_argument("--mocap-host", default=None, metavar="HOST")
    g.add_argument("--time-scale", type=_positive, default=1.0, metavar="X",
                   help="simulation seconds per wall second (sim source only)")
    g.add_argument("--ports", type=_ports, default={}, metavar="ID=PORT,...",
                   help="UDP port of each simulated vehicle (overrides the flight file)")
    g.add_argument("--duration", type=_positive, default=None, metavar="S",
                   help="stop after S simulation seconds")
    g.add_argument("--log-level", default="WARNING")
    g.set_defaults(func=run)


def register(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Register ``groundstation`` (the entry point ``agent.cli`` uses)."""
    add_parser(subparsers)


def _mission(args: argparse.Namespace, scenario_name: str) -> str:
    from agent.wire import keys

    name = args.mission or "".join(c if c.isalnum() or c in "_-" else "_"
                                   for c in scenario_name)[:32]
    try:
        return keys.validate_id(name, "mission")
    except keys.KeyFormatError as e:
        raise _UsageError(f"--mission: {e}") from None


def _zenoh_config(args: argparse.Namespace) -> Any:
    from pathlib import Path

    from agent.net.router import client_config

    if args.connect:
        return client_config(args.connect)
    if args.zenoh:
        import zenoh

        if not Path(args.zenoh).is_file():
            raise _UsageError(f"--zenoh {args.zenoh}: no such file")
        try:
            return zenoh.Config.from_file(args.zenoh)
        except Exception as e:
            raise _UsageError(f"--zenoh {args.zenoh}: {e}") from None
    return client_config(["tcp/127.0.0.1:7447"])


def _build_source(args: argparse.Namespace, scenario: Any, flight: Any, clock: Any) -> Any:
    import numpy as np

    from agent.config.flight import drone_ports
    from groundstation.mocap import MocapError, MotionCaptureSource, SimMocapSource
    from groundstation.sim_quad import SimFleet, VehicleParams

    ids = [a.id for a in scenario.agents]
    if args.source == "motioncapture":
        m = flight.mocap
        bodies = m.bodies or {d: d for d in ids}
        unknown = sorted(set(bodies.values()) - set(ids))
        if unknown:
            raise _UsageError(f"flight.mocap.bodies: drone ids {', '.join(unknown)} are not "
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
            raise _UsageError(str(e)) from None
    ports = drone_ports(flight, ids)
    ports.update({d: p for d, p in args.ports.items() if d in ports})
    bad = sorted(set(args.ports) - set(ids))
    if bad:
        raise _UsageError(f"--ports: {', '.join(bad)} not agents of the scenario")
    v = flight.vehicle
    try:
        params = VehicleParams(autopilot=flight.autopilot, mass=v.mass,
                               hover_thrust=v.hover_thrust, drag=v.drag, tau_att=v.tau_att,
                               tau_thrust=v.tau_thrust, setpoint_timeout=v.setpoint_timeout,
                               land_speed=v.land_speed, telemetry_rate=v.telemetry_rate,
                               mocap_noise_pos=v.mocap_noise_pos,
                               mocap_noise_att=v.mocap_noise_att,
                               mocap_latency=v.mocap_latency)
    except ValueError as e:
        raise _UsageError(f"flight.vehicle: {e}") from None
    start = np.array([[a.p0[0], a.p0[1], 0.0] for a in scenario.agents])
    yaw0 = [float(np.arctan2(a.v0[1], a.v0[0])) for a in scenario.agents]
    try:
        fleet = SimFleet(ids, clock, params, [ports[d] for d in ids], start, yaw0,
                         host=flight.host, seed=flight.seed)
    except OSError as e:
        raise _UsageError(f"cannot open the simulated vehicles' UDP ports "
                          f"{sorted(ports.values())}: {e.strerror or e}") from None
    return SimMocapSource(fleet.start())


def run(args: argparse.Namespace) -> int:
    """Run the ground station until SIGINT/SIGTERM or ``--duration``."""
    logging.basicConfig(level=getattr(logging, str(args.log_level).upper(), logging.WARNING),
                        format="%(asctime)s %(name)s %(levelname)s %(message)s")
    from agent.clock import WallClock
    from agent.config.flight import load_flight
    from agent.config.scenario import ScenarioError, load_scenario
    from agent.net.clocksync import ClockPublisher
    from groundstation.sim_quad import FleetClock
    from groundstation.station import Station, landmark_set

    try:
        scenario = load_scenario(args.scenario)
        flight = load_flight(args.scenario, args.flight)
        mission = _mission(args, scenario.name)
        if args.source == "motioncapture" and args.time_scale != 1.0:
            raise _UsageError("--time-scale applies to the simulator only (real mocap runs in "
                              "real time)")
        pace = WallClock(args.time_scale)
        cfg = _zenoh_config(args)
        source = _build_source(args, scenario, flight, pace)
        # Simulation: the physics' own time is the mission clock; real mocap: the wall clock.
        fleet = getattr(source, "fleet", None)
        clock = FleetClock(fleet) if fleet is not None else pace
    except (ScenarioError, _UsageError) as e:
        print(f"viscover: error: {e}", file=sys.stderr)
        return EXIT_USAGE
    from agent.net.transport import ZenohTransport

    stop = threading.Event()
    transport = None
    publisher = None
    try:
        try:
            transport = ZenohTransport(cfg, None, "groundstation")
        except Exception as e:
            print(f"viscover: error: cannot open a Zenoh session (is the router running?): {e}",
                  file=sys.stderr)
            return EXIT_USAGE
        publisher = ClockPublisher(transport, mission, clock).start()
        lms = landmark_set(mission, scenario.landmark_ids, scenario.q, scenario.u)
        station = Station(transport, mission, source, clock, args.rate or flight.rate,
                          flight.stale_s, lms, flight.landmarks_period_s, pace=pace)

        def on_signal(_signum: int, _frame: FrameType | None) -> None:
            stop.set()

        for s in (signal.SIGINT, signal.SIGTERM):
            signal.signal(s, on_signal)
        ports = getattr(getattr(source, "fleet", None), "quads", [])
        where = " ".join(f"{q.name}=udp:{flight.host}:{q.port}" for q in ports)
        print(f"viscover-groundstation ready mission={mission} time_scale={clock.time_scale:g}"
              f" {where}".rstrip(), flush=True)
        station.run(stop, args.duration)
        return 0
    finally:
        if publisher is not None:
            publisher.stop()
        source.close()
        if transport is not None:
            transport.close()


def main(argv: list[str] | None = None) -> int:
    """Standalone entry point: ``python -m groundstation.cli_commands groundstation ...``."""
    parser = argparse.ArgumentParser(prog="viscover")
    sub = parser.add_subparsers(dest="command", required=True)
    register(sub)
    try:
        args = parser.parse_args(argv)
    except SystemExit as e:
        return e.code if isinstance(e.code, int) else EXIT_USAGE
    return int(args.func(args))


if __name__ == "__main__":
    sys.exit(main())
