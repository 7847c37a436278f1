"""``viscover export-plan RUN_DIR --origin LAT,LON,ALT``: an inspection run's captures as one
QGroundControl ``.plan`` per drone (:mod:`agent.flight.refly`, :mod:`agent.flight.qgc_plan`),
to fly the inspection again in the autopilot's own mission mode (AUTO) and compare."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from agent.commands import kit
from agent.errors import UsageError
from agent.flight.flavours import flavour_names
from agent.flight.geodetic import Origin
from agent.flight.qgc_plan import plan_document
from agent.flight.refly import fences, plan_routes
from agent.storage.recording import EVENTS_NAME, MCAP_NAME

#: The files of a run folder's recording (either one is enough to report it).
RECORDING_FILES = (MCAP_NAME, EVENTS_NAME)


#: The line of an ``export-plan`` without ``--origin``.
NO_ORIGIN = ("--origin LAT,LON,ALT is required: the scenario carries no geodetic origin "
             "(latitude, longitude [degrees] and altitude [m] of its (0, 0, 0))")


def add_run_arguments(p: argparse.ArgumentParser, origin_use: str, *,
                      origin_missing: str | None = None) -> None:
    """RUN_DIR and ``--origin`` of the commands that read an inspection run's result.json
    (``origin_use``: what the origin is needed for, appended to its help; ``origin_missing``:
    ``--origin`` is required, and this line says so when it is missing)."""
    p.add_argument("run_dir", metavar="RUN_DIR",
                   help="a viscover simulate output folder, or a run folder of viscover launch "
                   "or record (its report/, else its recording)")
    what: dict[str, Any] = {
        "metavar": "LAT,LON,ALT", "type": origin,
        "help": "geodetic position of the world frame's origin (ENU): latitude and longitude "
                "[degrees], altitude [m AMSL] of the ground there" + origin_use}
    if origin_missing is not None:
        kit.required_option(p, "--origin", missing=origin_missing, **what)
    else:
        p.add_argument("--origin", **what)


def register(sub: kit.Subparsers) -> None:
    """Add ``export-plan``."""
    p = sub.add_parser(
        "export-plan", help="write one QGroundControl .plan per drone to fly an inspection "
        "run's captures again",
        description="Read RUN_DIR/result.json (or RUN_DIR/report/result.json) of an inspection "
        "mission and write, per drone, a QGroundControl .plan: take-off, at each capture a "
        "gimbal item, a waypoint at the camera position facing the camera's heading and an "
        "image capture, then land at the launch point; the fence is the mission space's "
        "rectangle (inclusion) and the structure's footprint (exclusion) when no route crosses "
        "it. Altitudes are relative to home: arm each drone on the ground below its start "
        "pose, at the origin's level.")
    add_run_arguments(p, "", origin_missing=NO_ORIGIN)
    p.add_argument("--out", metavar="DIR", help="where to write <agent>.plan (default "
                   "RUN_DIR/plans)")
    p.add_argument("--autopilot", choices=flavour_names(), default="px4",
                   help="the plan's firmware type (default px4)")
    p.add_argument("--hold", type=kit.non_negative, default=1.0, metavar="S",
                   help="least hold time at each viewpoint before its image [s] (default 1)")
    p.add_argument("--gimbal-rate", type=kit.positive, default=60.0, metavar="DEG_PER_S",
                   help="how fast the gimbal turns [degrees/s] (default 60, the simulated "
                   "one's): a viewpoint's hold is long enough for the turn from the previous "
                   "one's pitch and yaw (from level, any yaw, before the first)")
    p.add_argument("--fence-margin", type=kit.non_negative, default=1.0, metavar="M",
                   help="how far inside the mission space the inclusion fence lies [m] "
                   "(default 1)")
    p.set_defaults(func=cmd_export_plan)


def origin(text: str) -> Origin:
    """``LAT,LON,ALT``: degrees, degrees, metres."""
    parts = text.split(",")
    try:
        if len(parts) != 3:
            raise ValueError("expected three numbers")
        lat, lon, alt = (kit.number(s.strip()) for s in parts)
        return Origin(lat, lon, alt)
    except (ValueError, argparse.ArgumentTypeError) as e:
        raise argparse.ArgumentTypeError(
            f"{text!r}: {e}; write LAT,LON,ALT, e.g. 47.3977,8.5456,488") from None


def find_result(run: Path) -> Path:
    """RUN_DIR/result.json, else RUN_DIR/report/result.json; else, in a run folder with a
    recording (``viscover launch`` / ``record``), RUN_DIR/report/result.json built from it
    now (as ``viscover report --no-plots`` builds it), said on stderr."""
    for path in (run / "result.json", run / "report" / "result.json"):
        if path.is_file():
            return path
    if not run.is_dir():
        raise UsageError(f"{run}: no such folder")
    if not any((run / name).is_file() for name in RECORDING_FILES):
        raise UsageError(f"{run}: no result.json here or in report/, and no recording to "
                         "build one from (run viscover simulate, or record the mission)")
    from agent.commands.report import write_result_json

    path = write_result_json(run, run / "report")
    print(f"viscover: {path}: built from the run's recording (viscover report {run} adds the "
          "plots and report.html)", file=sys.stderr)
    return path


def read_result(path: Path) -> dict[str, Any]:
    """``result.json`` as a dict (UsageError if unreadable)."""
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise UsageError(f"{path}: cannot read it as JSON: {e}") from None
    if not isinstance(doc, dict):
        raise UsageError(f"{path}: not a viscover result (expected a JSON object)")
    return doc


def cmd_export_plan(args: argparse.Namespace) -> int:
    """``viscover export-plan RUN_DIR``."""
    run = Path(args.run_dir)
    path = find_result(run)
    doc = read_result(path)
    where: Origin | None = args.origin
    if where is None:  # argparse requires it; a caller of this function may not have
        raise UsageError(NO_ORIGIN)
    try:
        routes = plan_routes(doc)
        fence = fences(doc, routes, margin=args.fence_margin)
    except ValueError as e:
        raise UsageError(f"{path}: {e}") from None
    # The camera's shortest interval between two images (the run's [camera], if any).
    numbers = (doc.get("inspection") or {}).get("numbers") or {}
    trigger = float(numbers.get("trigger_s", 0.0))
    out = Path(args.out) if args.out else run / "plans"
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise UsageError(f"--out {out}: cannot create directory: {e.strerror or e}") from None
    for route in routes:
        if not route.agent or "/" in route.agent or route.agent.startswith("."):
            raise UsageError(f"{path}: agent id {route.agent!r} cannot name a file")
        plan = plan_document(route, fence, where, autopilot=args.autopilot, hold=args.hold,
                             gimbal_rate=args.gimbal_rate, trigger_s=trigger)
        target = out / f"{route.agent}.plan"
        target.write_text(json.dumps(plan, indent=2, allow_nan=False) + "\n", encoding="utf-8")
        n = len(route.viewpoints)
        print(f"{target}: {n} viewpoint{'s' * (n != 1)}, {len(plan['mission']['items'])} items")
    for line in (*fence.notes, *(w for r in routes for w in r.warnings)):
        print(f"viscover: warning: {line}", file=sys.stderr)
    return 0
