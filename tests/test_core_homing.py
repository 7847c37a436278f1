"""Return to the launch point (agent.core.homing): arrival, separation and walls over whole runs."""

from __future__ import annotations

import math

import numpy as np
import pytest

from agent.core.avoidance import MissionSpace
from agent.core.homing import homing_velocity
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
def test_agents_crossing_to_the_far_side_keep_r_s(mode: str, planar: bool) -> None:
    """Five agents on a circle fly to the diametrically opposite point (every path crosses
    the centre): nobody comes closer than R_s, nobody leaves Ω, everybody arrives."""
    n, radius = 5, 4.0
    params = PlannerParams(dt=0.1, p_lim=0.5, r_s=1.0, d_w=0.5, avoidance=mode,  # type: ignore[arg-type]
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
def test_the_way_home_goes_round_the_structure(mode: str, planar: bool) -> None:
    """Two agents each on the far side of a box from their targets, at the box's height:
    both arrive, keeping R_s from each other and R_s/2 from the box up to s²/(2 R_s) (a step
    s that keeps clear of the sphere behind the box's nearest point may cut that much into
    a face's layer; the next step cannot go deeper)."""
    params = PlannerParams(dt=0.1, p_lim=0.5, r_s=1.0, d_w=0.5, avoidance=mode,  # type: ignore[arg-type]
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
