"""``viscover report RUN_DIR``: the report of a recorded mission (:mod:`agent.sim.replay`),
the same as ``viscover simulate`` writes (``result.json``, plots, ``landmarks.csv``,
``report.html``: :mod:`agent.sim.html_report`).

A recording without agent states (a flight interrupted early) is reported from what it holds
(poses or motion capture, events), saying what is missing; exit 0. One without anything of the
drones, or unreadable: one line, exit 2."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from agent.commands import kit
from agent.commands.simulate import summarize
from agent.config.digest import scenario_digest
from agent.config.scenario import Scenario
from agent.errors import UsageError
from agent.sim.html_report import utc, write_html
from agent.sim.inspection_report import read_captures
from agent.sim.replay import Recording, RecordingError, read_recording, to_result
from agent.sim.report import write_report
from agent.sim.result import SimResult
from agent.sim.run_inspection import find_scenario, inspection_summary, observed_given_up
from agent.storage.recording import EVENTS_NAME


def register(sub: kit.Subparsers) -> None:
    """Add ``report``."""
    p = sub.add_parser(
        "report", help="build the report of a recorded mission (plots, result.json, HTML)",
        description="Read RUN_DIR's recording (recording.mcap, events.jsonl: written by "
        "viscover launch or viscover record) and write the report viscover simulate writes "
        "(result.json, trajectories.png, coverage.png, partition.png, structure.png, "
        "landmarks.csv, report.html: date, scenario digest, software version, every "
        "landmark's best quality, distance and incidence, the events by phase) into --out "
        "(default RUN_DIR/report).")
    p.add_argument("run_dir", metavar="RUN_DIR", help="a run folder with a recording")
    p.add_argument("--out", metavar="DIR", help="report directory (default RUN_DIR/report)")
    p.add_argument("--no-plots", action="store_true", help="result.json only")
    p.set_defaults(func=cmd_report)


def recorded_result(run: Path) -> tuple[SimResult, Recording, Scenario | None, str]:
    """The result of run folder ``run``'s recording: (result, recording, its scenario if
    found, why it was not when an inspection's was needed); a UsageError when there is no
    readable recording of the drones."""
    if not run.is_dir():
        raise UsageError(f"{run}: no such run folder")
    try:
        rec = read_recording(run)
    except RecordingError as e:
        raise UsageError(str(e)) from None
    if rec.empty:
        raise UsageError(f"{run}: the recording holds no agent state, pose or motion capture "
                         "(was the mission running on this mission name?)")
    result = to_result(rec)
    result.captures = read_captures(run / "captures.jsonl")  # an inspection's, if any
    sc, why = find_scenario(run, rec.info)  # its mesh, digest and capture table, if found
    if not (run / "captures.jsonl").is_file():  # a coverage run: nothing more to say
        return result, rec, sc, ""
    if sc is not None and sc.inspection is not None:  # an inspection: its summary and plot
        result.inspection = inspection_summary(sc, result.captures, observed_given_up(run, sc))
        if not result.inspection.complete:  # landmarks left: not complete, whatever ended
            result.complete, result.t_complete = False, None
        why = ""
    return result, rec, sc, why


def write_result_json(run: Path, out: Path) -> Path:
    """``out/result.json`` of run folder ``run``'s recording, no plots (what ``export-plan``
    and ``export-images`` read); its path."""
    result, rec, _sc, _why = recorded_result(run)
    _mkdir(out)
    return write_report(result, out, plots=False, missing=rec.missing)[0]


def _mkdir(out: Path) -> None:
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise UsageError(f"--out {out}: cannot create directory: {e.strerror or e}") from None


def cmd_report(args: argparse.Namespace) -> int:
    """``viscover report RUN_DIR``."""
    run = Path(args.run_dir)
    result, rec, sc, why = recorded_result(run)
    out = Path(args.out) if args.out else run / "report"
    _mkdir(out)
    if why:
        print(why)
    plots = not args.no_plots
    paths = write_report(result, out, plots=plots, missing=rec.missing)
    source = f"recorded, {'finalised' if rec.complete_file else 'cut short'}"
    started = rec.info.get("started")
    write_html(result, out, paths, source=source, plots=plots, events=rec.events,
               counts=rec.counts, scenario=sc, missing=rec.missing,
               date=utc(float(started)) if isinstance(started, int | float) else "unknown",
               digest=_digest(run, rec, sc), recorded_by=rec.info.get("software"))
    print(f"report written to {out}/ ({', '.join(p.name for p in paths)})")
    print(summarize(result) if rec.missing is None else f"{rec.missing}; "
          f"{float(result.times[-1]):.1f} s recorded, {len(rec.events)} event(s)")
    if (line := times_line(result)) is not None:
        print(line)
    if rec.events_skipped:
        print(f"{rec.events_skipped} line(s) of {EVENTS_NAME} skipped: not events of this "
              "build (torn, or of another one)")
    return 0


def times_line(result: SimResult) -> str | None:
    """One line naming the report's clock and the drones' own (None: a simulation, one clock):
    every t is mission time τ from the first recorded sample; each drone's clock, which
    ``viscover launch`` and ``status`` show as "mission t", reads τ plus its offset."""
    if result.wall_origin is None or not result.clock_offsets:
        return None
    groups: dict[str, list[str]] = {}
    for a, o in sorted(result.clock_offsets.items()):
        groups.setdefault(f"τ {'+' if o >= 0 else '-'} {abs(o):.1f} s", []).append(a)
    reads = "; ".join(f"{t} ({', '.join(ids)})" for t, ids in groups.items())
    return (f"times: every t here is mission time τ [s], 0 at the first recorded sample; the "
            f"drones' own clocks (the \"mission t\" of viscover launch and status) read {reads}; "
            f"wall time: τ / {result.time_scale:.3g} after {utc(result.wall_origin)}")


def _digest(run: Path, rec: Recording, sc: Scenario | None) -> str:
    """The run's scenario digest: ``launch.json``'s, else the recording's, else the scenario
    file's (when it was found and has the recorded landmarks)."""
    try:
        doc = json.loads((run / "launch.json").read_text(encoding="utf-8"))
        if isinstance(doc, dict) and isinstance(doc.get("scenario_digest"), str):
            return str(doc["scenario_digest"])
    except (OSError, ValueError):
        pass
    if isinstance(rec.info.get("digest"), str):
        return str(rec.info["digest"])
    return scenario_digest(sc) if sc is not None else "unknown (scenario file not found)"
