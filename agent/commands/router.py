"""``viscover router``: a Zenoh router run from Python (``zenohd`` is not needed)."""

from __future__ import annotations

import argparse
import os
import re
from pathlib import Path

from agent.commands import kit
from agent.errors import EXIT_INTERRUPTED, UsageError
from agent.net.router import run_router


def register(sub: kit.Subparsers) -> None:
    """Add ``router``."""
    r = sub.add_parser("router", help="run a Zenoh router",
                       description="Run a Zenoh router (Ctrl-C to stop).")
    r.add_argument("--config", required=True, metavar="FILE",
                   help="router config (json5), e.g. broker_config/router.json5")
    r.add_argument("--listen", metavar="ENDPOINT", type=kit.endpoint, action="append",
                   default=[], help="listen here instead of the config's endpoints, e.g. "
                   "tcp/0.0.0.0:7448 (repeatable)")
    r.add_argument("--state-dir", type=Path, default=None, metavar="DIR",
                   help="keep the team's fence record here across restarts of the router "
                   "(made if missing; default: in memory only)")
    kit.add_log_level(r)
    r.set_defaults(func=cmd_router, log_level="INFO")


def cmd_router(args: argparse.Namespace) -> int:
    """``viscover router --config FILE``."""
    if not Path(args.config).is_file():
        raise UsageError(f"--config {args.config}: no such file")
    if args.state_dir is not None:
        try:
            args.state_dir.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            raise UsageError(f"--state-dir {args.state_dir}: {e.strerror}") from None
        if not os.access(args.state_dir, os.W_OK):
            raise UsageError(f"--state-dir {args.state_dir}: not writable by this user")
    kit.setup_logging(args.log_level, "router")
    try:
        run_router(args.config, listen=args.listen or None, state_dir=args.state_dir)
    except KeyboardInterrupt:
        return EXIT_INTERRUPTED
    except Exception as e:
        raise UsageError(router_error(str(e))) from None
    return 0


def router_error(text: str) -> str:
    """One line for a router that could not start: a port already in use is named with its
    fix; anything else is Zenoh's message without its source locations."""
    m = re.search(r"bound to (\S+?):? \[.*Address already in use", text)
    if m:
        return (f"router: {m.group(1)} is already in use (another router?): stop it, or "
                "listen elsewhere with --listen tcp/0.0.0.0:PORT")
    return "router: " + re.sub(r" at /\S+\.rs:\d+\.?", "", text).strip()
