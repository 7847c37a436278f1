"""``viscover record``: record a mission from any machine of the mesh into a folder
(``events.jsonl`` and ``recording.mcap``, :mod:`agent.mission.recorder`)."""

from __future__ import annotations

import argparse
import os
import sys
import threading
import time

from agent.commands import kit
from agent.errors import EXIT_INCOMPLETE, UsageError
from agent.mission.recorder import Recorder
from agent.runners.process import stop_on_signals


def register(sub: kit.Subparsers) -> None:
    """Add ``record``."""
    p = sub.add_parser(
        "record", help="record a mission: events.jsonl and an MCAP file for Foxglove",
        description="Subscribe to a mission and write OUT/events.jsonl (phases, trades, faults, "
        "failsafes, commands) and OUT/recording.mcap (poses, camera frusta, landmarks coloured "
        "by owner, mocap, coverage; opens in Foxglove) until Ctrl-C / SIGTERM (the file is "
        "finalised), --until-complete or --timeout. Then: viscover report OUT.")
    p.add_argument("--scenario", required=True, metavar="FILE.toml",
                   help="the mission's scenario file (the same on every machine)")
    p.add_argument("--out", required=True, metavar="DIR", help="folder to record into (created)")
    kit.add_network_arguments(p)
    p.add_argument("--live", type=int, default=None, metavar="PORT",
                   help="also serve the mission live to Foxglove (WebSocket on PORT, 0: any "
                   "free port; Foxglove: Open connection, ws://HOST:PORT)")
    p.add_argument("--live-host", default="127.0.0.1", metavar="HOST",
                   help="address the live server listens on (default 127.0.0.1)")
    p.add_argument("--until-complete", action="store_true",
                   help="stop once the mission is complete and every agent has left it")
    p.add_argument("--timeout", type=kit.positive, default=None, metavar="S",
                   help="stop after S seconds (exit 3 with --until-complete if not complete)")
    kit.add_log_level(p)
    p.set_defaults(func=cmd_record)


def cmd_record(args: argparse.Namespace) -> int:
    """``viscover record --scenario S.toml --out DIR``."""
    kit.setup_logging(args.log_level, "recorder")
    sc = kit.scenario_arg(args.scenario)
    mission = kit.mission_name(args.mission, sc)
    out = kit.output_dir(args.out)
    stop = threading.Event()
    got: list[int] = []  # SIGINT / SIGTERM received
    with stop_on_signals(stop, got):
        rec = tp = None
        complete = False
        try:
            tp = kit.open_session(args, f"recorder-{os.getpid()}", stop=stop)
            try:
                rec = Recorder(tp, sc, mission, out, live=args.live, live_host=args.live_host)
            except RuntimeError as e:  # the live server's port is taken or not allowed
                raise UsageError(f"--live {args.live}: cannot serve on {args.live_host}: {e}") \
                    from None
            live = "" if rec.server is None else \
                f", live on ws://{args.live_host}:{rec.server.port}"
            print(f"viscover-record ready: mission {mission} into {rec.path}{live} (Ctrl-C to "
                  "stop)", flush=True)
            deadline = None if args.timeout is None else time.monotonic() + args.timeout
            while not stop.wait(0.1):
                if deadline is not None and time.monotonic() >= deadline:
                    break
                if args.until_complete and rec.watch.observer.done.is_set() and all(
                        d.live is False for d in rec.watch.drones.values()):
                    break
            complete = rec.watch.observer.done.is_set()
        finally:
            if rec is not None:
                rec.close()
                n = sum(rec.counts.values())
                print(f"viscover-record: {n} messages in {rec.path} "
                      f"({rec.path.stat().st_size / 1e3:.0f} kB), events in {rec.events_path}",
                      file=sys.stderr, flush=True)
            if tp is not None:
                tp.close()
    if got:
        return 128 + got[0]
    return EXIT_INCOMPLETE if args.until_complete and not complete else 0
