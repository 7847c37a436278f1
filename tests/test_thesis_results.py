"""The thesis' chapter 5 and section 6.2 results, reproduced by the kinematic simulator on the
shipped scenario files (scenarios/*.toml), plus Proposition 4 over whole runs."""

from __future__ import annotations

from functools import cache
from pathlib import Path

import numpy as np
import pytest

from agent.config.parse import load_scenario
from agent.config.scenario import Scenario
from agent.core.vision import per_landmark
from agent.sim.kinematic import simulate
from agent.sim.result import SimResult

SCENARIOS = Path(__file__).resolve().parent.parent / "scenarios"


@cache
def run(name: str) -> tuple[Scenario, SimResult]:
    """Simulate a shipped scenario once per test session."""
    sc = load_scenario(SCENARIOS / f"{name}.toml")
    return sc, simulate(sc)


def owner_visions(sc: Scenario, res: SimResult) -> np.ndarray:
    """Final vision of every landmark by its owner (m,)."""
    out = np.zeros(sc.q.shape[0])
    own = res.final_owner
    for i in range(len(sc.agents)):
        mine = own == i
        out[mine] = per_landmark(res.positions[-1, i], res.directions[-1, i], sc.q[mine],
                                 sc.u[mine], sc.d_opt)
    return out


def min_pair_distance(res: SimResult, planar: bool) -> float:
    """Smallest distance between two agents over the whole run [m]."""
    pos = res.positions.copy()
    if planar:
        pos[..., 2] = 0.0
    n = pos.shape[1]
    if n < 2:
        return np.inf
    i, j = np.triu_indices(n, k=1)
    return float(np.linalg.norm(pos[:, i] - pos[:, j], axis=-1).min())


ALL = ["free_5_1", "bounded_5_2_abrupt", "bounded_5_2_smooth", "oscillation_5_2",
       "oscillation_5_2_fixed", "two_agents_5_2", "hexagon_5_3", "cube_6_2"]


@pytest.mark.parametrize("name", ALL)
def test_proposition_4_coverage_never_decreases(name: str) -> None:
    """Eq. 4.15 over the whole run: planner steps and trades only increase the coverage."""
    _, res = run(name)
    assert np.all(np.diff(res.coverage) >= -1e-12)
    for i in range(res.vision.shape[1]):  # Proposition 3 between trades, per agent
        own = res.owners
        same = np.all(own[1:] == own[:-1], axis=1)
        assert np.all(np.diff(res.vision[:, i])[same] >= -1e-12)


@pytest.mark.parametrize("name", ALL)
def test_runs_end_converged_inside_the_mission_space(name: str) -> None:
    sc, res = run(name)
    assert res.complete, f"{name} did not converge within {sc.duration} s"
    lo, hi = sc.space.lo, sc.space.hi
    assert np.all(res.positions >= lo - 1e-9) and np.all(res.positions <= hi + 1e-9)
    assert min_pair_distance(res, sc.planar) >= sc.params.r_s - 1e-9


def test_5_1_converges_to_the_maximum_of_the_vision_map() -> None:
    """Section 5.1: the single camera ends where no nearby position sees better."""
    sc, res = run("free_5_1")
    p, v = res.positions[-1, 0], res.directions[-1, 0]
    best = res.coverage[-1]
    # The vision map v(p) = max over orientations; sample orientations densely on the circle.
    psi = np.linspace(-np.pi, np.pi, 3601)
    dirs = np.column_stack([np.cos(psi), np.sin(psi), np.zeros_like(psi)])
    offsets = 0.05 * np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0],
                               [1, 1, 0], [1, -1, 0], [-1, 1, 0], [-1, -1, 0]], float)
    for off in offsets:
        around = max(float(per_landmark(p + off, d, sc.q, sc.u, sc.d_opt).sum()) for d in dirs)
        assert around <= best + 1e-3
    assert best >= max(float(per_landmark(p, d, sc.q, sc.u, sc.d_opt).sum()) for d in dirs) - 1e-3
    assert np.linalg.norm(v) == pytest.approx(1.0)


def test_5_2_bounded_never_leaves_and_both_modes_end_at_the_same_point() -> None:
    sc_a, abrupt = run("bounded_5_2_abrupt")
    _, smooth = run("bounded_5_2_smooth")
    for res in (abrupt, smooth):
        assert np.all(res.positions[..., :2] >= sc_a.space.lo[:2] - 1e-9)
        assert np.all(res.positions[..., :2] <= sc_a.space.hi[:2] + 1e-9)
    # The free-space maximum is outside Ω: both stop on the wall, at the same point.
    assert abrupt.positions[-1, 0, 1] == pytest.approx(sc_a.space.lo[1], abs=1e-3)
    gap = np.linalg.norm(abrupt.positions[-1, 0] - smooth.positions[-1, 0])
    assert gap < 0.02, f"abrupt and smooth end {gap:.3f} m apart"
    # Abrupt reaches the wall and slides; smooth starts turning D_w before it.
    y_lo = sc_a.space.lo[1]
    d_w = sc_a.params.d_w

    def first_deflection(res: SimResult) -> float:
        y = res.positions[:, 0, 1] - y_lo
        moving = np.linalg.norm(np.diff(res.positions[:, 0], axis=0), axis=1) > 0
        return float(y[:-1][moving].min()) if moving.any() else np.inf
    assert first_deflection(smooth) <= first_deflection(abrupt) + d_w


def test_5_2_two_agents_never_closer_than_the_safety_radius() -> None:
    sc, res = run("two_agents_5_2")
    assert min_pair_distance(res, planar=True) >= sc.params.r_s - 1e-9
    vis = owner_visions(sc, res)
    assert np.all(vis > 0.0)


def _immediate_reversals(res: SimResult) -> int:
    """Pairs of consecutive steps, both moving, whose directions differ by more than 90°."""
    step = np.diff(res.positions[:, 0, :2], axis=0)
    norm = np.linalg.norm(step, axis=1)
    both = (norm[1:] > 1e-12) & (norm[:-1] > 1e-12)
    return int(np.sum(np.einsum("ij,ij->i", step[1:], step[:-1])[both] < 0.0))


def test_5_2_oscillation_and_the_lambda_dir_fix() -> None:
    """Figure 5.8: near-perpendicular p_opt makes the direction flip from one step to the next;
    with λ_dir (figure 5.9) a sweep keeps its direction until the magnitude control stops it."""
    sc_fix, fixed = run("oscillation_5_2_fixed")
    _, osc = run("oscillation_5_2")
    assert _immediate_reversals(osc) > 20, "the oscillation of figure 5.8 did not appear"
    assert _immediate_reversals(fixed) == 0
    # Between consecutive moving steps the turn is at most acos(λ_dir).
    step = np.diff(fixed.positions[:, 0, :2], axis=0)
    norm = np.linalg.norm(step, axis=1)
    both = (norm[1:] > 1e-12) & (norm[:-1] > 1e-12)
    cosines = np.einsum("ij,ij->i", step[1:], step[:-1])[both] / (norm[1:] * norm[:-1])[both]
    assert sc_fix.params.lambda_dir is not None
    assert np.all(cosines >= sc_fix.params.lambda_dir - 1e-9)
    # Both end on the wall near the same constrained maximum.
    assert np.linalg.norm(fixed.positions[-1, 0] - osc.positions[-1, 0]) < 0.1
    assert fixed.coverage[-1] == pytest.approx(osc.coverage[-1], rel=1e-3)


def test_5_3_reproduces_the_three_trades() -> None:
    """Section 5.3: landmark 2 goes to A, 5 to B, 6 to C, in that order, and no other trade."""
    sc, res = run("hexagon_5_3")
    moved = []
    for t in res.trades:
        for lid in t.to_partner:
            moved.append((lid, t.partner))
        for lid in t.to_initiator:
            moved.append((lid, t.initiator))
    assert moved == [(2, "A"), (5, "B"), (6, "C")]
    assert np.all(owner_visions(sc, res) > 0.0)
    assert all(t.gain > 0 for t in res.trades)


def test_6_2_cube_every_landmark_visible_to_its_owner() -> None:
    sc, res = run("cube_6_2")
    assert np.all(owner_visions(sc, res) > 0.0)
    # Figure 6.3: the agent above the cube looks down at the top face.
    top = np.flatnonzero(sc.u[:, 2] > 0.9)
    owner_of_top = set(res.final_owner[top].tolist())
    assert len(owner_of_top) == 1
    i = owner_of_top.pop()
    assert res.directions[-1, i, 2] < -0.9


def test_simulation_is_deterministic() -> None:
    """Same scenario, same seed: the very same run, bit for bit."""
    sc = load_scenario(SCENARIOS / "hexagon_5_3.toml")
    a, b = simulate(sc), simulate(sc)
    np.testing.assert_array_equal(a.positions, b.positions)
    np.testing.assert_array_equal(a.directions, b.directions)
    np.testing.assert_array_equal(a.owners, b.owners)
    assert a.trades == b.trades
