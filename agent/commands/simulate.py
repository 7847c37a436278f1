"""``viscover simulate`` (the chapter-5 kinematic simulator in one process, with a report) and
``viscover scenario check`` (validate scenario files)."""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING, TextIO

import numpy as np

from agent.commands import kit
from agent.config.digest import scenario_digest
from agent.config.parse import load_scenario
from agent.config.scenario import Scenario, ScenarioError
from agent.errors import EXIT_FAILURE, EXIT_INCOMPLETE, EXIT_USAGE, UsageError
from agent.sim.html_report import utc, write_html
from agent.sim.kinematic import LOCKSTEP_THESIS_ONLY, simulate
from agent.sim.report import write_report
from agent.sim.result import SimResult
from agent.strategy.registry import strategy_of

if TYPE_CHECKING:  # the agents' engine is loaded when it runs
    from agent.testing.rehearsal import MissionFaults, Outcome


class Progress:
    """A percentage line on ``stream``: rewritten in place on a terminal, otherwise one line
    per 10 % so that logs stay short. Called as ``progress(t, duration)`` [s]."""

    def __init__(self, label: str, stream: TextIO | None = None) -> None:
        self.label = label
        self.stream = stream if stream is not None else sys.stderr
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.last = -1
        self.t = 0.0
        self.start = time.monotonic()

    def __call__(self, t: float, duration: float) -> None:
        self.t = t
        pct = int(100.0 * min(max(t / duration, 0.0), 1.0)) if duration > 0 else 100
        step = 1 if self.tty else 10
        if pct // step == self.last // step and self.last >= 0:
            return
        self.last = pct
        msg = f"{self.label}: {pct:3d}%  t = {t:7.1f} s / {duration:g} s"
        if self.tty:
            self.stream.write("\r" + msg)
        else:
            self.stream.write(msg + "\n")
        self.stream.flush()

    def close(self, finished: bool = True) -> None:
        """Write the final line: simulated time reached and wall-clock time taken, and whether
        the run finished or was interrupted (then no report is written)."""
        if self.last < 0:
            return
        how = "done" if finished else "interrupted (no report written)"
        msg = (f"{self.label}: {how}, t = {self.t:.1f} s simulated in "
               f"{time.monotonic() - self.start:.1f} s")
        self.stream.write(f"\r{msg:<60}\n" if self.tty else msg + "\n")
        self.stream.flush()


def summarize(result: SimResult) -> str:
    """A few human lines: coverage (under each visibility model), landmarks seen by their
    owner, trades, completion (saying so when landmarks are unseen), final partition; for an
    inspection, what was captured and how it ended (:mod:`agent.protocol.inspection_end`:
    ``complete at t = X s`` or ``INCOMPLETE: G given up (...)``)."""
    t_end = float(result.times[-1]) if len(result.times) else 0.0
    if result.inspection is not None:
        t = result.t_complete if result.complete else None
        return "\n".join([result.inspection.end_line(t),
                          f"{len(result.captures)} capture(s), {len(result.trades)} "
                          "re-split(s) of the remaining work"])
    if result.complete:
        done = f"complete at t = {result.t_complete:g} s" if result.t_complete is not None \
            else "complete"
        unseen = int((~result.seen_by_owner()).sum())
        if unseen:
            done += f" with {unseen} landmark(s) unseen by their owner"
    else:
        done = f"NOT complete after {t_end:g} s"
    owner = result.final_owner
    ids = np.asarray(result.landmark_ids)
    parts = []
    for i, aid in enumerate(result.agent_ids):
        mine = ids[owner == i]
        parts.append(f"{aid}: {mine.tolist()}" if ids.size <= 60 else f"{aid}: {mine.size}")
    return "\n".join([
        f"{result.coverage_line()}; {len(result.trades)} trade(s); {done}",
        result.quality_line(),
        ("final partition: " if ids.size <= 60 else "landmarks per agent: ") + "; ".join(parts),
    ])


def cmd_simulate(args: argparse.Namespace) -> int:
    """``viscover simulate SCENARIO.toml --out DIR``: the run, then the report that
    ``viscover report`` writes of a recording (result.json, plots, report.html); with fault
    flags the rehearsal of :mod:`agent.testing.rehearsal` (rehearsal.json, the observer's
    end). Exit status :data:`~agent.errors.EXIT_FAILURE` on an invariant violation,
    :data:`~agent.errors.EXIT_INCOMPLETE` when an inspection ended with landmarks given up
    (the report is written all the same), else 0."""
    from agent.world.structure import resolve_structure

    scenario = kit.scenario_arg(args.scenario, resolve=False)  # sampled after --seed
    if args.seed is not None:
        if args.seed < 0:
            raise UsageError(f"--seed {args.seed}: must be a non-negative integer")
        scenario = scenario.with_seed(args.seed)
    check_engine(scenario, args.engine, "--engine", faulted=False)
    faults = rehearsal_faults(args, scenario)
    out = kit.output_dir(args.out)

    progress = None if args.quiet else Progress(scenario.name)
    finished = False
    try:
        result, outcome = run_simulation(scenario, args.engine, faults, progress)
        finished = True
    finally:
        if progress is not None:
            progress.close(finished)
    paths = write_report(result, out, plots=not args.no_plots)
    if not args.no_plots:  # --no-plots: result.json only (a fast, scriptable run)
        write_html(result, out, paths, source="simulated", scenario=scenario,
                   date=utc(time.time()) + " (simulated)",
                   digest=scenario_digest(resolve_structure(scenario)))
    if faults is not None and outcome is not None:
        paths.append(write_rehearsal(out, faults, outcome))
    print(f"report written to {out}/ ({', '.join(p.name for p in paths)})")
    if not args.quiet:
        print(summarize(result))
    if faults is not None and outcome is not None:
        if not args.quiet:
            print_rehearsal(faults, outcome)
        else:  # --quiet: the violations alone, on stderr
            for v in outcome.violations:
                print(f"VIOLATION {v}", file=sys.stderr)
    return exit_status(result, outcome)


def check_engine(scenario: Scenario, engine: str, name: str, faulted: bool) -> None:
    """One line (:class:`UsageError`, naming the option ``name``) if ``engine`` cannot run
    ``scenario``: the lockstep engine runs the thesis strategy and inspections only, and no
    faults."""
    if engine not in ("agents", "lockstep"):
        raise UsageError(f"{name} {engine}: choose agents or lockstep")
    if engine != "lockstep":
        return
    if faulted:
        raise UsageError(f"{name} lockstep: faults are rehearsed with the agents' own code "
                         f"over their network; drop {name} lockstep")
    if scenario.inspection is None and strategy_of(scenario.strategy).extends_thesis:
        why = LOCKSTEP_THESIS_ONLY.format(strategy=scenario.strategy)
        raise UsageError(f"{name} lockstep: {why}; drop {name} lockstep")


def run_simulation(scenario: Scenario, engine: str, faults: MissionFaults | None,
                   progress: Progress | None = None) -> tuple[SimResult, Outcome | None]:
    """The mission of ``scenario`` in memory on virtual time: under ``faults`` the agents' own
    code watched by an observer (the rehearsal's outcome too), else ``engine``'s run (agents:
    the drones' own decision code; lockstep: chapter 5's engines)."""
    if faults is not None:
        from agent.testing.agent_engine import rehearse

        return rehearse(scenario, faults, progress=progress)
    if engine == "agents":
        from agent.testing.agent_engine import simulate_agents

        return simulate_agents(scenario, progress=progress), None
    return simulate(scenario, progress=progress), None


def exit_status(result: SimResult, outcome: Outcome | None) -> int:
    """``viscover simulate``'s status: :data:`~agent.errors.EXIT_FAILURE` on an invariant
    violation, :data:`~agent.errors.EXIT_INCOMPLETE` for an inspection that left landmarks,
    else 0."""
    if outcome is not None and outcome.violations:
        return EXIT_FAILURE
    if result.inspection is not None and not result.inspection.complete:
        return EXIT_INCOMPLETE
    return 0


def rehearsal_faults(args: argparse.Namespace, scenario: Scenario) -> MissionFaults | None:
    """The fault flags of ``simulate`` as :class:`MissionFaults` (None: none given); a bad
    value, a drone not of ``scenario`` or ``--engine lockstep`` with faults: one line
    (:class:`UsageError`)."""
    from agent.testing.rehearsal import faults_of

    given = [args.drop, args.dup, args.jitter, args.fault_seed]
    if all(x is None for x in given) and not args.lose:
        return None
    faults = faults_of(drop=args.drop or "0", dup=args.dup or "0", jitter=args.jitter or "0",
                       lose=args.lose, seed=args.fault_seed or "0")
    check_engine(scenario, args.engine, "--engine", faulted=True)
    faults.check(scenario)
    return faults


def write_rehearsal(out: Path, faults: MissionFaults, outcome: Outcome) -> Path:
    """``rehearsal.json`` in ``out``: the faults, the drones lost (id → mission time [s]),
    every violation, and the observer's report (``observer.json`` of a launched run, its
    times in mission seconds)."""
    doc = {"faults": {"drop": faults.drop, "dup": faults.dup, "jitter_s": faults.jitter,
                      "lose": [{"id": a, "t": t} for a, t in faults.losses],
                      "seed": faults.seed},
           "lost": outcome.lost, "violations": outcome.violations,
           "complete": outcome.complete, "observer": outcome.report.to_json()}
    path = out / "rehearsal.json"
    path.write_text(json.dumps(doc, indent=1) + "\n", encoding="utf-8")
    return path


def print_rehearsal(faults: MissionFaults, outcome: Outcome) -> None:
    """The faults, then the observer's end of the mission as ``viscover observe`` prints it
    (times in mission seconds), the drones lost, and the ledgers' own violations."""
    from agent.mission.observer import print_report
    from agent.testing.rehearsal import lost_line

    print(f"rehearsal: {faults.describe()}")
    print_report(outcome.report)
    if line := lost_line(outcome.lost, outcome.report):
        print(line)
    seen = set(outcome.report.violations)  # printed by print_report
    for v in outcome.violations:
        if v not in seen:
            print(f"VIOLATION {v}")
    print("invariants: " + ("hold" if outcome.ok else f"{len(outcome.violations)} "
                            "violation(s)"))


def register_simulate(sub: kit.Subparsers) -> None:
    """Add ``simulate``."""
    p = sub.add_parser(
        "simulate",
        help="simulate a scenario's mission in one process and write a report",
        description="Simulate SCENARIO (a .toml file) in one process, on virtual time, with "
        "the drones' own decision code (or --engine lockstep: chapter 5's simulation, every "
        "drone stepped in turn; the thesis and inspection missions), and write its report "
        "to --out: result.json, plots, landmarks.csv and report.html (the page viscover "
        "report writes of a recorded mission). With --drop, --dup, --jitter, --lose or "
        "--fault-seed the mission is rehearsed under seeded faults, watched by an observer "
        "as a launched mission is (rehearsal.json; docs/api.md). Exit 1 on an invariant "
        "violation, 3 when an inspection ends incomplete (landmarks given up, or its "
        "duration ran out first).",
    )
    p.add_argument("scenario", metavar="SCENARIO.toml", help="scenario file")
    p.add_argument("--out", required=True, metavar="DIR", help="report directory (created)")
    p.add_argument("--seed", type=int, default=None, help="override the scenario seed")
    p.add_argument("--engine", choices=("agents", "lockstep"), default="agents",
                   help="agents (default): one agent core per drone in memory, in virtual "
                   "time, the decision code the drones run (what they will do); lockstep: "
                   "the reference engines that step every drone in turn each Δt (chapter 5's "
                   "simulation of the thesis strategy, and inspection missions; 2-3x "
                   "faster)")
    p.add_argument("--no-plots", action="store_true", help="write result.json only")
    p.add_argument("--quiet", action="store_true",
                   help="no progress line and no summary (errors still go to stderr)")
    f = p.add_argument_group(
        "fault rehearsal (the agents' own code; seeded, deterministic; watched by an observer: "
        "invariants checked, rehearsal.json written; exit 1 on a violation)")
    f.add_argument("--drop", default=None, metavar="P",
                   help="probability that any message is lost (each agent, both ways)")
    f.add_argument("--dup", default=None, metavar="P",
                   help="probability that a delivered message is delivered twice")
    f.add_argument("--jitter", default=None, metavar="S",
                   help="each copy delayed by a uniform random time in [0, S) [s]: messages "
                   "overtake each other")
    f.add_argument("--lose", action="append", default=[], metavar="ID@T",
                   help="drone ID lost for good at mission time T [s] (repeatable); the team "
                   "fences it out after the scenario's lost_after and adopts its landmarks")
    f.add_argument("--fault-seed", default=None, metavar="N",
                   help="seed of every fault (default 0): the same seed, the same run")
    p.set_defaults(func=cmd_simulate)


def cmd_scenario_check(args: argparse.Namespace) -> int:
    """``viscover scenario check FILE...``: each file parsed, and its mesh read and
    sampled as a run does, so that a bad mesh is an error here too."""
    from agent.world.structure import resolve_structure

    bad = 0
    for f in args.files:
        try:
            sc = resolve_structure(load_scenario(f))
        except ScenarioError as e:
            print(f"viscover: error: {e}", file=sys.stderr)
            bad += 1
            continue
        print(f"ok  {f}: {sc.summary()}")
        if sc.structure is not None:
            print(f"    {mesh_check(sc)}")
        if sc.inspection is not None:
            try:
                print(f"    {inspection_check(sc)}")
            except ScenarioError as e:
                print(f"viscover: error: {e}", file=sys.stderr)
                bad += 1
    return EXIT_USAGE if bad else 0


def mesh_check(sc: Scenario) -> str:
    """One line on what the structure's mesh held and what loading it repaired, and how
    many of its landmarks lie on surface no camera can image (buried inside another part,
    or facing a closed cavity)."""
    from agent.structure.mesh import mesh_repairs
    from agent.structure.solid import BURIED, CAVITY
    from agent.world.structure import structure_model

    assert sc.structure is not None
    model = structure_model(sc.structure)
    repairs = mesh_repairs(model.mesh)
    line = "mesh: " + (repairs.line() if repairs is not None else "as given")
    hidden = model.hidden(sc.q, sc.u)
    of = np.asarray(sc.landmark_ids) if sc.view_of is None else np.asarray(sc.view_of)

    def count(code: int) -> int:  # landmarks, not the view landmarks of a multi-view spec
        return int(np.unique(of[hidden == code]).size)

    line += (f"; {count(BURIED)} landmarks on faces buried inside another part, "
             f"{count(CAVITY)} facing a closed cavity")
    return line


def inspection_check(sc: Scenario) -> str:
    """One line on what an inspection scenario can capture, naming every uncapturable
    landmark with its reason (the mesh is read and sampled here)."""
    from agent.core.inspection import uncapturable_line
    from agent.world.structure import resolve_structure
    from agent.world.tables import mission_tables

    sc = resolve_structure(sc)
    table, _ = mission_tables(sc)
    ids = np.asarray(sc.landmark_ids)
    m = ids.size
    what = "landmarks" if sc.view_of is None else "view landmarks"
    line = (f"inspection: {int(table.capturable.sum())}/{m} {what} capturable at "
            f"{sc.inspection.describe()} from {table.P.shape[0]} candidate viewpoints"
            if sc.inspection is not None else "")
    if bad := uncapturable_line(table.reason, ids):
        line += f"; {bad}"
    return line


def register_scenario(sub: kit.Subparsers) -> None:
    """Add ``scenario check``."""
    p = sub.add_parser("scenario", help="work with scenario files",
                       description="Work with scenario files.")
    ssub = p.add_subparsers(dest="scenario_cmd", metavar="ACTION", required=True)
    c = ssub.add_parser("check", help="validate scenario files and print a summary",
                        description="Validate each FILE; print one summary line per good file "
                        "and one error line per bad one (exit 2 if any is bad).")
    c.add_argument("files", nargs="+", metavar="FILE", help="scenario .toml files")
    c.set_defaults(func=cmd_scenario_check)
