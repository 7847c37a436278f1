"""``viscover router``: a Zenoh router run from Python (``zenohd`` is not needed)."""

from __future__ import annotations

import argparse
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
    kit.add_log_level(r)
    r.set_defaults(func=cmd_router, log_level="INFO")


def cmd_router(args: argparse.Namespace) -> int:
    """``viscover router --config FILE``."""
    if not Path(args.config).is_file():
        raise UsageError(f"--config {args.config}: no such file")
    kit.setup_logging(args.log_level, "router")
    try:
        run_router(args.config)
    except KeyboardInterrupt:
        return EXIT_INTERRUPTED
    except Exception as e:
        raise UsageError(f"router: {e}") from None
    return 0
