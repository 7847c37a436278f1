"""The ``viscover`` command: one entry point for every process of a mission.

Subcommands are registered in :data:`COMMANDS`; each registers its parser and sets ``func``
(a ``Namespace -> int`` handler) as a default, and :func:`agent.commands.kit.run_handler`
runs it. This is the only module of :mod:`agent` that may import :mod:`groundstation` (to
register ``viscover groundstation``); everything else depends one way, see
:mod:`agent`.

Exit statuses (:mod:`agent.errors`): 0 ok; 1 the mission went wrong; 2 a user mistake (one
line on stderr, never a traceback); 3 not complete in time; 130 interrupted; 141 the output's
reader went away, for a command whose output is its product (the others carry on without it:
:data:`KEEP_RUNNING`, :mod:`agent.commands.console`). ``viscover --version``: the installed
package's version; every command takes ``--log-level`` (added here to those that do not add
it themselves) and logs in one format from the start.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Callable, Sequence
from importlib import metadata
from typing import Any, NoReturn, cast

from agent.commands import console, kit
from agent.commands.extras import missing_extra, needs_line, register_unavailable
from agent.errors import EXIT_USAGE

#: Every subcommand: name → (module, its function adding the parser). A command's module is
#: imported only when that command runs (or for ``--help``), so that ``viscover router``
#: starts in a fraction of a second.
COMMANDS: dict[str, tuple[str, str]] = {
    "simulate": ("agent.commands.simulate", "register_simulate"),
    "scenario": ("agent.commands.simulate", "register_scenario"),
    "prepare": ("agent.commands.prepare", "register"),
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
    "import-plan": ("agent.commands.import_plan", "register"),
    "export-images": ("agent.commands.images", "register"),
    "status": ("agent.commands.status", "register"),
    "ros2-bridge": ("groundstation.ros2.cli", "register"),
}


#: Commands whose output is a view of work that must go on when its reader goes away (they
#: fly, run a mission, or write files): their output is dropped and they carry on; every other
#: command ends quietly with status 141 (:mod:`agent.commands.console`).
KEEP_RUNNING = frozenset({"launch", "agent", "fly", "groundstation", "router", "record",
                          "observe", "land", "stop", "ros2-bridge", "simulate", "report",
                          "export-plan", "export-images"})

_REQUIRED = "the following arguments are required: "


class Parser(argparse.ArgumentParser):
    """argparse without abbreviated options, for every command: a shortened option that
    happens to prefix another must not silently mean it (``launch --out DIR`` was taken for
    ``--outdoor DIR``). A required option missing is argparse's error, or the option's own
    line when it has one (:func:`agent.commands.kit.required_option`)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        kwargs.setdefault("allow_abbrev", False)
        super().__init__(*args, **kwargs)

    def error(self, message: str) -> NoReturn:
        if message.startswith(_REQUIRED):
            missing = message[len(_REQUIRED):].split(", ")
            for action in self._actions:
                said = kit.missing_line(action)
                if said is not None and any(o in missing for o in action.option_strings):
                    self.exit(EXIT_USAGE, f"viscover: error: {said}\n")
        super().error(message)


def version() -> str:
    """``viscover VERSION``, from the installed package's metadata."""
    try:
        return f"viscover {metadata.version('viscover')}"
    except metadata.PackageNotFoundError:
        return "viscover (version unknown: the package is not installed; pip install -e .)"


def _leaves(parser: argparse.ArgumentParser) -> list[argparse.ArgumentParser]:
    """The parsers of ``parser``'s commands that run something (``scenario check``, not
    ``scenario``)."""
    subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    if not subs:
        return [parser]
    return [leaf for s in subs for p in dict.fromkeys(s.choices.values()) for leaf in _leaves(p)]


def build_parser(only: Sequence[str] | None = None) -> argparse.ArgumentParser:
    """The top-level parser with the subcommands ``only`` (default: every one)."""
    parser = Parser(
        prog="viscover",
        description="Multi-drone visual coverage (vision-based planning and landmark trading).",
    )
    parser.add_argument("--version", action="version", version=version(),
                        help="print the installed version and exit")
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
    for leaf in _leaves(parser):
        if "--log-level" not in leaf._option_string_actions:  # every command logs alike
            kit.add_log_level(leaf)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run the CLI; returns the exit status."""
    args_in = sys.argv[1:] if argv is None else argv
    first = args_in[0] if args_in else None
    policy: console.Policy = "keep" if first in KEEP_RUNNING else "end"
    with console.guarded(policy):
        try:
            return _main(args_in, first)
        except BrokenPipeError:  # its output's reader went away (| head): end quietly
            if not kit.console_gone():
                raise
            return console.EXIT_BROKEN_PIPE


def _main(args_in: list[str], first: str | None) -> int:
    if first in COMMANDS:  # its optional extra missing: one line, before any parsing
        try:
            importlib.import_module(COMMANDS[first][0])
        except ModuleNotFoundError as e:
            if (what := missing_extra(e)) is None:
                raise
            return kit.fail(needs_line(first, *what))
    only = [first] if first in COMMANDS else [] if first == "--version" else None
    parser = build_parser(only)
    try:
        args = parser.parse_args(args_in)  # prints usage + one error line on bad arguments
    except SystemExit as e:  # --help (0) or bad arguments (2): return instead of exiting
        if kit.console_gone():  # --help into a closed pipe (argparse ignores the error)
            return console.EXIT_BROKEN_PIPE
        return e.code if isinstance(e.code, int) else EXIT_USAGE
    kit.setup_logging(args.log_level, args.command)  # a command may set it again, with its tag
    try:
        return kit.run_handler(args.func, args)
    except ModuleNotFoundError as e:  # a lazy import of an optional extra, not installed
        if (what := missing_extra(e)) is None:
            raise
        return kit.fail(needs_line(args.command, *what))


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
