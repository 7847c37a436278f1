"""``viscover observe``: watch a mission (:class:`agent.mission.observer.Observer`): ownership
invariants, coverage, completion."""

from __future__ import annotations

import argparse
import json
import os
import threading
import time
from pathlib import Path

from agent.commands import kit
from agent.errors import EXIT_FAILURE, EXIT_INCOMPLETE, UsageError
from agent.mission.observer import Observer, fence_keys, print_report
from agent.net.security import OBSERVER
from agent.runners.process import stop_on_signals


def register(sub: kit.Subparsers) -> None:
    """Add ``observe``."""
    o = sub.add_parser("observe", help="watch a mission and check its invariants",
                       description="Subscribe to every agent's state; report invariant "
                       "violations (exit 1), coverage and completion.")
    o.add_argument("--scenario", required=True, metavar="FILE.toml",
                   help="the mission's scenario file (the same on every machine)")
    kit.add_network_arguments(o)
    o.add_argument("--until-complete", action="store_true",
                   help="exit when the mission ends (exit 3 on --timeout, or when an "
                   "inspection ended with landmarks given up)")
    o.add_argument("--timeout", type=kit.positive, default=None, metavar="S",
                   help="stop after S seconds")
    o.add_argument("--json-out", metavar="PATH", help="write the report as JSON")
    kit.add_log_level(o)
    o.set_defaults(func=cmd_observe)


def cmd_observe(args: argparse.Namespace) -> int:
    """``viscover observe --scenario S.toml ...``."""
    kit.setup_logging(args.log_level, "observer")
    sc = kit.scenario_arg(args.scenario)
    mission = kit.mission_name(args.mission, sc)
    if args.json_out:
        parent = Path(args.json_out).parent
        if not parent.is_dir():
            raise UsageError(f"--json-out {args.json_out}: directory {parent} does not exist")
    stop = threading.Event()
    with stop_on_signals(stop):
        tp = kit.open_session(args, f"observer-{os.getpid()}", OBSERVER, stop)
        obs = None
        try:
            obs = Observer(tp, mission, [a.id for a in sc.agents], list(sc.landmark_ids),
                           initial=sc.initial_sets(),
                           fence_keys=fence_keys(getattr(args, "tls_dir", None)))
            deadline = None if args.timeout is None else time.monotonic() + args.timeout
            while not stop.is_set():
                if args.until_complete and obs.done.is_set():
                    break
                if deadline is not None and time.monotonic() >= deadline:
                    break
                stop.wait(0.05)
            rep = obs.snapshot()
            print_report(rep)
            if args.json_out:
                Path(args.json_out).write_text(json.dumps(rep.to_json(), indent=1))
            if rep.violations:
                return EXIT_FAILURE
            if args.until_complete and not rep.complete:
                return EXIT_INCOMPLETE
            return 0
        finally:
            if obs is not None:
                obs.close()
            tp.close()
