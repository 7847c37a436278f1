"""The inspection summary of a recorded run (``viscover report RUN_DIR``): the run's scenario
found again (the run folder's ``launch.json`` ``scenario`` path, else the recording's
``/mission/info`` ``source``), its capture table (:func:`~agent.world.tables.mission_tables`)
and the captures of ``captures.jsonl`` give what ``viscover simulate`` reports: captured,
capturable, uncapturable with reasons (:class:`~agent.sim.result.InspectionSummary`), and
what was given up and why, as the launch's observer judged it (``observer.json``'s
``inspection``: :func:`observed_given_up`)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from agent.config.parse import load_scenario
from agent.config.scenario import Scenario
from agent.core.inspection import REASONS
from agent.errors import UsageError
from agent.protocol.inspection_end import CODE_OF, inspection_end
from agent.sim.resolution import scenario_parts, spec_numbers
from agent.sim.result import CaptureEvent, InspectionSummary
from agent.world.structure import resolve_structure
from agent.world.tables import mission_tables


def _candidates(run: Path, info: dict[str, Any]) -> list[Path]:
    """Where the run's scenario file may be: ``launch.json``'s path (as given to launch:
    from here, from the run folder, from the folder holding the runs), then the recording's
    source."""
    names: list[str] = []
    try:
        doc = json.loads((run / "launch.json").read_text(encoding="utf-8"))
        if isinstance(doc, dict) and isinstance(doc.get("scenario"), str):
            names.append(doc["scenario"])
    except (OSError, ValueError):
        pass
    if isinstance(info.get("source"), str):
        names.append(info["source"])
    out: list[Path] = []
    for name in names:  # at most two names
        p = Path(name)
        out += [p] if p.is_absolute() else [p, run / p, run.parent / p, run.parent.parent / p]
    return out


def run_scenario(run: Path, info: dict[str, Any]) -> tuple[Scenario | None, str]:
    """The run's inspection scenario (structure resolved) and "", or None and one line
    saying why not (none found, not an inspection, not the recorded landmarks)."""
    sc, why = find_scenario(run, info)
    if sc is None or sc.inspection is None:
        return None, why  # a coverage mission: nothing to say
    return sc, ""


def find_scenario(run: Path, info: dict[str, Any]) -> tuple[Scenario | None, str]:
    """The run's scenario (structure resolved) and "", or None and one line saying why not
    (none found, does not load, not the recorded landmarks)."""
    tried = _candidates(run, info)
    path = next((p for p in tried if p.is_file()), None)
    if path is None:
        where = ", ".join(dict.fromkeys(str(p) for p in tried)) or "no launch.json, no source"
        return None, f"scenario file not found ({where}): no inspection block"
    try:
        sc = resolve_structure(load_scenario(path))
    except UsageError as e:
        return None, f"scenario {path} does not load ({e}): no inspection block"
    if [int(x) for x in sc.landmark_ids] != [int(x) for x in info.get("landmark_ids", [])]:
        return None, f"scenario {path} has other landmarks than the recording: " \
            "no inspection block"
    return sc, ""


def inspection_summary(sc: Scenario, captures: list[CaptureEvent],
                       given_up: NDArray[np.int8] | None = None) -> InspectionSummary:
    """What the run captured (``captures``) against the capture table of ``sc``; a landmark
    uncapturable by the table but captured all the same counts as capturable. Each capturable
    landmark not captured is given up with the reason the drones gave (``given_up``: codes
    per landmark row of :mod:`agent.protocol.inspection_end`; None: none known), else for
    ``time`` (:func:`~agent.protocol.inspection_end.inspection_end`)."""
    assert sc.inspection is not None, "not an inspection mission"
    table, _ = mission_tables(sc)
    ids = np.asarray(sc.landmark_ids, dtype=np.int64)
    got = sorted({int(lid) for c in captures for lid in c.landmarks})
    cap = np.isin(ids, got)
    left = np.flatnonzero((table.reason != 0) & ~cap)
    return InspectionSummary(
        quality=sc.inspection.quality, spec=sc.inspection.describe(), captured=got,
        capturable=int(ids.size - left.size),
        uncapturable={int(ids[j]): REASONS[int(table.reason[j])] for j in left},
        given_up=inspection_end(ids, table.capturable, cap, given_up).given_up,
        numbers=spec_numbers(sc.inspection), parts=scenario_parts(sc))


def observed_given_up(run: Path, sc: Scenario) -> NDArray[np.int8] | None:
    """The given-up codes per landmark row of ``sc`` that the run's observer reported
    (``observer.json``: ``inspection`` → ``given_up`` {id: reason}); None without one."""
    try:
        doc = json.loads((run / "observer.json").read_text(encoding="utf-8"))
        said = doc["inspection"]["given_up"]
        row = {int(lid): k for k, lid in enumerate(sc.landmark_ids)}
        codes = np.zeros(len(row), dtype=np.int8)
        for lid, reason in said.items():  # the landmarks given up: a few
            codes[row[int(lid)]] = CODE_OF[reason]
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return None
    return codes
