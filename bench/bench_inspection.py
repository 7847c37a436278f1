"""Inspection benchmark: does the team capture everything, how fast against a centralised
offline plan, and are its captures real?

For each structure type of our own (:mod:`bench.inspection.scenes`: a U-shaped building
round a courtyard, a wind-turbine tower with its nacelle, a round storage tank, a gabled
house; CAD-like assemblies of closed parts that overlap or touch (a house body and a roof set
into it, a U of three overlapping boxes, a chimney with a platform and a boiler house); an
open scan with wrongly wound triangles; occlusion, a 90°×70° field of view, incidence ≤ 75°,
quality ≥ 0.3; and the CAD house specified by a camera: GSD ≤ 2 mm/px within 60°, aimed 10 %
finer, also with three views 20° apart of each landmark), 1-6 drones and ``STARTS`` seeded
random starts per cell, the simulator flies the inspection
(:class:`agent.sim.inspection.InspectionSim`) and each run is measured:

- ``captured_fraction``: captured / capturable landmarks (goal: 1 in every run);
- ``time_ratio``: mission time (until the last capture) over the offline plan's
  (:mod:`bench.inspection.offline`; goal: median ≤ 1.5, worst ≤ 2); ``time_home_ratio``:
  until every drone is home, over the offline plan flown back to the starts (same goal);
- ``distance``: metres flown by the team, and by its busiest drone;
- ``false_captures``: logged captures that fail the independent re-check
  (:mod:`bench.inspection.recheck`; with the camera, the GSD from its datasheet numbers; with
  views, also each landmark whose captured views are closer than the parallax; goal: 0).

The same strategy flown by agent runtimes in memory at 30 % loss (``inspection_agents_cell``,
``inspection_agents_summary``; :mod:`bench.inspection.agents_run`) on a subset of the cells:
captured fraction, the time of the last first capture over the simulator's for the same
start, false captures from the journaled capture poses, ownership violations.

One row per cell (``inspection_cell``), one summary row (``inspection_summary``) and the
per-tick cost of the inspection at 10⁴ landmarks (``inspection_tick``): the capture test over
every uncaptured landmark, the decision on the next viewpoint (and its route), and apart the
flight step (the planner's section-4.3 avoidance of the structure, not the inspection's).

Run: ``python -m bench.bench_inspection [--starts N] [--sizes 1,2,3] [--structures a,b]``.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time
from typing import Any, TextIO

import numpy as np

from agent.sim.inspection import InspectionSim
from agent.world.tables import mission_tables
from bench.inspection.agents_run import agents_run
from bench.inspection.offline import offline_plan
from bench.inspection.recheck import close_views, false_captures, logged, spec_angles
from bench.inspection.scenes import (
    PARALLAX_DEG,
    SCENES,
    Scene,
    random_starts,
    recheck_gsd,
    scenario,
)

SIZES = (1, 2, 3, 4, 5, 6)
STARTS = 10
#: The agents (in memory, at 30 % loss) against the simulator: a subset of the cells.
AGENT_SIZES = (1, 2, 3, 4, 6)
AGENT_STARTS = 3


def _emit(out: TextIO, rec: dict[str, Any]) -> None:
    out.write(json.dumps(rec) + "\n")
    out.flush()


def _run(scene: Scene, n: int, seed: int, cache: dict[str, Any]) -> dict[str, Any]:
    """One run: random starts, the flown inspection, the offline plan, the re-check."""
    rng = np.random.default_rng([SCENES.index(scene), n, seed])
    starts = random_starts(scene, n, rng)
    sc = scenario(scene, starts)
    if scene.kind not in cache:
        cache[scene.kind] = mission_tables(sc)
    table, grid = cache[scene.kind]
    sim = InspectionSim(sc, table, grid)
    t0 = time.perf_counter()
    while not sim.done and sim.t < sc.duration:
        sim.tick()
    # Then until every drone is home (the mission's time as the field team lives it).
    while not all(d.mode == "done" for d in sim.drones) and sim.t < sc.duration:
        sim.tick()
    wall = time.perf_counter() - t0
    plan = offline_plan(table, starts, sc.params.p_lim)
    summary = sim.summary()
    bad = _false(sim, scene)
    capturable = int(table.capturable.sum())
    got = int((sim.cap & table.capturable).sum())
    t_end = sim.t_complete if sim.t_complete is not None else sim.t
    dist = sim.distances()
    return {"fraction": got / max(capturable, 1), "t": t_end, "t_offline": plan.time,
            "ratio": t_end / max(plan.time, sc.params.dt), "t_home": sim.t,
            "ratio_home": sim.t / max(plan.time_home, sc.params.dt),
            "distance": float(dist.sum()),
            "distance_max": float(dist.max()), "false": bad, "complete": sim.complete,
            "landmarks": len(sc.landmark_ids), "uncapturable": len(summary.uncapturable),
            "viewpoints_offline": plan.viewpoints, "captures": len(sim.captures),
            "wall_s": wall}


def _false(sim: InspectionSim, scene: Scene) -> int:
    """Logged captures of ``sim`` that fail the independent re-check (with the camera's
    GSD from its datasheet numbers in a GSD scene)."""
    spec = sim.spec
    fov, inc = spec_angles(spec)
    captures = logged(sim.captures)
    assert sim.model is not None
    sc = sim.sc
    sectors = None if sc.view_axis is None or sc.view_cos is None else \
        (sc.view_axis, sc.view_cos)
    bad = false_captures(sim.model.mesh, captures, list(sc.landmark_ids), sc.q, sc.u,
                         sc.d_opt, spec.quality, fov, inc, recheck_gsd(scene), sectors)
    if sc.view_of is not None:  # views of one landmark closer than the parallax
        bad += close_views(captures, list(sc.landmark_ids), sc.q, sc.view_of, scene.views,
                           PARALLAX_DEG)
    return bad


def _cell(scene: Scene, n: int, starts: int, cache: dict[str, Any]) -> dict[str, Any]:
    runs = [_run(scene, n, s, cache) for s in range(starts)]
    ratios = [r["ratio"] for r in runs]
    homes = [r["ratio_home"] for r in runs]
    return {
        "bench": "inspection_cell", "structure": scene.kind, "mesh": scene.mesh, "drones": n,
        "starts": starts, "landmarks": runs[0]["landmarks"],
        "uncapturable": runs[0]["uncapturable"],
        "captured_fraction_min": round(min(r["fraction"] for r in runs), 4),
        "runs_incomplete": sum(not r["complete"] for r in runs),
        "time_s_median": round(statistics.median(r["t"] for r in runs), 1),
        "offline_time_s_median": round(statistics.median(r["t_offline"] for r in runs), 1),
        "time_ratio_median": round(statistics.median(ratios), 3),
        "time_ratio_worst": round(max(ratios), 3),
        "time_home_s_median": round(statistics.median(r["t_home"] for r in runs), 1),
        "time_home_ratio_median": round(statistics.median(homes), 3),
        "time_home_ratio_worst": round(max(homes), 3),
        "distance_m_median": round(statistics.median(r["distance"] for r in runs), 1),
        "distance_max_drone_m_median": round(statistics.median(r["distance_max"]
                                                               for r in runs), 1),
        "false_captures": sum(r["false"] for r in runs),
        "captures_median": statistics.median(r["captures"] for r in runs),
        "offline_viewpoints": runs[0]["viewpoints_offline"],
        "wall_s_per_run": round(statistics.mean(r["wall_s"] for r in runs), 2),
        "ratios": [round(x, 3) for x in ratios],
        "home_ratios": [round(x, 3) for x in homes],
    }


def tick_cost(m_target: int = 10_000, ticks: int = 200) -> dict[str, Any]:
    """Per-tick cost of one drone's inspection decision at about ``m_target`` landmarks."""
    scene = SCENES[0]
    rng = np.random.default_rng(7)
    starts = random_starts(scene, 2, rng)
    sc = scenario(scene, starts)  # spacing scaled from this sample's density
    spacing = scene.spacing * float(np.sqrt(len(sc.landmark_ids) / m_target))
    sc = scenario(Scene(scene.kind, scene.mesh, scene.d_opt, spacing, scene.lo, scene.hi),
                  starts)
    assert sc.inspection is not None and sc.structure is not None
    t0 = time.perf_counter()
    table, grid = mission_tables(sc)  # the capture table and the route grid
    build = time.perf_counter() - t0
    sim = InspectionSim(sc, table, grid)
    decided: list[float] = []
    plain_decide = sim._decide

    def timed_decide(i: int) -> None:  # the strategy's decision, timed apart from the flight
        t = time.perf_counter()
        plain_decide(i)
        decided.append(time.perf_counter() - t)

    sim._decide = timed_decide  # type: ignore[method-assign]
    captures, decisions, flights = [], [], []
    for _ in range(ticks):
        n = len(decided)
        t = time.perf_counter()
        sim._act(0)
        act = time.perf_counter() - t
        t = time.perf_counter()
        sim._capture(0)
        captures.append(time.perf_counter() - t)
        spent = sum(decided[n:])
        if len(decided) > n:
            decisions.append(spent)
        flights.append(act - spent)
        sim.t += sc.params.dt

    def ms(xs: list[float], q: float) -> float:
        return round(1e3 * float(np.quantile(xs, q)), 3) if xs else 0.0

    return {"bench": "inspection_tick", "landmarks": len(sc.landmark_ids),
            "candidates": int(table.P.shape[0]), "table_build_s": round(build, 2),
            "capture_ms_median": ms(captures, 0.5), "capture_ms_p95": ms(captures, 0.95),
            "capture_ms_max": ms(captures, 1.0), "decisions": len(decisions),
            "decision_ms_median": ms(decisions, 0.5), "decision_ms_max": ms(decisions, 1.0),
            "decision_tick_ms_max": round(ms(captures, 1.0) + ms(decisions, 1.0), 3),
            "flight_ms_median": ms(flights, 0.5), "flight_ms_p95": ms(flights, 0.95),
            "flight_ms_max": ms(flights, 1.0),
            "goal_ms": 5.0, "load_1min": round(os.getloadavg()[0], 2),
            "note": "capture: the capture test over every uncaptured landmark (with line of "
                    "sight); decision: choosing the next viewpoint (the rest of the tour, or a "
                    "new one after a re-split) and its route; decision_tick: the worst capture "
                    "plus the worst decision (the inspection's part of a tick, goal 5 ms); "
                    "flight: one dt of transit with section-4.3 avoidance of the structure "
                    "(the planner's, not the inspection's)"}


def agents_cells(out: TextIO, sizes: tuple[int, ...] = AGENT_SIZES,
                 starts: int = AGENT_STARTS, loss: float = 0.3,
                 scenes: tuple[Scene, ...] = SCENES) -> list[dict[str, Any]]:
    """The agents in memory against the simulator, same starts: one row per cell and one
    summary row."""
    cache: dict[str, Any] = {}
    cells = []
    for scene in scenes:
        for n in sizes:
            runs = []
            for seed in range(starts):
                rng = np.random.default_rng([SCENES.index(scene), n, seed])
                sc = scenario(scene, random_starts(scene, n, rng))
                if scene.kind not in cache:
                    cache[scene.kind] = mission_tables(sc)
                table, grid = cache[scene.kind]
                sim = InspectionSim(sc, table, grid)
                while not sim.done and sim.t < sc.duration:
                    sim.tick()
                got = agents_run(sc, table, loss, seed, recheck_gsd(scene),
                                 (scene.views, PARALLAX_DEG) if scene.views > 1 else None)
                got["ratio"] = got["t"] / max(sim.t_complete or sim.t, sc.params.dt)
                runs.append(got)
            ratios = [r["ratio"] for r in runs]
            rec = {"bench": "inspection_agents_cell", "structure": scene.kind, "drones": n,
                   "starts": starts, "loss": loss,
                   "captured_fraction_min": round(min(r["fraction"] for r in runs), 4),
                   "runs_incomplete": sum(not r["complete"] for r in runs),
                   "time_vs_simulator_median": round(statistics.median(ratios), 3),
                   "time_vs_simulator_worst": round(max(ratios), 3),
                   "false_captures": sum(r["false"] for r in runs),
                   "violations": sum(r["violations"] for r in runs),
                   "wall_s_per_run": round(statistics.mean(r["wall_s"] for r in runs), 1)}
            _emit(out, rec)
            cells.append(rec)
    summary = {"bench": "inspection_agents_summary", "cells": len(cells),
               "runs": starts * len(cells), "loss": loss,
               "captured_fraction_min": min(c["captured_fraction_min"] for c in cells),
               "runs_incomplete": sum(c["runs_incomplete"] for c in cells),
               "time_vs_simulator_median_of_cells": round(statistics.median(
                   c["time_vs_simulator_median"] for c in cells), 3),
               "time_vs_simulator_worst": max(c["time_vs_simulator_worst"] for c in cells),
               "false_captures": sum(c["false_captures"] for c in cells),
               "violations": sum(c["violations"] for c in cells)}
    _emit(out, summary)
    return [*cells, summary]


def run(out: TextIO | None = None, sizes: tuple[int, ...] = SIZES, starts: int = STARTS,
        tick: bool = True, agents: bool = True, scenes: tuple[Scene, ...] = SCENES
        ) -> list[dict[str, Any]]:
    """Every cell, the summary and the per-tick cost; printed and returned."""
    out = out or sys.stdout
    cache: dict[str, Any] = {}
    cells = []
    for scene in scenes:
        for n in sizes:
            rec = _cell(scene, n, starts, cache)
            _emit(out, rec)
            cells.append(rec)
    ratios = [x for c in cells for x in c["ratios"]]
    homes = [x for c in cells for x in c["home_ratios"]]
    summary = {
        "bench": "inspection_summary", "runs": len(ratios),
        "structures": [s.kind for s in scenes],
        "sizes": list(sizes), "starts": starts,
        "captured_fraction_min": min(c["captured_fraction_min"] for c in cells),
        "runs_incomplete": sum(c["runs_incomplete"] for c in cells),
        "time_ratio_median": round(statistics.median(ratios), 3),
        "time_ratio_worst": round(max(ratios), 3),
        "runs_over_2x": sum(x > 2.0 for x in ratios),
        "time_home_ratio_median_of_cells": round(statistics.median(
            c["time_home_ratio_median"] for c in cells), 3),
        "time_home_ratio_worst": round(max(homes), 3),
        "false_captures": sum(c["false_captures"] for c in cells),
        "goal": "fraction 1 in every run; ratio median <= 1.5, worst <= 2; 0 false",
    }
    _emit(out, summary)
    records = [*cells, summary]
    if agents:
        records += agents_cells(out, scenes=scenes)
    if tick:
        rec = tick_cost()
        _emit(out, rec)
        records.append(rec)
    return records


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--starts", type=int, default=STARTS)
    ap.add_argument("--sizes", default=",".join(map(str, SIZES)))
    ap.add_argument("--no-tick", action="store_true")
    ap.add_argument("--tick-only", action="store_true")
    ap.add_argument("--agents-only", action="store_true")
    ap.add_argument("--no-agents", action="store_true")
    ap.add_argument("--structures", default="",
                    help="comma-separated scene kinds (default: all): "
                    + ",".join(s.kind for s in SCENES))
    a = ap.parse_args(argv)
    kinds = [k for k in a.structures.split(",") if k]
    unknown = sorted(set(kinds) - {s.kind for s in SCENES})
    if unknown:
        ap.error(f"unknown structure(s) {', '.join(unknown)}")
    scenes = tuple(s for s in SCENES if not kinds or s.kind in kinds)
    if a.tick_only:
        _emit(sys.stdout, tick_cost())
        return 0
    if a.agents_only:
        agents_cells(sys.stdout, scenes=scenes)
        return 0
    run(sizes=tuple(int(x) for x in a.sizes.split(",")), starts=a.starts, tick=not a.no_tick,
        agents=not a.no_agents, scenes=scenes)
    return 0


if __name__ == "__main__":
    sys.exit(main())
