"""One rule for how a flight towards a goal is doing (:class:`agent.world.environment.
TransitProgress`), the rule of the simulator's transits and flights and of the agents':
getting closer, or still turning closer to the goal's direction, is progress; anything else
for more than STALL_TICKS ticks gives the flight up."""

from __future__ import annotations

import math

from hypothesis import given
from hypothesis import strategies as st

from agent.world.environment import (
    ALIGNED_RAD,
    PROGRESS_M,
    STALL_TICKS,
    TURN_PROGRESS_RAD,
    TransitProgress,
)


def test_getting_closer_is_progress_and_circling_is_not() -> None:
    p = TransitProgress()
    for k in range(100):  # 5 cm a tick: always progress
        p.update(10.0 - 0.05 * k)
    assert p.stall == 0 and not p.stalled
    for k in range(STALL_TICKS + 1):  # sliding along another's safety radius, never closer
        assert not p.stalled
        p.update(5.05 + 0.004 * math.sin(k))
    assert p.stalled
    q = TransitProgress()
    for k in range(10 * STALL_TICKS):  # creeping 1 mm a tick is progress every 10 ticks
        q.update(5.0 - 0.001 * k)
    assert q.stall < 10


def test_a_kinematic_turn_is_progress_until_aligned() -> None:
    """A camera turning at ω_lim·Δt = 0.1 rad a tick from π, the drone not moving: progress
    every tick until the angle left is within ALIGNED_RAD, so a half turn never stalls."""
    p = TransitProgress()
    left = math.pi
    ticks = 0
    while left > ALIGNED_RAD:
        p.update(3.0, left)
        assert p.stall <= 1
        left = max(0.0, left - 0.1)
        ticks += 1
    assert ticks > STALL_TICKS and not p.stalled


def test_a_flown_camera_that_stops_turning_closer_stalls() -> None:
    """A flown camera's measured direction wobbles around 5 mrad off the goal: once the angle
    left no longer shrinks by TURN_PROGRESS_RAD the flight stalls (it would never end)."""
    p = TransitProgress()
    p.update(0.0, 0.2)
    p.update(0.0, 0.005)  # turned closer: progress
    for k in range(STALL_TICKS + 1):
        assert not p.stalled
        p.update(0.0, 0.005 + 0.0005 * (k % 3))
    assert p.stalled


@given(st.lists(st.tuples(st.floats(0.0, 50.0), st.floats(0.0, math.pi)), min_size=1,
                max_size=80))
def test_the_stall_count_is_the_ticks_since_the_last_progress(
        ticks: list[tuple[float, float]]) -> None:
    """Whatever the sequence: the count is the number of ticks since the last one that got
    PROGRESS_M closer than ever or turned TURN_PROGRESS_RAD closer than ever (the model)."""
    p = TransitProgress()
    best_m = best_rad = math.inf
    since = 0
    for dist, left in ticks:
        if dist < best_m - PROGRESS_M:
            best_m, since = dist, 0
        elif ALIGNED_RAD < left < best_rad - TURN_PROGRESS_RAD:
            since = 0
        else:
            since += 1
        best_rad = min(best_rad, left)
        p.update(dist, left)
        assert p.stall == since and p.stalled == (since > STALL_TICKS)
