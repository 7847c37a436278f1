"""Run reports (agent.sim.report) on small hand-built results."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from agent.core.orientation import optimal_orientation
from agent.core.vision import vision
from agent.sim.report import RESULT_KEYS, vision_map, write_report
from agent.sim.result import SimResult, TradeEvent

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def _result(planar: bool) -> SimResult:
    """Two agents, three landmarks, five samples, one trade at t = 0.2 s."""
    t = np.arange(5, dtype=np.float64) * 0.1
    q = np.array([[1.0, 4.5, 0.0], [2.0, 4.1, 0.0], [2.5, 4.3, 0.0]])
    ang = np.array([-2 * np.pi / 3, -np.pi / 2, -np.pi / 4])
    u = np.stack([np.cos(ang), np.sin(ang), np.zeros(3)], axis=1)
    if not planar:
        q[:, 2] = 1.0
    start = np.array([[-1.0, 5.0, 0.0], [2.0, 1.0, 0.0]])
    step = np.array([[0.05, -0.1, 0.0], [0.0, 0.05, 0.0]])
    positions = start[None] + t[:, None, None] / 0.1 * step[None]
    directions = np.tile(np.array([[0.0, 1.0, 0.0], [0.0, 1.0, 0.0]]), (5, 1, 1))
    owners = np.array([[0, 0, 1]] * 2 + [[0, 1, 1]] * 3)
    inf = np.inf
    return SimResult(
        scenario="tiny", seed=4, planar=planar, agent_ids=["A", "B"], landmark_ids=[1, 2, 3],
        q=q, u=u,
        space_lo=np.array([-3.0, -inf, -inf]), space_hi=np.array([5.0, 6.0, inf]),
        d_opt=3.0, times=t, positions=positions, directions=directions,
        vision=np.column_stack([np.linspace(0.1, 0.5, 5), np.linspace(0.2, 0.3, 5)]),
        coverage=np.linspace(0.3, 0.8, 5), owners=owners,
        trades=[TradeEvent(0.2, "B", "A", [2], [], 0.1)],
        complete=True, t_complete=0.4,
    )


@pytest.mark.parametrize("planar", [True, False], ids=["2d", "3d"])
def test_write_report(tmp_path: Path, planar: bool) -> None:
    paths = write_report(_result(planar), tmp_path / "out")
    names = sorted(p.name for p in paths)
    assert names == ["coverage.png", "partition.png", "result.json", "trajectories.png"]
    for p in paths:
        assert p.exists()
        if p.suffix == ".png":
            assert p.read_bytes()[:8] == PNG_SIGNATURE
    doc = json.loads((tmp_path / "out" / "result.json").read_text())
    assert tuple(doc) == RESULT_KEYS
    assert doc["scenario"] == "tiny" and doc["seed"] == 4 and doc["planar"] is planar
    assert doc["agents"] == ["A", "B"] and doc["landmark_ids"] == [1, 2, 3]
    assert doc["space"] == {"lo": [-3.0, None, None], "hi": [5.0, 6.0, None]}
    assert doc["initial_partition"] == {"A": [1, 2], "B": [3]}
    assert doc["final_partition"] == {"A": [1], "B": [2, 3]}
    assert doc["coverage"][0] == [0.0, 0.3] and len(doc["coverage"]) == 5
    assert set(doc["vision"]) == {"A", "B"} and len(doc["vision"]["A"]) == 5
    assert doc["trades"] == [{"t": 0.2, "initiator": "B", "partner": "A", "to_partner": [2],
                              "to_initiator": [], "gain": 0.1}]
    assert doc["complete"] is True and doc["t_complete"] == 0.4
    assert doc["final_poses"]["B"]["direction"] == [0.0, 1.0, 0.0]
    checks = doc["checks"]
    # A, left of landmark 1 and looking north, does not see it; B sees 2 and 3.
    assert set(checks) == {"all_visible_to_owner", "not_visible", "min_pairwise_distance",
                           "stayed_inside_space", "max_outside_space"}
    assert checks["not_visible"] == [1] and checks["all_visible_to_owner"] is False
    d0 = np.linalg.norm(np.array([-1.0, 5.0]) - np.array([2.0, 1.0]))
    assert checks["min_pairwise_distance"] < d0
    assert checks["stayed_inside_space"] is True


def test_report_without_plots_and_outside_space(tmp_path: Path) -> None:
    r = _result(True)
    r.positions[-1, 0, 0] = -3.5  # half a metre beyond the wall x = -3
    paths = write_report(r, tmp_path, plots=False)
    assert [p.name for p in paths] == ["result.json"]
    checks = json.loads(paths[0].read_text())["checks"]
    assert checks["stayed_inside_space"] is False
    assert checks["max_outside_space"] == pytest.approx(0.5)


def test_single_agent_has_no_pairwise_distance(tmp_path: Path) -> None:
    r = _result(True)
    r.agent_ids = ["A"]
    r.positions, r.directions = r.positions[:, :1], r.directions[:, :1]
    r.vision, r.owners, r.trades = r.vision[:, :1], np.zeros_like(r.owners), []
    doc = json.loads(write_report(r, tmp_path, plots=False)[0].read_text())
    assert doc["checks"]["min_pairwise_distance"] is None


@pytest.mark.parametrize("m", [3, 8])
def test_vision_map_matches_algorithm_1(m: int) -> None:
    rng = np.random.default_rng(m)
    ang = rng.uniform(-np.pi, np.pi, m)
    u = np.stack([np.cos(ang), np.sin(ang), np.zeros(m)], axis=1)
    q = np.column_stack([rng.uniform(-1, 1, (m, 2)), np.zeros(m)])
    xs, ys = np.linspace(-3, 3, 7), np.linspace(-2, 2, 5)
    vm = vision_map(xs, ys, q, u, 1.5)
    assert vm.shape == (5, 7)
    for iy, ix in [(0, 0), (2, 3), (4, 6), (1, 5)]:
        p = np.array([xs[ix], ys[iy], 0.0])
        v = optimal_orientation(p, q, u, 1.5)
        exact = vision(p, v, q, u, 1.5) if v.any() else 0.0
        assert vm[iy, ix] == pytest.approx(exact, rel=2e-3, abs=1e-12)
