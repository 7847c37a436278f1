"""Optional extras: a command whose packages are not installed says so in one line (exit 2).

A drone's companion computer installs only the core (``pip install viscover``): the agent,
``fly``, ``preflight``, ``router``, ``status``, ``observe``, ``land`` / ``stop``. The other
parts come with extras of ``pyproject.toml`` (:data:`EXTRAS`): ``ground`` (``launch``,
``record``, ``report``, plots, the rich status view), ``mocap`` (real motion capture),
``occlusion-fast`` (Embree ray casting) and ``ros2`` (``ros2-bridge``: rosbags, xxhash). A
command that needs a missing one is still listed by ``viscover --help`` and, when run, prints
``viscover: error: viscover record needs the package foxglove, which is not installed: install
viscover[ground] (pip install 'viscover[ground]')`` and exits 2, never a traceback.
"""

from __future__ import annotations

import argparse

from agent.commands import kit
from agent.errors import UsageError

#: Top-level module of an optional package → the extra that installs it.
EXTRAS: dict[str, str] = {
    "matplotlib": "ground",
    "mpl_toolkits": "ground",
    "foxglove": "ground",
    "mcap": "ground",
    "rich": "ground",
    "motioncapture": "mocap",
    "embreex": "occlusion-fast",
    "rosbags": "ros2",
    "xxhash": "ros2",
}


def missing_extra(error: ImportError) -> tuple[str, str] | None:
    """(package, extra) when ``error`` is the import of an optional package that is not
    installed; None for anything else (a real bug, to be raised)."""
    name = getattr(error, "name", None) or ""
    top = name.split(".")[0]
    extra = EXTRAS.get(top)
    return None if extra is None or not isinstance(error, ModuleNotFoundError) else (top, extra)


def needs_line(command: str, package: str, extra: str) -> str:
    """The one line (without ``viscover: error:``) for a command missing an extra."""
    return (f"viscover {command} needs the package {package}, which is not installed: "
            f"install viscover[{extra}] (pip install 'viscover[{extra}]')")


def register_unavailable(sub: kit.Subparsers, command: str, package: str, extra: str) -> None:
    """Add ``command`` as a stand-in, listed by ``viscover --help``, that refuses in one line
    (:func:`agent.cli.main` refuses a command line naming it before parsing)."""
    line = needs_line(command, package, extra)
    p = sub.add_parser(command, help=f"(needs viscover[{extra}]: not installed)",
                       description=line)

    def refuse(_args: argparse.Namespace) -> int:
        raise UsageError(line)

    p.set_defaults(func=refuse)
