"""``viscover report RUN_DIR``: the report of a recorded mission (:mod:`agent.sim.replay`),
the same as ``viscover simulate`` writes (``result.json``, plots) plus ``report.html``.

A recording without agent states (a flight interrupted early) is reported from what it holds
(poses or motion capture, events), saying what is missing; exit 0. One without anything of the
drones, or unreadable: one line, exit 2."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from agent.commands import kit
from agent.commands.simulate import summarize
from agent.errors import UsageError
from agent.sim.inspection_report import read_captures
from agent.sim.replay import RecordingError, read_recording, to_result
from agent.sim.report import write_report
from agent.sim.run_inspection import inspection_summary, run_scenario
from agent.sim.webpage import page

_CAPTIONS = {"trajectories.png": "Trajectories (o start, * end)",
             "coverage.png": "Coverage score and each agent's vision over time, trades marked",
             "partition.png": "Final partition: landmarks coloured by owner",
             "captures.png": "Captures: landmarks coloured by capture quality, the "
                             "uncaptured ones marked"}


def register(sub: kit.Subparsers) -> None:
    """Add ``report``."""
    p = sub.add_parser(
        "report", help="build the report of a recorded mission (plots, result.json, HTML)",
        description="Read RUN_DIR's recording (recording.mcap, events.jsonl: written by "
        "viscover launch or viscover record) and write the report viscover simulate writes "
        "(result.json, trajectories.png, coverage.png, partition.png) plus report.html, a "
        "page with the figures and the mission's events, into --out (default RUN_DIR/report).")
    p.add_argument("run_dir", metavar="RUN_DIR", help="a run folder with a recording")
    p.add_argument("--out", metavar="DIR", help="report directory (default RUN_DIR/report)")
    p.add_argument("--no-plots", action="store_true", help="result.json only")
    p.set_defaults(func=cmd_report)


def cmd_report(args: argparse.Namespace) -> int:
    """``viscover report RUN_DIR``."""
    run = Path(args.run_dir)
    if not run.is_dir():
        raise UsageError(f"{run}: no such run folder")
    try:
        rec = read_recording(run)
    except RecordingError as e:
        raise UsageError(str(e)) from None
    if rec.empty:
        raise UsageError(f"{run}: the recording holds no agent state, pose or motion capture "
                         "(was the mission running on this mission name?)")
    out = Path(args.out) if args.out else run / "report"
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise UsageError(f"--out {out}: cannot create directory: {e.strerror or e}") from None
    result = to_result(rec)
    result.captures = read_captures(run / "captures.jsonl")  # an inspection's, if any
    if (run / "captures.jsonl").is_file():  # an inspection run: its summary and plot
        sc, why = run_scenario(run, rec.info)
        if sc is not None:
            result.inspection = inspection_summary(sc, result.captures)
        elif why:
            print(why)
    paths = write_report(result, out, plots=not args.no_plots, missing=rec.missing)
    figures = [(p, _CAPTIONS[p.name]) for p in paths if p.name in _CAPTIONS]
    doc = json.loads((out / "result.json").read_text(encoding="utf-8"))
    source = f"recorded, {'finalised' if rec.complete_file else 'cut short'}"
    html_path = out / "report.html"
    html_path.write_text(page(doc, figures, rec.events, rec.counts, source), encoding="utf-8")
    paths.append(html_path)
    print(f"report written to {out}/ ({', '.join(p.name for p in paths)})")
    print(summarize(result) if rec.missing is None else f"{rec.missing}; "
          f"{float(result.times[-1]):.1f} s recorded, {len(rec.events)} event(s)")
    return 0
