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

At the scale of real structures the building is scaled by √10 (``--landmarks 10000``: 9,985
landmarks every 0.8 m on a 95 m × 88 m × 49 m space) and flown by 10 and 20 drones, both by
the agents in memory (``team_inspection``) and by ``viscover simulate`` itself, the command a
user runs, in a child process (``team_simulate``: its result.json's inspection block and its
completion time, against the same offline plan; its wall time and peak memory).

``make bench`` writes the 1,005-landmark row and the 10⁴ rows at 10 and 20 drones (about 20
minutes on this machine); ``python -m bench.bench_team [--drones 20] [--spacing 0.8]
[--landmarks 1000] [--simulate]`` one of them.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import resource
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, TextIO

import numpy as np

from agent.sim.inspection import InspectionSim
from agent.world.tables import mission_tables
from bench.inspection.agents_run import agents_run
from bench.inspection.offline import offline_plan
from bench.inspection.scenes import (
    SCENES,
    random_starts,
    recheck_gsd,
    scaled_scene,
    scenario,
    scene_text,
)

DRONES = 20
SPACING = 0.8  #: landmark spacing on the U building [m]: 1,005 landmarks
ROOT = Path(__file__).resolve().parents[1]
#: (drones, landmarks) of ``make bench``'s rows at the scale of real structures
LARGE = ((10, 10_000), (20, 10_000))


def team_inspection(drones: int = DRONES, scale: float = 1.0, spacing: float = SPACING,
                    seed: int = 0) -> dict[str, Any]:
    """The ``team_inspection`` row of one seeded start (the building scaled by ``scale``)."""
    scene = scaled_scene(next(s for s in SCENES if s.kind == "concave"), scale, spacing)
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
        "drones": drones, "scale": round(scale, 3), "landmarks": len(sc.landmark_ids),
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


def team_simulate(drones: int, scale: float, spacing: float = SPACING, seed: int = 0
                  ) -> dict[str, Any]:
    """The ``team_simulate`` row: ``viscover simulate`` of the same scene and start as
    :func:`team_inspection`, in a child process."""
    scene = scaled_scene(next(s for s in SCENES if s.kind == "concave"), scale, spacing)
    starts = random_starts(scene, drones, np.random.default_rng([0, drones, seed]))
    sc = scenario(scene, starts)
    table, _ = mission_tables(sc)
    plan = offline_plan(table, starts, sc.params.p_lim)
    with tempfile.TemporaryDirectory(prefix="viscover-team-") as tmp:
        toml = Path(tmp) / "team.toml"
        toml.write_text(scene_text(scene, starts), encoding="utf-8")
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(ROOT), env.get("PYTHONPATH")]))
        t0 = time.perf_counter()
        run = subprocess.run([sys.executable, "-m", "agent.cli", "simulate", str(toml), "--out",
                              str(Path(tmp) / "out"), "--no-plots", "--quiet"],
                             capture_output=True, text=True, env=env, cwd=ROOT)
        wall = time.perf_counter() - t0
        peak_mb = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
        if run.returncode not in (0, 3):
            raise RuntimeError(f"viscover simulate exited {run.returncode}: {run.stderr[-500:]}")
        res = json.loads((Path(tmp) / "out" / "result.json").read_text(encoding="utf-8"))
    ins = res["inspection"]  # captured: the landmark ids; capturable: how many
    t = res["t_complete"] if res["complete"] else None
    return {
        "bench": "team_simulate", "command": "viscover simulate", "structure": scene.kind,
        "drones": drones, "scale": round(scale, 3), "landmarks": len(sc.landmark_ids),
        "seed": seed, "captured": len(ins["captured"]), "capturable": ins["capturable"],
        "complete": bool(res["complete"]), "exit": run.returncode,
        "complete_s": None if t is None else round(t, 1),
        "offline_time_s": round(plan.time, 2),
        "time_ratio": None if t is None else round(t / max(plan.time, sc.params.dt), 3),
        "wall_s": round(wall, 1), "peak_mb": round(peak_mb),
        "goal": "every capturable landmark captured; complete",
    }


def run(out: TextIO | None = None, drones: int = DRONES, spacing: float = SPACING,
        scale: float | None = None, simulate: bool = False) -> list[dict[str, Any]]:
    """Print and return the rows: with ``scale`` None (``make bench``) the 1,005-landmark
    in-memory row and both kinds of row at each size of :data:`LARGE`; else one row."""
    stream = out if out is not None else sys.stdout
    todo: list[tuple[Callable[..., dict[str, Any]], int, float]]
    if scale is None:
        todo = [(team_inspection, drones, 1.0)]
        for n, m in LARGE:
            todo += [(team_inspection, n, math.sqrt(m / 1000.0)),
                     (team_simulate, n, math.sqrt(m / 1000.0))]
    else:
        todo = [(team_simulate if simulate else team_inspection, drones, scale)]
    rows = []
    for fn, n, k in todo:
        rec = fn(n, scale=k, spacing=spacing)
        stream.write(json.dumps(rec) + "\n")
        stream.flush()
        rows.append(rec)
    return rows


def main(argv: list[str] | None = None) -> int:
    """Command-line entry point."""
    p = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    p.add_argument("--drones", type=int, default=DRONES)
    p.add_argument("--spacing", type=float, default=SPACING, metavar="M")
    p.add_argument("--landmarks", type=int, default=1000, metavar="N",
                   help="scale the building by sqrt(N / 1000) (about N landmarks at 0.8 m)")
    p.add_argument("--simulate", action="store_true", help="viscover simulate, not in memory")
    a = p.parse_args(argv)
    run(sys.stdout, a.drones, a.spacing, math.sqrt(a.landmarks / 1000.0), a.simulate)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
