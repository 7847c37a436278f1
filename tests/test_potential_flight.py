"""``strategy = "potential"`` flown: simulated quadrotors over MAVLink (``viscover launch
--flight``: ground station, mocap, set-points, one flying agent per drone) on the quality
benchmark's L-shaped start where the thesis leaves a face unseen. The flown team ends at the
simulator's score, its thesis stage at the thesis' score, and every drone flies home round
the structure and lands (one of them ends pressed against the structure's far face)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from bench.quality.runs import run_strategy, run_thesis
from bench.quality.structures import make_scene
from tests.agent_helpers import scenario_toml
from tests.conftest import repo_env

pytestmark = [pytest.mark.slow, pytest.mark.serial, pytest.mark.long]


def test_a_flown_team_makes_the_coverage_moves_and_ends_at_the_simulators_score(
        tmp_path: Path) -> None:
    scene = make_scene("lshape", "tuning", 1, 3, 1)
    path = tmp_path / "scene.toml"
    path.write_text(scenario_toml(scene.scenario(), strategy="potential", lost_after=0.0))
    run = subprocess.run([sys.executable, "-m", "agent.cli", "launch", str(path), "--flight",
                          "--runs", str(tmp_path / "runs"), "--timeout", "240",
                          "--time-scale", "5"],
                         capture_output=True, text=True, env=repo_env(), cwd=tmp_path,
                         timeout=300)
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-3000:]
    for aid in ("D0", "D1", "D2"):
        assert run.stdout.count(f"viscover-flight-agent {aid}: landed") == 1
    assert "not home within" not in run.stdout + run.stderr
    (folder,) = (tmp_path / "runs").iterdir()
    obs = json.loads((folder / "observer.json").read_text())
    assert obs["complete"] and obs["violations"] == [] and not obs["reverted"]
    assert obs["thesis_stage_coverage"] == pytest.approx(run_thesis(scene).score, rel=1e-3)
    assert obs["coverage"] == pytest.approx(run_strategy(scene).score, rel=1e-3)
