"""The ``viscover`` command: one entry point for every process of a mission.

Subcommands are registered in :data:`COMMANDS`; each registers its parser and sets ``func``
(a ``Namespace -> int`` handler) as a default, and :func:`agent.commands.kit.run_handler`
runs it. This is the only module of :mod:`agent` that may import :mod:`groundstation` (to
register ``viscover groundstation``); everything else depends one way, see
:mod:`agent`.

Exit statuses (:mod:`agent.errors`): 0 ok; 1 the mission went wrong; 2 a user mistake (one
line on stderr, never a traceback); 3 not complete in time; 130 interrupted.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Callable, Sequence
from typing import Any, cast

from agent.commands.extras import missing_extra, needs_line, register_unavailable
from agent.errors import EXIT_USAGE

#: Every subcommand: name → (module, its function adding the parser). A command's module is
#: imported only when that command runs (or for ``--help``), so that ``viscover router``
#: starts in a fraction of a second.
COMMANDS: dict[str, tuple[str, str]] = {
    "simulate": ("agent.commands.simulate", "register_simulate"),
    "scenario": ("agent.commands.simulate", "register_scenario"),
    "router": ("agent.commands.router", "register"),
    "agent": ("agent.commands.agent", "register"),
    "observe": ("agent.commands.observe", "register"),
    "groundstation": ("groundstation.cli", "register"),
    "fly": ("agent.commands.fly", "register"),
    "preflight": ("agent.commands.preflight", "register"),
    "launch": ("agent.commands.launch", "register"),
    "land": ("agent.commands.mission", "register"),
    "stop": ("agent.commands.mission", "register"),
    "record": ("agent.commands.record", "register"),
    "report": ("agent.commands.report", "register"),
    "export-plan": ("agent.commands.export_plan", "register"),
    "export-images": ("agent.commands.images", "register"),
    "status": ("agent.commands.status", "register"),
    "ros2-bridge": ("groundstation.ros2.cli", "register"),
}


class Parser(argparse.ArgumentParser):
    """argparse without abbreviated options, for every command: a shortened option that
    happens to prefix another must not silently mean it (``launch --out DIR`` was taken for
    ``--outdoor DIR``)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        kwargs.setdefault("allow_abbrev", False)
        super().__init__(*args, **kwargs)


def build_parser(only: Sequence[str] | None = None) -> argparse.ArgumentParser:
    """The top-level parser with the subcommands ``only`` (default: every one)."""
    parser = Parser(
        prog="viscover",
        description="Multi-drone visual coverage (vision-based planning and landmark trading).",
    )
    # Every subcommand's parser is a Parser too (argparse makes them of the parent's class).
    sub = cast("argparse._SubParsersAction[argparse.ArgumentParser]",
               parser.add_subparsers(dest="command", metavar="COMMAND", required=True))
    done: set[tuple[str, str]] = set()
    for name in only if only is not None else COMMANDS:
        module, attr = COMMANDS[name]
        if (module, attr) in done:  # one function may register several commands
            continue
        try:
            mod = importlib.import_module(module)
        except ModuleNotFoundError as e:  # an optional extra that is not installed
            if (what := missing_extra(e)) is None:
                raise
            register_unavailable(sub, name, *what)
            continue
        done.add((module, attr))
        add = cast(Callable[[object], None], getattr(mod, attr))
        add(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run the CLI; returns the exit status."""
    from agent.commands import kit

    args_in = sys.argv[1:] if argv is None else argv
    first = args_in[0] if args_in else None
    if first in COMMANDS:  # its optional extra missing: one line, before any parsing
        try:
            importlib.import_module(COMMANDS[first][0])
        except ModuleNotFoundError as e:
            if (what := missing_extra(e)) is None:
                raise
            return kit.fail(needs_line(first, *what))
    parser = build_parser([first] if first in COMMANDS else None)
    try:
        args = parser.parse_args(args_in)  # prints usage + one error line on bad arguments
    except SystemExit as e:  # --help (0) or bad arguments (2): return instead of exiting
        return e.code if isinstance(e.code, int) else EXIT_USAGE
    try:
        return kit.run_handler(args.func, args)
    except ModuleNotFoundError as e:  # a lazy import of an optional extra, not installed
        if (what := missing_extra(e)) is None:
            raise
        return kit.fail(needs_line(args.command, *what))


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
