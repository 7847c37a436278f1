"""A 20-drone inspection of about 10³ landmarks, flown by the agents in memory.

The U-shaped building of the inspection benchmark (:mod:`bench.inspection.scenes`, scene
``concave``: occlusion, a 90°×70° field of view, incidence ≤ 75°, quality ≥ 0.3) sampled
every 0.8 m (1,005 landmarks), 20 drones from seeded random starts; the team is 20 agent
runtimes on the in-memory network (:class:`agent.testing.memsim.MemoryMission`, lossless,
virtual time: their trade protocol and journals, what the processes run), measured as the
inspection benchmark measures (:func:`bench.inspection.agents_run.agents_run`): the fraction
of the capturable landmarks captured (goal 1), the time of the last first capture against
the centralised offline plan of the same start (:mod:`bench.inspection.offline`; the
inspection benchmark's goal: ≤ 1.5 median, ≤ 2 worst) and against the simulator
(:class:`agent.sim.inspection.InspectionSim`), false captures by the independent re-check
(goal 0) and ownership violations (goal 0).

One row ``team_inspection``; run ``python -m bench.bench_team [--drones 20] [--spacing 0.8]``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from typing import Any, TextIO

import numpy as np

from agent.sim.inspection import InspectionSim
from agent.world.tables import mission_tables
from bench.inspection.agents_run import agents_run
from bench.inspection.offline import offline_plan
from bench.inspection.scenes import SCENES, random_starts, recheck_gsd, scenario

DRONES = 20
SPACING = 0.8  #: landmark spacing on the U building [m]: 1,005 landmarks


def team_inspection(drones: int = DRONES, spacing: float = SPACING, seed: int = 0
                    ) -> dict[str, Any]:
    """The ``team_inspection`` row of one seeded start."""
    scene = dataclasses.replace(next(s for s in SCENES if s.kind == "concave"),
                                spacing=spacing)
    starts = random_starts(scene, drones, np.random.default_rng([0, drones, seed]))
    sc = scenario(scene, starts)
    t0 = time.perf_counter()
    table, grid = mission_tables(sc)
    prepare_s = time.perf_counter() - t0
    plan = offline_plan(table, starts, sc.params.p_lim)
    sim = InspectionSim(sc, table, grid)
    while not sim.done and sim.t < sc.duration:
        sim.tick()
    got = agents_run(sc, table, 0.0, seed, recheck_gsd(scene))
    sim_t = sim.t_complete if sim.t_complete is not None else sim.t
    return {
        "bench": "team_inspection", "structure": scene.kind, "mesh": scene.mesh,
        "drones": drones, "landmarks": len(sc.landmark_ids),
        "capturable": int(table.capturable.sum()), "seed": seed, "loss": 0.0,
        "captured_fraction": round(got["fraction"], 4), "complete": got["complete"],
        "time_s": round(got["t"], 2), "offline_time_s": round(plan.time, 2),
        "offline_viewpoints": plan.viewpoints,
        "time_ratio": round(got["t"] / max(plan.time, sc.params.dt), 3),
        "simulator_time_s": round(sim_t, 2),
        "time_vs_simulator": round(got["t"] / max(sim_t, sc.params.dt), 3),
        "false_captures": got["false"], "violations": got["violations"],
        "prepare_s": round(prepare_s, 1), "wall_s": round(got["wall_s"], 1),
        "goal": "fraction 1; time_ratio <= 2 (inspection benchmark: median <= 1.5); "
                "0 false, 0 violations",
    }


def run(out: TextIO | None = None, drones: int = DRONES, spacing: float = SPACING
        ) -> list[dict[str, Any]]:
    """Print and return the ``team_inspection`` row."""
    stream = out if out is not None else sys.stdout
    rec = team_inspection(drones, spacing)
    stream.write(json.dumps(rec) + "\n")
    stream.flush()
    return [rec]


def main(argv: list[str] | None = None) -> int:
    """Command-line entry point."""
    p = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    p.add_argument("--drones", type=int, default=DRONES)
    p.add_argument("--spacing", type=float, default=SPACING, metavar="M")
    a = p.parse_args(argv)
    run(sys.stdout, a.drones, a.spacing)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
