"""Return to the launch point (agent.core.homing): arrival, separation and walls over whole runs."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from agent.core.avoidance import AvoidanceMode, MissionSpace
from agent.core.homing import detour_waypoints, homing_velocity
from agent.core.planner import PlannerParams


def fly_home(starts: np.ndarray, targets: np.ndarray, params: PlannerParams,
             space: MissionSpace, max_steps: int) -> tuple[np.ndarray, float, int]:
    """Agents take turns (asynchronous, as in chapter 5), each one Δt of homing per round.
    Returns final positions, the smallest pairwise distance seen and the rounds used."""
    p = starts.astype(np.float64).copy()
    n = p.shape[0]
    d_min = math.inf
    for k in range(max_steps):
        moved = False
        for i in range(n):
            others = np.delete(p, i, axis=0)
            vel = homing_velocity(p[i], targets[i], params, space, others)
            assert np.linalg.norm(vel) <= params.p_lim + 1e-12
            if np.any(vel):
                p[i] = p[i] + vel * params.dt
                moved = True
            assert space.contains(p[i], tol=1e-9), (k, i, p[i])
            if n > 1:
                d_min = min(d_min, float(np.linalg.norm(others - p[i], axis=1).min()))
        if not moved:
            return p, d_min, k
    return p, d_min, max_steps


def test_unobstructed_flight_is_straight_and_arrives() -> None:
    rng = np.random.default_rng(7)
    params = PlannerParams(dt=0.1, p_lim=0.5)
    for _ in range(50):
        start, target = rng.uniform(-5, 5, 3), rng.uniform(-5, 5, 3)
        p = start.copy()
        dist0 = float(np.linalg.norm(target - start))
        steps = 0
        while np.any(vel := homing_velocity(p, target, params)):
            # Straight: every step points at the target, and the distance only falls.
            to = target - p
            assert np.dot(vel, to) == pytest.approx(np.linalg.norm(vel) * np.linalg.norm(to))
            p = p + vel * params.dt
            steps += 1
        assert np.linalg.norm(target - p) <= params.p_min * params.dt + 1e-12
        assert steps <= math.ceil(dist0 / (params.p_lim * params.dt)) + 1


@pytest.mark.parametrize("mode", ["abrupt", "smooth"])
@pytest.mark.parametrize("planar", [False, True])
def test_agents_crossing_to_the_far_side_keep_r_s(mode: AvoidanceMode, planar: bool) -> None:
    """Five agents on a circle fly to the diametrically opposite point (every path crosses
    the centre): nobody comes closer than R_s, nobody leaves Ω, everybody arrives."""
    n, radius = 5, 4.0
    params = PlannerParams(dt=0.1, p_lim=0.5, r_s=1.0, d_w=0.5, avoidance=mode,
                           planar=planar)
    space = MissionSpace(np.array([-6.0, -6.0, 0.0]), np.array([6.0, 6.0, 6.0]))
    a = 2 * np.pi * np.arange(n) / n
    z = np.full(n, 2.0) if planar else 2.0 + 0.3 * np.arange(n)
    starts = np.stack([radius * np.cos(a), radius * np.sin(a), z], axis=1)
    targets = np.stack([-starts[:, 0], -starts[:, 1], z[::-1]], axis=1)
    if planar:
        targets[:, 2] = z
    final, d_min, rounds = fly_home(starts, targets, params, space, max_steps=3000)
    assert d_min >= params.r_s - 1e-9
    gap = np.linalg.norm((final - targets)[:, :2] if planar else final - targets, axis=1)
    assert gap.max() <= 0.05, (gap, rounds)


def test_a_target_beyond_a_wall_stops_at_the_wall() -> None:
    params = PlannerParams(dt=0.1, p_lim=0.5)
    space = MissionSpace(np.array([0.0, 0.0, 0.0]), np.array([4.0, 4.0, 4.0]))
    final, _d, _k = fly_home(np.array([[2.0, 2.0, 2.0]]), np.array([[9.0, 2.0, 2.0]]),
                             params, space, max_steps=500)
    assert final[0, 0] == pytest.approx(4.0, abs=1e-6) and space.contains(final[0])


def spots(rng: np.random.Generator, n: int, planar: bool) -> np.ndarray:
    """``n`` random points of the test space, pairwise more than 1.2 m (> R_s) apart."""
    while True:
        x = rng.uniform([-5.0, -5.0, 0.5], [5.0, 5.0, 5.5], (n, 3))
        if planar:
            x[:, 2] = 2.0
        gaps = np.linalg.norm(x[:, None] - x[None], axis=2) + 9.0 * np.eye(n)
        if gaps.min() > 1.2:
            return x


@pytest.mark.parametrize("seed", range(4))
def test_random_crowds_arrive_without_breaking_r_s(seed: int) -> None:
    """2-6 agents, random starts and targets (R_s apart), both modes, 2-D and 3-D."""
    rng = np.random.default_rng(seed)
    space = MissionSpace(np.array([-6.0, -6.0, 0.0]), np.array([6.0, 6.0, 6.0]))
    for trial in range(10):
        n = int(rng.integers(2, 7))
        planar = trial % 3 == 0
        params = PlannerParams(dt=0.1, p_lim=0.5, r_s=1.0, d_w=0.5, planar=planar,
                               avoidance="abrupt" if trial % 2 else "smooth")

        starts, targets = spots(rng, n, planar), spots(rng, n, planar)
        final, d_min, _k = fly_home(starts, targets, params, space, max_steps=4000)
        assert d_min >= params.r_s - 1e-9
        gap = final - targets
        if planar:
            gap[:, 2] = 0.0
        assert np.linalg.norm(gap, axis=1).max() <= 0.05, (seed, trial)


@pytest.mark.parametrize("mode", ["abrupt", "smooth"])
@pytest.mark.parametrize("planar", [False, True])
def test_the_way_home_goes_round_the_structure(mode: AvoidanceMode, planar: bool) -> None:
    """Two agents each on the far side of a box from their targets, at the box's height:
    both arrive, keeping R_s from each other and R_s/2 from the box up to s²/(2 R_s) (a step
    s that keeps clear of the sphere behind the box's nearest point may cut that much into
    a face's layer; the next step cannot go deeper)."""
    params = PlannerParams(dt=0.1, p_lim=0.5, r_s=1.0, d_w=0.5, avoidance=mode,
                           planar=planar)
    space = MissionSpace(np.array([-8.0, -8.0, 0.0]), np.array([8.0, 8.0, 8.0]))
    box = (np.array([-1.0, -1.0, 0.0]), np.array([1.0, 1.0, 3.0]))
    p = np.array([[-3.0, 0.1, 2.0], [3.0, -0.2, 2.5]])
    targets = np.array([[3.5, 0.0, 2.0], [-3.5, 0.3, 2.5]])
    d_box = math.inf
    for _ in range(4000):
        moved = False
        for i in range(2):
            vel = homing_velocity(p[i], targets[i], params, space, p[[1 - i]], structure=box)
            if np.any(vel):
                p[i] = p[i] + vel * params.dt
                moved = True
            nearest = np.clip(p[i], *box)
            d_box = min(d_box, float(np.linalg.norm((p[i] - nearest)[:2] if planar
                                                    else p[i] - nearest)))
            assert np.linalg.norm(p[0] - p[1]) >= params.r_s - 1e-9
        if not moved:
            break
    step = params.p_lim * params.dt
    assert d_box >= params.r_s / 2 - step * step / (2 * params.r_s) - 1e-9
    assert np.linalg.norm((p - targets)[:, :2], axis=1).max() <= 0.05


def test_no_turn_when_the_obstacle_is_not_ahead() -> None:
    """The cube mission's A, 0.1 m from its target with the structure 1 m behind it: the
    velocity points straight at the target (a turn there made a flown drone orbit it)."""
    params = PlannerParams(dt=0.1, p_lim=0.3, r_s=1.5, d_w=0.5)
    box = (np.array([-0.25, -0.25, 0.75]), np.array([0.25, 0.25, 1.25]))
    p, target = np.array([-0.9, -0.95, 1.0]), np.array([-1.0, -1.0, 1.0])
    vel = homing_velocity(p, target, params, structure=box)
    to = target - p
    assert np.dot(vel, to) == pytest.approx(np.linalg.norm(vel) * np.linalg.norm(to))


def test_a_drone_pressed_against_a_long_face_goes_round_it_by_the_detour() -> None:
    """A flown L-shape mission ended with a drone R_s/2 off the long face of the structure's
    box and its launch point diagonally beyond: homing alone dithers there for ever (the
    virtual agent slides with the nearest point); over the detour's corners it arrives, never
    nearer the box than R_s/2 up to s²/(2 R_s)."""
    params = PlannerParams(dt=0.1, p_lim=0.3, r_s=1.0, d_w=0.5)
    space = MissionSpace(np.array([-7.8, -6.2, 0.3]), np.array([7.8, 10.6, 7.3]))
    box = (np.array([-2.78, -1.19, 0.96]), np.array([2.78, 5.63, 3.84]))
    start = np.array([2.78 + 0.5, 4.52, 1.96])
    target = np.array([-7.37, -6.15, 1.96])
    alone = start.copy()
    for _ in range(2000):  # 200 s of homing alone
        alone = alone + homing_velocity(alone, target, params, space, None, box) * params.dt
    assert np.linalg.norm(alone[:2] - target[:2]) > 5.0  # stuck by the face
    route = detour_waypoints(start, target, box, 0.5 * params.r_s, 0.5 * params.r_s + 0.5)
    assert route.shape[0] >= 2 and np.array_equal(route[-1], target)
    p, d_box, steps = start.copy(), math.inf, 0
    for w in route:
        while np.linalg.norm((w - p)[:2]) > 0.05 and steps < 4000:
            p = p + homing_velocity(p, w, params, space, None, structure=box) * params.dt
            d_box = min(d_box, float(np.linalg.norm(p - np.clip(p, *box))))
            steps += 1
    step = params.p_lim * params.dt
    assert np.linalg.norm((p - target)[:2]) <= 0.05, (p, steps)
    assert d_box >= params.r_s / 2 - step * step / (2 * params.r_s) - 1e-9


@pytest.mark.parametrize("seed", range(3))
def test_the_detour_is_the_shortest_way_that_keeps_out_of_the_layer(seed: int) -> None:
    """Random starts and targets round a box: with the straight way clear the route is just
    the target; otherwise no leg enters the kept layer (sampled densely) and the route is no
    longer than either way round over the box's inflated corners."""
    rng = np.random.default_rng(seed)
    box = (np.array([-2.0, -1.0, 0.0]), np.array([2.0, 1.0, 3.0]))
    keep, corner = 0.5, 1.0
    lo, hi = box[0][:2] - keep + 0.05, box[1][:2] + keep - 0.05
    detoured = 0
    for _ in range(60):
        a = rng.uniform([-6.0, -6.0, 1.0], [6.0, 6.0, 3.0])
        b = rng.uniform([-6.0, -6.0, 1.0], [6.0, 6.0, 3.0])
        if any(np.all(x[:2] > lo) and np.all(x[:2] < hi) for x in (a, b)):
            continue
        route = detour_waypoints(a, b, box, keep, corner)
        legs = np.vstack([a, route])
        s = np.linspace(0.0, 1.0, 400)[:, None]
        pts = np.vstack([x + s * (y - x) for x, y in itertools.pairwise(legs)])
        inside = np.all((pts[:, :2] > lo + 1e-6) & (pts[:, :2] < hi - 1e-6), axis=1)
        assert not inside.any()
        if route.shape[0] == 1:
            continue
        detoured += 1
        length = np.linalg.norm(np.diff(legs[:, :2], axis=0), axis=1).sum()
        c_lo, c_hi = box[0][:2] - corner, box[1][:2] + corner
        ring = np.array([[c_lo[0], c_lo[1]], [c_hi[0], c_lo[1]], [c_hi[0], c_hi[1]],
                         [c_lo[0], c_hi[1]]])
        # Either way round the ring from the corner nearest a to the one nearest b bounds it.
        i = int(np.argmin(np.linalg.norm(ring - a[:2], axis=1)))
        j = int(np.argmin(np.linalg.norm(ring - b[:2], axis=1)))
        ways = []
        for step in (1, -1):
            k, way = i, [a[:2], ring[i]]
            while k != j:
                k = (k + step) % 4
                way.append(ring[k])
            way.append(b[:2])
            ways.append(np.linalg.norm(np.diff(np.array(way), axis=0), axis=1).sum())
        assert length <= max(ways) + 1e-9
    assert detoured >= 10
