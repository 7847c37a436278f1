"""``viscover ros2-bridge``: watch (and record) a mission with ROS 2 tools.

:func:`register` adds the subcommand (:mod:`agent.cli` lists it; it needs the ``ros2`` extra,
``pip install 'viscover[ros2]'``, and says so in one line when it is missing).

Once running it prints ``viscover-ros2-bridge ready: ...`` on stdout and bridges until
Ctrl-C / SIGTERM, ``--duration``, or the mission's mesh gone for :data:`MESH_GONE_S` (its
router stopped: the session has no router or peer; said once on stderr,
``viscover-ros2-bridge: mesh gone: no router/peers heard for 10 s; stopping``); then one line
on stderr with the messages sent per kind. ``--from-recording RUN_DIR --bag DIR`` instead
converts a recorded run, no network (:mod:`groundstation.ros2.convert`).
Exit statuses: 0 stopped by ``--duration`` or SIGTERM, or the mesh gone after the mission
completed; 1 the mesh gone before the mission completed; 130 Ctrl-C; 2 a user mistake (one
line).
"""

from __future__ import annotations

import argparse
import os
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from agent.commands import kit
from agent.errors import EXIT_FAILURE, EXIT_INTERRUPTED, EXIT_OK, UsageError
from agent.mission.watch import MESH_GONE_S
from agent.net.transport import ZenohTransport
from agent.runners.process import stop_on_signals
from groundstation.ros2 import rmw
from groundstation.ros2.bag import BagError, BagWriter
from groundstation.ros2.bridge import Bridge, rmw_summary
from groundstation.ros2.convert import ConvertError, convert, read_run
from groundstation.ros2.names import DEFAULT_NAMESPACE, Names, check_namespace
from groundstation.ros2.node import RosNode

#: the ROS domain when neither --domain nor $ROS_DOMAIN_ID says
DEFAULT_DOMAIN = 0


def _domain(text: str) -> int:
    if not text.isdigit() or int(text) > 232:
        raise argparse.ArgumentTypeError(f"{text!r}: a ROS domain id is an integer 0..232")
    return int(text)


def register(sub: kit.Subparsers) -> None:
    """Add ``ros2-bridge``."""
    p = sub.add_parser(
        "ros2-bridge", help="republish a mission as ROS 2 topics (rmw_zenoh) and/or a bag",
        description="Listen to a mission as an observer does and republish it as ROS 2 topics "
        "that rmw_zenoh nodes (rviz2, ros2 topic, ros2 bag) on the same Zenoh router see: "
        "per drone PoseStamped and /tf (world -> drone -> camera), landmarks and camera "
        "frusta as MarkerArray, diagnostics, events; <ns>/land and <ns>/stop "
        "(std_msgs/String: 'all' or drone ids) become viscover land / stop. --bag also "
        "writes a ROS 2 bag (MCAP, CDR). A drone's mocap topic is announced once its first "
        f"mocap pose comes. Once the mission's router has been gone for {MESH_GONE_S:g} s it "
        "says so and stops: exit 0 after a completed mission, else 1.")
    p.add_argument("--scenario", required=True, metavar="FILE.toml",
                   help="the mission's scenario file (the same on every machine)")
    kit.add_network_arguments(p)
    p.add_argument("--ros-connect", metavar="ENDPOINT", type=kit.endpoint, action="append",
                   default=[], help="publish the ROS topics through this router (e.g. the "
                   "ROS machines' rmw_zenohd, tcp/HOST:7447) instead of the mission's")
    p.add_argument("--domain", type=_domain, default=None, metavar="N",
                   help="ROS domain id (default $ROS_DOMAIN_ID, else 0)")
    p.add_argument("--distro", choices=rmw.DISTROS, default=rmw.DISTROS[0],
                   help="type hashes in keys and tokens: jazzy = RIHS01 (Jazzy and later, "
                   "the default), humble = TypeHashNotSupported")
    p.add_argument("--namespace", default=DEFAULT_NAMESPACE, metavar="NS",
                   help=f"namespace of the topics (default {DEFAULT_NAMESPACE})")
    p.add_argument("--bag", metavar="DIR", default=None,
                   help="also write a ROS 2 bag (MCAP storage) into DIR (must not exist)")
    p.add_argument("--no-publish", action="store_true",
                   help="publish no ROS topic (with --bag: record only)")
    p.add_argument("--from-recording", metavar="RUN_DIR", default=None,
                   help="no network: convert the recording of a run folder (viscover launch "
                   "/ record) of this scenario into the --bag")
    p.add_argument("--scene-hz", type=kit.positive, default=10.0, metavar="HZ",
                   help="most camera-frusta updates per second (default 10)")
    p.add_argument("--duration", type=kit.positive, default=None, metavar="S",
                   help="stop after S seconds")
    kit.add_log_level(p)
    p.set_defaults(func=cmd_ros2_bridge)


def domain_of(arg: int | None, env: dict[str, str]) -> int:
    """``--domain``, else ``$ROS_DOMAIN_ID`` (checked), else 0."""
    if arg is not None:
        return arg
    text = env.get("ROS_DOMAIN_ID", "").strip()
    if not text:
        return DEFAULT_DOMAIN
    try:
        return _domain(text)
    except argparse.ArgumentTypeError as e:
        raise UsageError(f"$ROS_DOMAIN_ID {e}; set it right or give --domain") from None


def _open_ros(args: argparse.Namespace, tp: ZenohTransport) -> tuple[Any, ZenohTransport | None]:
    """The Zenoh session of the ROS side: the mission's, or one to ``--ros-connect``."""
    if not args.ros_connect:
        return tp.session, None
    from agent.net.router import client_config
    from agent.net.session import open_session

    own = open_session(client_config(args.ros_connect), None, f"ros2-{os.getpid()}",
                       args.connect_wait, option="--ros-connect")
    return own.session, own


def _bag(make: Callable[[Path], Any], path: str) -> Any:
    """``make(Path(path))``, a :class:`BagError` as a usage error naming ``--bag``."""
    try:
        return make(Path(path))
    except BagError as e:
        raise UsageError(f"--bag {e}") from None


def _from_recording(args: argparse.Namespace, names: Names) -> int:
    """``--from-recording RUN_DIR --bag DIR``: the recording as a bag (no network)."""
    if args.bag is None:
        raise UsageError("--from-recording writes a bag: add --bag DIR")
    run_dir = Path(args.from_recording)
    if not run_dir.is_dir():
        raise UsageError(f"--from-recording {run_dir}: no such folder")
    _bag(BagWriter.check, args.bag)
    sc = kit.scenario_arg(args.scenario)
    try:
        rec = read_run(run_dir, sc)
    except ConvertError as e:
        raise UsageError(f"--from-recording {e}") from None
    bag = _bag(BagWriter, args.bag)
    try:
        n = convert(rec, sc, names, bag)
    finally:
        bag.close()
    print(f"viscover-ros2-bridge: bag {args.bag} ({n} messages, {len(bag.counts)} topics) "
          f"from {run_dir}", flush=True)
    return 0


def cmd_ros2_bridge(args: argparse.Namespace) -> int:
    """``viscover ros2-bridge --scenario S.toml``."""
    kit.setup_logging(args.log_level, "ros2-bridge")
    try:
        names = Names(check_namespace(args.namespace))
    except ValueError as e:
        raise UsageError(f"--namespace: {e}") from None
    if args.no_publish and args.bag is None:
        raise UsageError("--no-publish without --bag would do nothing: add --bag DIR")
    if args.from_recording is not None:
        return _from_recording(args, names)
    domain = domain_of(args.domain, dict(os.environ))
    sc = kit.scenario_arg(args.scenario)
    mission = kit.mission_name(args.mission, sc)
    bag: BagWriter | None = None
    if args.bag is not None:
        _bag(BagWriter.check, args.bag)  # before waiting for the router: a mistake at once
    stop = threading.Event()
    got: list[int] = []
    tp = ros_tp = node = bridge = None
    code = EXIT_OK
    with stop_on_signals(stop, got):
        try:
            tp = kit.open_session(args, f"ros2-bridge-{os.getpid()}", stop=stop)
            if args.bag is not None:
                bag = _bag(BagWriter, args.bag)
            if not args.no_publish:
                session, ros_tp = _open_ros(args, tp)
                node = RosNode(session, domain, args.distro, names.ns)
            try:
                bridge = Bridge(tp, sc, mission, node=node, bag=bag, names=names,
                                scene_hz=args.scene_hz)
            except ValueError as e:  # two drone ids, one ROS name
                raise UsageError(f"{args.scenario}: {e}; rename one of them") from None
            what = [rmw_summary(node)] if node is not None else []
            what += [f"bag {args.bag}"] if bag is not None else []
            print(f"viscover-ros2-bridge ready: mission {mission} -> {len(bridge.model.topics())} "
                  f"topics under {names.ns}; {'; '.join(what)} (Ctrl-C to stop)", flush=True)
            deadline = None if args.duration is None else time.monotonic() + args.duration
            while not stop.wait(0.1):
                if deadline is not None and time.monotonic() >= deadline:
                    break
                if (ended := _mesh_gone(bridge)) is not None:
                    code = ended
                    break
        finally:
            if bridge is not None:
                bridge.close()
                s = bridge.summary()
                print(f"viscover-ros2-bridge: {sum(s['sent'].values())} messages sent "
                      f"({len(s['sent'])} topics), {s['rejected']} payloads rejected, "
                      f"{s['errors']} send errors", file=sys.stderr, flush=True)
            if node is not None:
                node.close()
            if bag is not None:
                bag.close()
                print(f"viscover-ros2-bridge: bag {args.bag} ({sum(bag.counts.values())} "
                      "messages)", file=sys.stderr, flush=True)
            for t in (ros_tp, tp):
                if t is not None:
                    t.close()
    if got:
        return EXIT_INTERRUPTED if got[0] == 2 else 0
    return code


def _mesh_gone(bridge: Bridge) -> int | None:
    """None while the mission's mesh is there (or gone for less than :data:`MESH_GONE_S`);
    else the exit status (0: the mission had completed, 1: not), said once on stderr."""
    gone, _line = bridge.watch.mesh_health()
    if gone is None or gone < MESH_GONE_S:
        return None
    complete = bridge.watch.observer.snapshot().complete
    print(f"viscover-ros2-bridge: mesh gone: no router/peers heard for {MESH_GONE_S:g} s; "
          "stopping" + ("" if complete else " (the mission had not completed)"),
          file=sys.stderr, flush=True)
    return EXIT_OK if complete else EXIT_FAILURE
