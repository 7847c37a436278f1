"""``viscover status``: the live state of a mission from any machine of the mesh
(:class:`agent.mission.watch.MissionWatch`), a table refreshed in place on a terminal (rich),
plain text otherwise."""

from __future__ import annotations

import argparse
import os
import sys
import threading
import time

from agent.commands import kit
from agent.errors import EXIT_FAILURE, EXIT_OK
from agent.mission.status import render_plain, render_rich
from agent.mission.watch import MissionView, MissionWatch
from agent.runners.process import stop_on_signals


def register(sub: kit.Subparsers) -> None:
    """Add ``status``."""
    p = sub.add_parser(
        "status", help="show a running mission: per drone and overall",
        description="Per drone: phase, landmarks owned, vision, trades, link and mocap health, "
        "battery, last fault; overall: coverage, landmarks seen / not seen by their owner, elapsed "
        "time, violations; a last line when the mesh is gone (no router/peers heard) or "
        "quiet. Refreshed every --period seconds until Ctrl-C (a table on a terminal, plain "
        "text otherwise); --once prints it once. Exit 1 on a violation or, with --once, when "
        "the mesh is gone.")
    p.add_argument("--scenario", required=True, metavar="FILE.toml",
                   help="the mission's scenario file (the same on every machine)")
    kit.add_network_arguments(p)
    p.add_argument("--once", action="store_true", help="print the status once and exit")
    p.add_argument("--wait", type=kit.non_negative, default=2.0, metavar="S",
                   help="listen up to S seconds before the first print, less once every "
                   "drone was heard (default 2)")
    p.add_argument("--period", type=kit.positive, default=1.0, metavar="S",
                   help="refresh every S seconds (default 1)")
    p.add_argument("--plain", action="store_true", help="plain text even on a terminal")
    kit.add_log_level(p)
    p.set_defaults(func=cmd_status)


def _rich_available() -> bool:
    """Whether :mod:`rich` can be imported."""
    try:
        import rich  # noqa: F401
    except ImportError:
        return False
    return True


def _listen(watch: MissionWatch, stop: threading.Event, wait_s: float) -> None:
    """Wait until every drone of the mission was heard, ``wait_s`` [s] at most, or a stop."""
    deadline = time.monotonic() + wait_s
    while not stop.wait(min(0.1, max(0.0, deadline - time.monotonic()))):
        if time.monotonic() >= deadline or all(r.phase != "-" for r in watch.view().rows):
            return


def cmd_status(args: argparse.Namespace) -> int:
    """``viscover status --scenario S.toml``."""
    kit.setup_logging(args.log_level, "status")
    sc = kit.scenario_arg(args.scenario)
    mission = kit.mission_name(args.mission, sc)
    fancy = sys.stdout.isatty() and not args.plain and _rich_available()
    stop = threading.Event()
    got: list[int] = []  # SIGINT / SIGTERM received
    with stop_on_signals(stop, got):
        tp = watch = None
        view: MissionView | None = None
        try:
            tp = kit.open_session(args, f"status-{os.getpid()}", stop=stop)
            watch = MissionWatch(tp, mission, sc, tls_dir=getattr(args, "tls_dir", None))
            _listen(watch, stop, args.wait)
            if fancy:
                from rich.console import Console
                from rich.live import Live

                console = Console()
                view = watch.view()
                if args.once:
                    console.print(render_rich(view))
                else:
                    with Live(render_rich(view), console=console, auto_refresh=False) as live:
                        while not stop.wait(args.period):
                            view = watch.view()
                            live.update(render_rich(view), refresh=True)
            else:
                while True:
                    view = watch.view()
                    print(time.strftime("%H:%M:%S ") + render_plain(view), flush=True)
                    if args.once or stop.wait(args.period):
                        break
                    print(flush=True)
        finally:
            if watch is not None:
                watch.close()
            if tp is not None:
                tp.close()
    if got:
        return 128 + got[0]
    gone = view is not None and view.mesh_gone_s is not None
    return EXIT_FAILURE if view is not None and (view.violations or gone) else EXIT_OK
