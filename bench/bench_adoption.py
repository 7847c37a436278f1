"""Lost drones: how long from a drone's loss until its landmarks are adopted, and how much of
the coverage the team gets back (:mod:`agent.protocol.fencing`).

Each case runs the same mission three times on the in-process network (the agents' real
planner and protocol on virtual time, seeded faults; deterministic):

* ``full``: nobody is lost (the reference coverage);
* ``orphaned``: the victim is killed for good at ``kill_at`` and nothing is adopted
  (``lost_after = 0``): the survivors' coverage with the victim's landmarks left uncovered;
* ``adopted``: the same kill with ``lost_after``: the victim is fenced out, its landmarks
  adopted and traded on.

Rows (``bench = "adoption"``): time from the kill to the last adoption [mission s] and the part
of it beyond ``lost_after`` (detection + the fence round), time to completion after the kill,
coverage full / orphaned / adopted and ``recovered`` = (adopted - orphaned) / (full -
orphaned): the share of the coverage lost with the drone that the team got back; for 3-D
scenes also the best coverage known for the survivors alone (the quality benchmark's
centralised reference) and the share of what they could get back that they did.

Run: ``python -m bench.bench_adoption`` (or ``make bench``).
"""

from __future__ import annotations

import dataclasses
import json
import sys
import tempfile
from pathlib import Path
from typing import Any, TextIO

from agent.config.parse import load_scenario, parse_scenario
from agent.config.scenario import Scenario
from agent.net.faults import FaultConfig
from agent.runtime.shell.runtime import AgentConfig
from agent.testing.memsim import MemoryMission
from agent.world.structure import environment_of
from bench.bench_trade import swarm_scene_toml
from bench.quality.reference import reference
from bench.quality.structures import Structure

ROOT = Path(__file__).resolve().parent.parent
LOST_AFTER = 10.0  #: [mission s]


def _mission(sc: Scenario, root: Path, drop: float, seed: int) -> MemoryMission:
    faults = FaultConfig(drop_default=drop) if drop else None
    return MemoryMission(sc, root, faults, seed=seed,
                         config=AgentConfig(mission="bench", seed=seed))


def _survivors_done(m: MemoryMission, victim: str) -> bool:
    return all(rt.complete for aid, rt in m.agents.items() if aid != victim)


def _with_loss(sc: Scenario, root: Path, victim: str, kill_at: float, drop: float,
               seed: int, max_time: float) -> tuple[MemoryMission, float]:
    """Run until ``kill_at``, kill ``victim`` for good, run until the others complete."""
    m = _mission(sc, root, drop, seed)
    m.run(kill_at, until=lambda _m: False)
    m.crash(victim)
    t_kill = m.net.now
    m.run(max_time, until=lambda mm: _survivors_done(mm, victim))
    return m, t_kill


def adoption_case(name: str, sc: Scenario, victim: str, kill_at: float, drop: float,
                  seed: int, max_time: float = 900.0) -> dict[str, Any]:
    """One row (see the module docstring)."""
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        full = _mission(sc, root / "full", drop, seed)
        full.run(max_time)
        c_full = full.coverage()
        full.close()
        orphaned, _ = _with_loss(dataclasses.replace(sc, lost_after=0.0), root / "orphaned",
                                 victim, kill_at, drop, seed, max_time)
        c_orphaned = orphaned.coverage()
        orphaned.close()
        adopted, t_kill = _with_loss(dataclasses.replace(sc, lost_after=LOST_AFTER),
                                     root / "adopted", victim, kill_at, drop, seed, max_time)
        rounds = [r for rt in adopted.agents.values() for r in rt.core.adoption.rounds]
        t_adopted = max((float(str(r["t"])) for r in rounds if int(str(r["adopted"])) > 0),
                        default=float("nan"))
        done = _survivors_done(adopted, victim)
        c_adopted = adopted.coverage()
        best = survivors_reference(sc, len(sc.agents) - 1)
        row = {
            "bench": "adoption", "scenario": name, "agents": len(sc.agents),
            "landmarks": len(sc.landmark_ids), "victim": victim, "kill_at_s": kill_at,
            "drop": drop, "seed": seed, "lost_after_s": LOST_AFTER,
            "adoption_after_kill_s": round(t_adopted - t_kill, 2),
            "beyond_lost_after_s": round(t_adopted - t_kill - LOST_AFTER, 2),
            "complete_after_kill_s": round(adopted.net.now - t_kill, 2) if done else None,
            "rounds": len(rounds),
            "adopted": sum(rt.core.machine.adopted for rt in adopted.agents.values()),
            "violations": len(adopted.violations) + len(adopted.final_violations()),
            "coverage_full": round(c_full, 4), "coverage_orphaned": round(c_orphaned, 4),
            "coverage_adopted": round(c_adopted, 4),
            "recovered": round((c_adopted - c_orphaned) / (c_full - c_orphaned), 3)
            if c_full > c_orphaned else None,
            "relocations": sum(rt.core.planning.relocations for rt in adopted.agents.values()),
            "coverage_best_survivors": None if best is None else round(best, 4),
            "recovered_of_best": None if best is None or best <= c_orphaned else
            round((c_adopted - c_orphaned) / (best - c_orphaned), 3),
        }
        adopted.close()
        return row


def survivors_reference(sc: Scenario, n: int) -> float | None:
    """The best coverage score known for ``n`` drones on the scenario's landmarks (the quality
    benchmark's centralised multi-start reference; 3-D scenarios only, None otherwise)."""
    if sc.planar:
        return None
    s = Structure("scenario", "adoption", 0, sc.q, sc.u, environment_of(sc).boxes,
                  sc.space.lo, sc.space.hi)
    return float(reference(s, n, sc.d_opt, starts=6).score)


def cases(quick: bool = False) -> list[tuple[str, Scenario, str, float]]:
    """(name, scenario, victim, kill time [mission s]) of every case."""
    out = [("hexagon_5_3", load_scenario(ROOT / "scenarios" / "hexagon_5_3.toml"), "C", 2.0),
           ("cube_6_2", load_scenario(ROOT / "scenarios" / "cube_6_2.toml"), "B", 2.0)]
    if not quick:
        for n, m in ((4, 40), (8, 80)):
            sc = parse_scenario(swarm_scene_toml(n, m, seed=1), f"<swarm {n}x{m}>")
            out.append((f"swarm_{n}_{m}", sc, f"N{n - 1}", 3.0))
    return out


def run(out: TextIO | None = None, quick: bool = False) -> list[dict[str, Any]]:
    """Every case at 0 and 30 % loss; one JSON line each on ``out``."""
    rows = []
    for name, sc, victim, kill_at in cases(quick):
        for drop in (0.0, 0.3):
            row = adoption_case(name, sc, victim, kill_at, drop, seed=1)
            rows.append(row)
            if out is not None:
                out.write(json.dumps(row) + "\n")
                out.flush()
    return rows


def main(argv: list[str] | None = None) -> int:
    """``python -m bench.bench_adoption [--quick]``."""
    run(sys.stdout, quick="--quick" in (argv or sys.argv[1:]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
