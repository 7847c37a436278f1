"""Same decisions: the simulator and the agents on the quality benchmark's fixed starts.

For each (structure kind, team size n, start) of the held-out split, one JSON line per run:
the final score (eq. 3.10) of the simulator's run and of the agents', their ratio, the share of
landmarks that end with the same owner (``same_owner``) and the same share once the agents'
drones are renamed by the best one-to-one matching (``same_up_to_relabel``: the same parts,
held by other drones), the largest distance between a drone's final positions [m], and
whether both completed. One summary line per strategy: how many runs ended at exactly the
simulator's partition, the mean and worst share, the worst score ratio.

- ``thesis``: chapter 5's lockstep simulator (:func:`agent.sim.kinematic.simulate`, every
  drone in turn each Δt) against the agents (one :class:`~agent.runtime.shell.runtime.AgentRuntime`
  per drone on the in-memory network, virtual time, no loss): the thesis reproduced by the
  agents' asynchronous code.
- ``potential``: its only simulator is the agents' own code (``viscover simulate``: no loss);
  against it the same agents under ``--loss`` (default 30 %) of every message, whose
  retransmissions put their decisions in another order: the tolerance of asynchrony.

The agents decide from their peers' published states, which arrive one state period late
(later under loss) and in an order the lockstep ticks do not have, so two equally good moves
can be taken in another order; the tolerance is stated in the README next to these numbers.

Run: ``python -m bench.bench_decisions [--kinds box,pier] [--sizes 2,3,4] [--starts 2]
[--strategies thesis,potential] [--loss 0.3]``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Callable
from typing import Any, TextIO

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import linear_sum_assignment

from agent.strategy.registry import STRATEGIES, StrategyName, strategy_of
from bench.quality.runs import RunResult, run_strategy, run_thesis
from bench.quality.structures import KINDS, Scene, make_scene

SIZES = (2, 3, 4, 5, 6)
STARTS = 2
LOSS = 0.3  #: the agents' message loss against potential's simulator


def same_up_to_relabel(a: NDArray[np.intp], b: NDArray[np.intp], n: int) -> float:
    """Share of landmarks whose owners agree once the drones of ``b`` are renamed by the
    one-to-one matching that agrees most (the same partition, whoever holds each part)."""
    both = np.zeros((n, n), dtype=np.int64)
    np.add.at(both, (a, b), 1)
    rows, cols = linear_sum_assignment(-both)
    return float(both[rows, cols].sum()) / float(a.size)


def compare(scene: Scene, strategy: StrategyName, loss: float = LOSS) -> dict[str, Any]:
    """One scene, one strategy: the simulator's and the agents' outcomes side by side (see
    the module docstring; ``loss``: the agents' message loss against ``potential``'s
    simulator)."""
    sim_fn: Callable[[Scene], RunResult] = run_thesis if strategy == "thesis" else run_strategy
    t0 = time.perf_counter()
    sim = sim_fn(scene)
    t1 = time.perf_counter()
    lossy = strategy_of(strategy).extends_thesis
    ag = run_strategy(scene, drop=loss, seed=2) if lossy else run_strategy(scene, strategy)
    t2 = time.perf_counter()
    return {
        "bench": "same_decisions", "strategy": strategy, "scene": scene.name, "n": scene.n,
        "agents_loss": loss if lossy else 0.0,
        "score_sim": round(sim.score, 4), "score_agents": round(ag.score, 4),
        "ratio": round(ag.score / sim.score, 4) if sim.score > 0 else None,
        "same_owner": round(float(np.mean(sim.owner == ag.owner)), 4),
        "same_up_to_relabel": round(same_up_to_relabel(sim.owner, ag.owner, scene.n), 4),
        "max_pose_gap_m": round(float(np.linalg.norm(sim.P - ag.P, axis=1).max()), 3),
        "complete_sim": bool(sim.complete), "complete_agents": bool(ag.complete),
        "t_sim_s": round(sim.t, 1), "t_agents_s": round(ag.t, 1),
        "wall_sim_s": round(t1 - t0, 2), "wall_agents_s": round(t2 - t1, 2),
    }


def run(out: TextIO, kinds: tuple[str, ...] = KINDS, sizes: tuple[int, ...] = SIZES,
        starts: int = STARTS, strategies: tuple[StrategyName, ...] = STRATEGIES,
        loss: float = LOSS) -> list[dict[str, Any]]:
    """Every (kind, n, start, strategy) of the held-out split; a line each and a summary line
    per strategy."""
    rows: list[dict[str, Any]] = []
    for strategy in strategies:
        mine = []
        for kind in kinds:
            for n in sizes:
                for start in range(starts):
                    rec = compare(make_scene(kind, "heldout", start // 5, n, start), strategy,
                                  loss)
                    print(json.dumps(rec), file=out, flush=True)
                    mine.append(rec)
        same = [r["same_owner"] for r in mine]
        relabel = [r["same_up_to_relabel"] for r in mine]
        ratios = [r["ratio"] for r in mine if r["ratio"] is not None]
        summary = {"bench": "same_decisions_summary", "strategy": strategy, "runs": len(mine),
                   "identical_partition": sum(s == 1.0 for s in same),
                   "mean_same_owner": round(float(np.mean(same)), 4),
                   "worst_same_owner": min(same),
                   "identical_up_to_relabel": sum(s == 1.0 for s in relabel),
                   "worst_same_up_to_relabel": min(relabel),
                   "mean_ratio": round(float(np.mean(ratios)), 4),
                   "worst_ratio": min(ratios), "best_ratio": max(ratios),
                   "complete_agents": sum(r["complete_agents"] for r in mine)}
        print(json.dumps(summary), file=out, flush=True)
        rows.extend([*mine, summary])
    return rows


def main(argv: list[str] | None = None) -> int:
    """Command line: a selection of kinds, sizes, starts and strategies."""
    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument("--kinds", default=",".join(KINDS))
    ap.add_argument("--sizes", default=",".join(map(str, SIZES)))
    ap.add_argument("--starts", type=int, default=STARTS)
    ap.add_argument("--strategies", default=",".join(STRATEGIES))
    ap.add_argument("--loss", type=float, default=LOSS,
                    help="share of messages the agents lose against potential's simulator")
    a = ap.parse_args(argv)
    names = [next((s for s in STRATEGIES if s == x), None) for x in a.strategies.split(",")]
    if any(x is None for x in names):
        ap.error(f"--strategies: use names of {', '.join(STRATEGIES)}")
    run(sys.stdout, tuple(a.kinds.split(",")), tuple(int(x) for x in a.sizes.split(",")),
        a.starts, tuple(x for x in names if x is not None), a.loss)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
