"""The run folder of ``viscover launch``: a fresh one per launch (:func:`new_run_dir`), the
check that a folder given to ``--resume`` is of the same scenario (:func:`check_resume`:
its ``launch.json`` and every journal carry the scenario's digest, :mod:`agent.config.digest`)
and the command lines that reach a launched mission from another terminal
(:func:`mission_commands`, printed at start and kept in ``launch.json``); after an inspection
mission, ``captures.jsonl`` from the agents' journals (:func:`write_captures`).
"""

from __future__ import annotations

import json
import shlex
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from agent.config.digest import scenario_digest
from agent.config.scenario import Scenario
from agent.errors import UsageError
from agent.mission.child import Child
from agent.protocol.records import CaptureRec
from agent.storage.journal import Journal, read_header


def new_run_dir(root: Path, scenario_name: str) -> Path:
    """A fresh ``root/<scenario>-<UTC time>[-n]`` folder."""
    stamp = time.strftime("%Y%m%d-%H%M%S", time.gmtime())
    for n in range(1000):
        path = root / f"{scenario_name}-{stamp}{'' if n == 0 else f'-{n}'}"
        try:
            path.mkdir(parents=True)
            return path
        except FileExistsError:
            continue
        except OSError as e:
            raise UsageError(f"--runs {root}: cannot create a run folder: {e.strerror or e}") \
                from None
    raise UsageError(f"--runs {root}: too many runs started this second")


def check_resume(run_dir: Path, sc: Scenario, scenario_path: str) -> None:
    """Refuse (a :class:`UsageError`, one line) to resume ``run_dir`` with scenario ``sc``
    unless its ``launch.json`` and every journal's header carry ``sc``'s digest; reads
    only, so a refused folder is left exactly as it was."""
    digest = scenario_digest(sc)
    fresh = "start a fresh run without --resume"
    try:
        doc = json.loads((run_dir / "launch.json").read_text())
    except (OSError, ValueError):
        doc = {}
    found: list[tuple[str, str, str]] = []  # (digest, scenario name, scenario file)
    if isinstance(doc, dict) and isinstance(doc.get("scenario_digest"), str):
        found.append((doc["scenario_digest"], str(doc.get("scenario_name", "?")),
                      str(doc.get("scenario", "?"))))
    for journal in sorted((run_dir / "state").glob("*/journal.bin")):
        head = read_header(journal)
        if head is not None:
            found.append((head.digest, head.scenario, head.source))
        elif journal.stat().st_size > 0:
            raise UsageError(f"--resume {run_dir}: journal {journal.parent} has no scenario "
                             "digest (an older viscover wrote it) and cannot be checked "
                             f"against {sc.name} ({scenario_path}); {fresh}")
    if not found:
        raise UsageError(f"--resume {run_dir}: no scenario digest in its launch.json (an older "
                         f"viscover wrote it): it cannot be checked against {sc.name} "
                         f"({scenario_path}); {fresh}")
    for got, name, source in found:
        if got == digest:
            continue
        other = f"another version of scenario {name}" if name == sc.name else \
            f"scenario {name}"
        raise UsageError(f"--resume {run_dir}: the run folder is a mission of {other} "
                         f"({source}), not of {sc.name} ({scenario_path}): resume it with "
                         f"viscover launch {source} --resume {run_dir}, or {fresh}")


def mission_commands(scenario_path: str, mission: str, endpoint: str,
                     extra: list[str] | tuple[str, ...] = ()) -> dict[str, str]:
    """The ``viscover status / land / stop`` command lines that reach the mission on the
    router at ``endpoint`` (``extra``: e.g. ``--tls-dir DIR``)."""
    tail = ["--scenario", scenario_path, "--mission", mission, "--connect", endpoint, *extra]
    return {"status": shlex.join(["viscover", "status", *tail]),
            "land": shlex.join(["viscover", "land", "--all", *tail]),
            "stop": shlex.join(["viscover", "stop", "--all", *tail])}


def write_captures(run_dir: Path, sc: Scenario) -> int:
    """For an inspection mission ``sc``: ``run_dir/captures.jsonl``, every capture the agents
    journaled (one line each, in time order: ``t`` [mission s], ``agent``, ``landmarks``
    (ids), camera ``position`` [m; world ENU], ``direction`` and image ``right`` axis (unit),
    each landmark's ``quality``), read from the journals under ``run_dir/state`` once the
    agents have left. Returns the count (nothing is written for a coverage mission)."""
    if sc.inspection is None:
        return 0
    rows = []
    for state in sorted((run_dir / "state").glob("*")):  # one journal folder per drone
        if not (state / "journal.bin").is_file():
            continue
        try:
            j = Journal(state)
            recs = [r for r in j.replay() if isinstance(r, CaptureRec)]
            j.close()
        except (OSError, UsageError):  # a damaged journal (JournalCorrupt): reported elsewhere
            continue
        rows += [{"t": r.t, "agent": state.name, "landmarks": list(r.ids), "position": list(r.p),
                  "direction": list(r.v), "right": list(r.right), "quality": list(r.quality)}
                 for r in recs]
    rows.sort(key=lambda r: (r["t"], r["agent"]))
    with open(run_dir / "captures.jsonl", "w", encoding="utf-8") as fh:
        fh.writelines(json.dumps(r) + "\n" for r in rows)
    return len(rows)


def write_launch_json(run_dir: Path, doc: dict[str, Any], children: Mapping[str, Child]) -> None:
    """``run_dir/launch.json``: ``doc`` and, under ``processes``, each child's command, pids,
    exit code, restarts and log."""
    doc = {**doc, "processes": {n: {"cmd": c.cmd, "pids": c.pids, "exit_code": c.exit_code,
                                    "restarts": c.restarts, "log": str(c.log_path)}
                                for n, c in children.items()}}
    (run_dir / "launch.json").write_text(json.dumps(doc, indent=1))
