"""The centralised offline plan the inspection is compared with: everything known before
take-off, one planner for the whole team. The fewest viewpoints of the capture table that
capture every capturable landmark (greedy set cover), shared among the drones so that the
longest open tour from their starts is short (min-max tours), flown at ṗ_lim in straight
lines. Straight lines ignore the structure in the way and the time to turn the camera, so
the plan's time is optimistic: a lower bar for the flown missions, not a feasible schedule."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from agent.core.inspection import CaptureTable
from agent.core.tours import greedy_cover, split_tours


@dataclass(frozen=True)
class OfflinePlan:
    """Viewpoints used, each drone's tour length [m] and the mission time [s]."""

    viewpoints: int
    lengths: list[float]
    time: float


def offline_plan(table: CaptureTable, starts: np.ndarray, speed: float) -> OfflinePlan:
    """Plan for drones at ``starts`` (n, 3) [m] flying at ``speed`` [m/s]."""
    rows, _ = greedy_cover(table.C, table.capturable, table.value)
    _, lengths = split_tours(starts, table.P[rows])
    return OfflinePlan(int(rows.size), [float(x) for x in lengths],
                       float(lengths.max(initial=0.0)) / speed)
