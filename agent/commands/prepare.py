"""``viscover prepare SCENARIO [-o FILE]``: an inspection's capture table and route grid built
once into a file the whole team loads (:mod:`agent.world.prepared`), bound to the scenario's
digest and settings. Progress on stderr, one summary line on stdout; a user mistake (a bad
scenario, not an inspection, an unwritable path) is one line and exit 2."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from agent.commands import kit
from agent.errors import UsageError


def register(sub: kit.Subparsers) -> None:
    """Add ``prepare``."""
    p = sub.add_parser(
        "prepare", help="build an inspection's capture table once, into a file for the team",
        description="Read SCENARIO (its mesh sampled as a run does), build its capture table "
        "(candidate viewpoints and what each captures) and route grid, and write them to "
        "FILE (default SCENARIO's name with .prepared.npz, in the current folder), bound to "
        "the scenario's digest and settings. Agents load it when the environment variable "
        "VISCOVER_PREPARED names it (viscover launch prepares once and does so); a file of "
        "another scenario or settings is refused. Progress on stderr.")
    p.add_argument("scenario", metavar="SCENARIO.toml", help="an inspection scenario file")
    p.add_argument("-o", "--out", metavar="FILE", default=None,
                   help="the prepared file to write (default ./NAME.prepared.npz)")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    p.set_defaults(func=cmd_prepare)


def _out_path(args: argparse.Namespace) -> Path:
    """The file to write, checked writable before any work: a usage error otherwise."""
    out = Path(args.out) if args.out else Path(f"{Path(args.scenario).stem}.prepared.npz")
    if out.is_dir():
        raise UsageError(f"-o {out}: is a directory; name the file to write, e.g. "
                         f"{out / (Path(args.scenario).stem + '.prepared.npz')}")
    if not out.parent.is_dir():
        raise UsageError(f"-o {out}: no such folder {str(out.parent)!r}; create it or choose "
                         "another path")
    return out


def cmd_prepare(args: argparse.Namespace) -> int:
    """Build and write the prepared file; print what it holds."""
    from agent.world.prepared import save_prepared
    from agent.world.tables import mission_tables

    out = _out_path(args)
    sc = kit.scenario_arg(args.scenario)
    if sc.inspection is None:
        raise UsageError(f"{args.scenario}: not an inspection mission (no [inspection] "
                         "table): only an inspection has a capture table to prepare")
    start = time.perf_counter()

    def say(line: str) -> None:
        print(f"prepare: {line} ({time.perf_counter() - start:.1f} s)", file=sys.stderr,
              flush=True)

    tables = mission_tables(sc, None if args.quiet else say)
    save_prepared(out, sc, tables)
    table = tables[0]
    print(f"prepared {out}: {sc.name}, {len(sc.landmark_ids):,} landmarks "
          f"({int(table.capturable.sum()):,} capturable), {table.P.shape[0]:,} viewpoints, "
          f"{table.rows.nnz:,} captures, {out.stat().st_size / 2**20:.1f} MiB, in "
          f"{time.perf_counter() - start:.1f} s")
    return 0
