"""Coverage quality: the thesis strategy and the coverage-move strategy against a centralised
reference, on seeded structures (box, L-shaped building, pier, bridge deck on columns).

For every split (tuning / held-out), structure kind and team size n, ``starts`` random starts
(random poses and random initial partitions; structure ``start // 5`` of the split, so two
structures per 10 starts) are simulated with both strategies:

- ``thesis``: gradient ascent + Algorithm 7 (:func:`agent.sim.kinematic.simulate`);
- ``potential``: the same plus the coverage moves judged on potential vision
  (:mod:`agent.core.coverage_moves`), as the agents make them: one
  :class:`~agent.runtime.shell.runtime.AgentRuntime` per drone in memory,
  :mod:`agent.runtime.moves.coverage`
  and :mod:`agent.runtime.moves.revert` (relocations, pair, triple and team re-splits, the revert;
  :mod:`bench.quality.runs`).

The reference (:mod:`bench.quality.reference`) is a multi-start joint optimisation of all n
poses with best-view ownership. Per cell one JSON line: mean and worst ratio of the final
score (eq. 3.10) to the reference, landmarks left unseen by their owner (``unseen``), how
many more than the reference leaves unseen (vision < 0.05; ``unseen_excess``), those another
drone sees at its final pose (``unseen_visible_to_other``), how often ``potential``
ended below ``thesis`` from the same start, and the mean simulated time to completion.
One summary line per split and strategy.

Run: ``python -m bench.bench_quality [--quick] [--kinds box,pier] [--splits heldout]
[--sizes 2,4] [--starts 10]``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Callable
from typing import Any, TextIO

import numpy as np

from agent.core.viewpoints import vision_matrix
from bench.quality.reference import Reference, reference
from bench.quality.runs import STRATEGY, RunResult, run_strategy, run_thesis
from bench.quality.structures import KINDS, SPLITS, Scene, make_scene, make_structure

SIZES = (2, 3, 4, 5, 6, 8)
STARTS = 10
#: ``--quick``: one held-out start per kind with 3 drones (about 15 s).
QUICK_SIZES, QUICK_SPLITS, QUICK_STARTS = (3,), ("heldout",), 1
#: ``potential`` below ``thesis`` counts beyond this relative margin: asynchronous agents end
#: their thesis stage within ~1e-6 of the simulator's optimum (when convergence is declared
#: depends on timing), which is not a loss of coverage.
AGENTS_TOL = 1e-4
#: A landmark counts as seen by the reference with at least this vision (eq. 3.1; 1 is a
#: head-on view at d_opt).
SEEABLE = 0.05


def _emit(out: TextIO, rec: dict[str, Any]) -> None:
    out.write(json.dumps(rec) + "\n")
    out.flush()


def unseen_counts(scene: Scene, r: RunResult, ref: Reference) -> tuple[int, int, int]:
    """Landmarks whose owner sees nothing of them (eq. 3.1 = 0): in all, how many more than
    the reference leaves below :data:`SEEABLE` (n drones cannot always see everything; the
    count, not the identity, is compared because symmetric optima see different landmarks),
    and those another drone sees at its final pose."""
    s = scene.structure
    M = vision_matrix(r.P, r.V, s.q, s.u, scene.d_opt)  # (n, m)
    own = M[r.owner, np.arange(s.q.shape[0])]
    unseen = own <= 0.0
    ref_unseen = vision_matrix(ref.P, ref.V, s.q, s.u, scene.d_opt).max(axis=0) < SEEABLE
    return (int(unseen.sum()), max(0, int(unseen.sum()) - int(ref_unseen.sum())),
            int((unseen & (M.max(axis=0) > 0.0)).sum()))


def _cell(split: str, kind: str, n: int, starts: int) -> list[dict[str, Any]]:
    """All runs of one (split, kind, n) cell, both strategies, as records."""
    refs: dict[int, Reference] = {}
    rows: dict[str, list[dict[str, float]]] = {"thesis": [], STRATEGY: []}
    runs: list[tuple[str, Callable[[Scene], RunResult]]] = [("thesis", run_thesis),
                                                            (STRATEGY, run_strategy)]
    below = 0
    t_ref = 0.0
    for start in range(starts):
        index = start // 5
        if index not in refs:
            t0 = time.perf_counter()
            refs[index] = reference(make_structure(kind, split, index), n, make_scene(
                kind, split, index, n, 0).d_opt)
            t_ref += time.perf_counter() - t0
        ref = refs[index]
        scene = make_scene(kind, split, index, n, start)
        scores = {}
        for name, fn in runs:
            t0 = time.perf_counter()
            r = fn(scene)
            wall = time.perf_counter() - t0
            unseen, excess, visible = unseen_counts(scene, r, ref)
            scores[name] = r.score
            rows[name].append({"ratio": r.score / ref.score, "unseen": unseen,
                               "unseen_excess": excess,
                               "unseen_visible_to_other": visible, "t_sim": r.t,
                               "complete": float(r.complete), "wall": wall})
        below += int(scores[STRATEGY] < scores["thesis"] * (1.0 - AGENTS_TOL))
    out = []
    for name, rs in rows.items():
        ratios = np.array([x["ratio"] for x in rs])
        out.append({
            "bench": "coverage_quality", "split": split, "structure": kind, "n": n,
            "strategy": name, "starts": starts, "structures": len(refs),
            "mean_ratio": round(float(ratios.mean()), 4),
            "worst_ratio": round(float(ratios.min()), 4),
            "runs_below_95pct": int((ratios < 0.95).sum()),
            "unseen_total": int(sum(x["unseen"] for x in rs)),
            "unseen_excess_total": int(sum(x["unseen_excess"] for x in rs)),
            "unseen_excess_max": int(max(x["unseen_excess"] for x in rs)),
            "unseen_visible_to_other_total": int(sum(x["unseen_visible_to_other"] for x in rs)),
            "complete": int(sum(x["complete"] for x in rs)),
            "mean_t_sim_s": round(float(np.mean([x["t_sim"] for x in rs])), 1),
            "mean_wall_s": round(float(np.mean([x["wall"] for x in rs])), 2),
            "reference_wall_s": round(t_ref / len(refs), 2),
            **({"runs_below_thesis": below} if name == STRATEGY else {}),
        })
    return out


def run(out: TextIO | None = None, quick: bool = False, kinds: tuple[str, ...] = KINDS,
        splits: tuple[str, ...] = SPLITS, sizes: tuple[int, ...] = SIZES,
        starts: int = STARTS) -> list[dict[str, Any]]:
    """Benchmark both strategies against the reference; print and return JSON records."""
    out = out or sys.stdout
    if quick:
        splits, sizes, starts = QUICK_SPLITS, QUICK_SIZES, QUICK_STARTS
    records: list[dict[str, Any]] = []
    for split in splits:
        cells = []
        for kind in kinds:
            for n in sizes:
                for rec in _cell(split, kind, n, starts):
                    _emit(out, rec)
                    cells.append(rec)
        for name in ("thesis", STRATEGY):
            mine = [c for c in cells if c["strategy"] == name]
            if not mine:
                continue
            rec = {"bench": "coverage_quality_summary", "split": split, "strategy": name,
                   "cells": len(mine), "runs": sum(c["starts"] for c in mine),
                   "mean_ratio": round(float(np.mean([c["mean_ratio"] for c in mine])), 4),
                   "worst_ratio": min(c["worst_ratio"] for c in mine),
                   "runs_below_95pct": sum(c["runs_below_95pct"] for c in mine),
                   "unseen_excess_total": sum(c["unseen_excess_total"] for c in mine),
                   "unseen_visible_to_other_total": sum(
                       c["unseen_visible_to_other_total"] for c in mine)}
            if name == STRATEGY:
                rec["runs_below_thesis"] = sum(c["runs_below_thesis"] for c in mine)
            _emit(out, rec)
            cells.append(rec)
        records.extend(cells)
    return records


def main(argv: list[str] | None = None) -> int:
    """Command line: ``--quick`` or a selection of kinds, splits, sizes and starts."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--kinds", default=",".join(KINDS))
    ap.add_argument("--splits", default=",".join(SPLITS))
    ap.add_argument("--sizes", default=",".join(map(str, SIZES)))
    ap.add_argument("--starts", type=int, default=STARTS)
    a = ap.parse_args(argv)
    run(sys.stdout, quick=a.quick, kinds=tuple(a.kinds.split(",")),
        splits=tuple(a.splits.split(",")), sizes=tuple(int(x) for x in a.sizes.split(",")),
        starts=a.starts)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
