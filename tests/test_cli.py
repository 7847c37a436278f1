"""The viscover command line (agent.cli)."""

from __future__ import annotations

import io
import json
from pathlib import Path

import pytest

from agent.cli import COMMANDS, main
from agent.commands.simulate import Progress

SCENARIOS = Path(__file__).resolve().parent.parent / "scenarios"

TINY = """\
name = "tiny"
dims = 2
d_opt = 3.0
duration = 3.0

[planner]
avoidance = "none"

[[landmarks]]
position = [1.0, 4.5]
normal_angle = -2.0943951023931953

[[landmarks]]
position = [2.0, 4.1]
normal_angle = -1.5707963267948966

[[agents]]
id = "A"
position = [-1.0, 5.0]
yaw = 1.0471975511965976
landmarks = [1, 2]
"""


@pytest.fixture
def tiny(tmp_path: Path) -> Path:
    f = tmp_path / "tiny.toml"
    f.write_text(TINY, encoding="utf-8")
    return f


def test_registry_lists_subcommands() -> None:
    assert list(COMMANDS)[:2] == ["simulate", "scenario"]


def test_scenario_check_shipped(capsys: pytest.CaptureFixture[str]) -> None:
    files = sorted(str(p) for p in SCENARIOS.glob("*.toml"))
    assert main(["scenario", "check", *files]) == 0
    out = capsys.readouterr().out
    assert out.count("ok  ") == len(files)
    assert "cube_6_2: 3-D, 15 landmarks, 3 agents" in out


def test_scenario_check_broken(tmp_path: Path, tiny: Path,
                               capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text(TINY.replace("d_opt = 3.0", "d_opt = -3.0"), encoding="utf-8")
    assert main(["scenario", "check", str(tiny), str(bad)]) == 2
    cap = capsys.readouterr()
    assert "Traceback" not in cap.err
    assert f"{bad}: d_opt: must be a positive number" in cap.err
    assert len(cap.err.strip().splitlines()) == 1
    assert "tiny: 2-D, 2 landmarks, 1 agent" in cap.out


@pytest.mark.parametrize("argv", [
    ["scenario", "check", "does/not/exist.toml"],
    ["simulate", "does/not/exist.toml", "--out", "x"],
])
def test_missing_file_is_a_user_error(argv: list[str], capsys: pytest.CaptureFixture[str]
                                      ) -> None:
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "does/not/exist.toml: no such file" in err and "Traceback" not in err


def test_bad_out_is_a_user_error(tmp_path: Path, tiny: Path,
                                 capsys: pytest.CaptureFixture[str]) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("x")
    assert main(["simulate", str(tiny), "--out", str(blocker)]) == 2
    err = capsys.readouterr().err
    assert "--out" in err and "not a directory" in err and "Traceback" not in err


def test_bad_arguments_return_2(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["no-such-command"]) == 2
    assert main(["--help"]) == 0
    capsys.readouterr()


def test_simulate_writes_report(tmp_path: Path, tiny: Path,
                                capsys: pytest.CaptureFixture[str]) -> None:
    import agent.sim.kinematic  # noqa: F401  (the real simulator)
    out = tmp_path / "run"
    assert main(["simulate", str(tiny), "--out", str(out), "--seed", "7"]) == 0
    cap = capsys.readouterr()
    assert str(out) in cap.out and "coverage" in cap.out
    assert "%" in cap.err  # progress
    doc = json.loads((out / "result.json").read_text())
    assert doc["scenario"] == "tiny" and doc["seed"] == 7 and doc["agents"] == ["A"]
    for name in ("trajectories.png", "coverage.png", "partition.png"):
        assert (out / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_simulate_quiet_no_plots(tmp_path: Path, tiny: Path,
                                 capsys: pytest.CaptureFixture[str]) -> None:
    import agent.sim.kinematic  # noqa: F401  (the real simulator)
    out = tmp_path / "run"
    assert main(["simulate", str(tiny), "--out", str(out), "--no-plots", "--quiet"]) == 0
    assert capsys.readouterr().err == ""
    assert sorted(p.name for p in out.iterdir()) == ["result.json"]


def test_progress_non_tty_prints_every_ten_percent() -> None:
    buf = io.StringIO()
    prog = Progress("x", buf)
    for k in range(101):
        prog(k * 0.1, 10.0)
    prog.close()
    lines = buf.getvalue().splitlines()
    assert len(lines) == 12 and lines[-2].startswith("x: 100%")
    assert lines[-1].startswith("x: done, t = 10.0 s")


def test_progress_says_interrupted_not_done() -> None:
    buf = io.StringIO()
    prog = Progress("x", buf)
    prog(2.5, 10.0)
    prog.close(finished=False)
    assert buf.getvalue().splitlines()[-1].startswith(
        "x: interrupted (no report written), t = 2.5 s simulated in ")


def test_complete_with_an_unseen_landmark_says_so() -> None:
    """One agent at the origin looking along +x owns a landmark in front facing it (seen) and
    one behind it (unseen): the summary must not say plain "complete"."""
    import numpy as np

    from agent.commands.simulate import summarize
    from agent.sim.result import SimResult

    q = np.array([[2.0, 0.0, 0.0], [-2.0, 0.0, 0.0]])
    u = np.array([[-1.0, 0.0, 0.0], [-1.0, 0.0, 0.0]])
    res = SimResult(
        scenario="s", seed=0, planar=False, agent_ids=["A"], landmark_ids=[3, 8], q=q, u=u,
        space_lo=np.full(3, -np.inf), space_hi=np.full(3, np.inf), d_opt=1.0,
        times=np.array([0.0]), positions=np.zeros((1, 1, 3)),
        directions=np.array([[[1.0, 0.0, 0.0]]]), vision=np.zeros((1, 1)),
        coverage=np.array([0.5]), owners=np.zeros((1, 2)), complete=True, t_complete=0.0)
    assert res.seen_by_owner().tolist() == [True, False]
    lines = summarize(res).splitlines()
    assert lines[0].endswith("complete at t = 0 s with 1 landmark(s) unseen by their owner")
    assert lines[1] == "1/2 landmarks seen by their owner; UNSEEN: 8"
