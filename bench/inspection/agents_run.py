"""An inspection flown by agent runtimes in memory (:class:`agent.testing.memsim.
MemoryMission`: one :class:`~agent.runtime.shell.runtime.AgentRuntime` per drone, their trade
protocol and journals, virtual time), measured as the simulator's run of the same start is:
the fraction captured, the time of the last first capture, and false captures re-checked
from the journaled capture poses (:mod:`bench.inspection.recheck`)."""

from __future__ import annotations

import math
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from agent.config.scenario import Scenario
from agent.core.inspection import CaptureTable
from agent.net.faults import FaultConfig
from agent.protocol.records import CaptureRec
from agent.storage.journal import Journal
from agent.testing.memsim import MemoryMission
from agent.world.structure import structure_model
from bench.inspection.recheck import LoggedCapture, close_views, false_captures


def agents_run(sc: Scenario, table: CaptureTable, loss: float, seed: int,
               gsd: tuple[float, float, float] | None = None,
               views: tuple[int, float] | None = None) -> dict[str, Any]:
    """One in-memory mission of ``sc`` at ``loss`` (with duplicates and reordering);
    ``gsd``: the re-check's GSD numbers (:func:`bench.inspection.scenes.recheck_gsd`);
    ``views``: (views per landmark, parallax [deg]) of a multi-view inspection."""
    assert sc.inspection is not None and sc.structure is not None
    faults = FaultConfig(drop_default=loss, duplicate=0.1, jitter_s=0.05) if loss else None
    with tempfile.TemporaryDirectory() as root:
        mm = MemoryMission(sc, root, faults=faults, seed=seed)
        t0 = time.perf_counter()
        try:
            done = mm.run(sc.duration)
            violations = mm.final_violations()
        finally:
            mm.close()
        wall = time.perf_counter() - t0
        recs: list[CaptureRec] = []
        for a in sc.agents:  # one journal per drone
            j = Journal(Path(root) / a.id)
            recs += [r for r in j.replay() if isinstance(r, CaptureRec)]
            j.close()
    ids = np.asarray(sc.landmark_ids)
    first: dict[int, float] = {}
    for r in sorted(recs, key=lambda r: r.t):
        for lid in r.ids:
            first.setdefault(lid, r.t)
    want = set(ids[table.capturable].tolist())
    got = want & set(first)
    spec = sc.inspection
    fov = (180.0, 180.0) if spec.fov is None else \
        (math.degrees(spec.fov[0]), math.degrees(spec.fov[1]))
    inc = 90.0 if spec.max_incidence is None else math.degrees(spec.max_incidence)
    caps: list[LoggedCapture] = [
        {"position": r.p, "direction": r.v, "right": r.right, "landmarks": r.ids}
        for r in recs]
    bad = false_captures(structure_model(sc.structure).mesh, caps, list(sc.landmark_ids),
                         sc.q, sc.u, sc.d_opt, spec.quality, fov, inc, gsd,
                         None if sc.view_axis is None or sc.view_cos is None
                         else (sc.view_axis, sc.view_cos))
    if views is not None and sc.view_of is not None:
        bad += close_views(caps, list(sc.landmark_ids), sc.q, sc.view_of, *views)
    return {"fraction": len(got) / max(len(want), 1), "complete": bool(done),
            "t": max((first[x] for x in got), default=float("nan")), "false": bad,
            "violations": len(violations), "wall_s": wall}
