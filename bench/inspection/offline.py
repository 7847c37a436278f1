"""The centralised offline plan the inspection is compared with: everything known before
take-off, one planner for the whole team. The fewest viewpoints of the capture table that
capture every capturable landmark (greedy set cover), shared among the drones so that the
longest open tour from their starts is short (min-max tours), flown at ṗ_lim in straight
lines. Straight lines ignore the structure in the way and the time to turn the camera, so
the plan's time is optimistic: a lower bar for the flown missions, not a feasible schedule.
``time_home`` adds each drone's flight back to its start, to compare with a mission's time
until every drone is home."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from agent.core.inspection import CaptureTable
from agent.core.tours import greedy_cover, order_tour, split_tours


@dataclass(frozen=True)
class OfflinePlan:
    """Viewpoints used, each drone's tour length [m] and the mission time [s]."""

    viewpoints: int
    lengths: list[float]
    time: float
    time_home: float  #: the same tours flown back to each drone's start [s]


def offline_plan(table: CaptureTable, starts: np.ndarray, speed: float) -> OfflinePlan:
    """Plan for drones at ``starts`` (n, 3) [m] flying at ``speed`` [m/s]."""
    rows, _ = greedy_cover(table.C, table.capturable, table.value)
    pts = table.P[rows]
    label, lengths = split_tours(starts, pts)
    home = lengths.copy()
    for i in range(starts.shape[0]):  # one drone at a time: its tour's way back
        members = np.flatnonzero(label == i)
        if members.size:
            last = pts[members[order_tour(starts[i], pts[members])][-1]]
            home[i] += float(np.linalg.norm(last - starts[i]))
    return OfflinePlan(int(rows.size), [float(x) for x in lengths],
                       float(lengths.max(initial=0.0)) / speed,
                       float(home.max(initial=0.0)) / speed)
