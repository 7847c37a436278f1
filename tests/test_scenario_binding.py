"""Journals and run folders are bound to their scenario (:mod:`agent.config.digest`): an agent
given a journal of another scenario, or ``launch --resume`` given a run folder of another
scenario, is refused in one line (exit 2) before anything is written."""

from __future__ import annotations

import json
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from agent.config.parse import parse_scenario
from tests.conftest import ROOT, repo_env, scenario_path

VISCOVER = [sys.executable, "-m", "agent.cli"]
HEX = str(scenario_path("hexagon_5_3"))
CUBE = str(scenario_path("cube_6_2"))


def _viscover(*args: str, cwd: Path, timeout: float = 60.0) -> subprocess.CompletedProcess[str]:
    return subprocess.run([*VISCOVER, *args], capture_output=True, text=True, env=repo_env(),
                          cwd=cwd, timeout=timeout, check=False)


def _files(root: Path) -> dict[str, tuple[bytes, int]]:
    """Every file under ``root``: its bytes and modification time [ns]."""
    return {str(p.relative_to(root)): (p.read_bytes(), p.stat().st_mtime_ns)
            for p in sorted(root.rglob("*")) if p.is_file()}


def test_the_digest_sees_ownership_not_tuning() -> None:
    from agent.config.digest import scenario_digest

    text = (ROOT / "scenarios" / "hexagon_5_3.toml").read_text()
    base = scenario_digest(parse_scenario(text, "a.toml"))
    assert len(base) == 16 and int(base, 16) >= 0
    # Where the file is and how the planner is tuned do not change what a journal means.
    assert scenario_digest(parse_scenario(text, "elsewhere/b.toml")) == base
    cosmetic = text.replace("duration = ", "duration = 1").replace("seed = 0", "seed = 7") \
        .replace("d_opt = 1.0", "d_opt = 1.5").replace("p_lim = 0.3", "p_lim = 0.2")
    assert cosmetic != text and scenario_digest(parse_scenario(cosmetic, "a.toml")) == base
    # Another mission name, another landmark set or another initial assignment: not the same.
    renamed = text.replace('name = "hexagon_5_3"', 'name = "hexagon_b"')
    assert scenario_digest(parse_scenario(renamed, "a.toml")) != base
    assert scenario_digest(parse_scenario(text.replace("side = 0.5", "side = 0.6"),
                                          "a.toml")) != base
    swapped = text.replace("[3, 6]", "[3, 5]").replace("[1, 5]", "[1, 6]")
    assert scenario_digest(parse_scenario(swapped, "a.toml")) != base
    assert scenario_digest(parse_scenario(Path(CUBE).read_text(), "a.toml")) != base


@pytest.fixture(scope="module")
def hexagon_run(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Path]:
    """A run folder of a (short) hexagon mission started by ``viscover launch``."""
    tmp = tmp_path_factory.mktemp("hexrun")
    done = _viscover("launch", HEX, "--runs", str(tmp / "runs"), "--timeout", "3",
                     "--no-record", cwd=tmp, timeout=90)
    assert done.returncode in (0, 3), done.stdout + done.stderr
    (run,) = (tmp / "runs").iterdir()
    yield run


def test_an_agent_refuses_a_journal_of_another_scenario(hexagon_run: Path, router: str) -> None:
    state = hexagon_run / "state" / "A"
    before = _files(state)
    assert before["journal.bin"][0]
    done = _viscover("agent", "--id", "A", "--scenario", CUBE, "--state-dir", str(state),
                     "--connect", router, "--timeout", "1", cwd=hexagon_run)
    assert done.returncode == 2, done.stderr
    assert done.stderr.splitlines() == [
        f"viscover: error: journal {state} belongs to scenario hexagon_5_3 ({HEX}), not to "
        f"cube_6_2 ({CUBE}): start this agent with --scenario {HEX}, or give it a fresh "
        "--state-dir"]
    assert _files(state) == before  # not a byte written, not even touched


def test_resume_refuses_a_run_folder_of_another_scenario(hexagon_run: Path) -> None:
    before = _files(hexagon_run)
    done = _viscover("launch", CUBE, "--resume", str(hexagon_run), "--timeout", "3",
                     "--no-record", cwd=hexagon_run.parent, timeout=90)
    assert done.returncode == 2, done.stdout + done.stderr
    assert done.stdout == ""
    assert done.stderr.splitlines() == [
        f"viscover: error: --resume {hexagon_run}: the run folder is a mission of scenario "
        f"hexagon_5_3 ({HEX}), not of cube_6_2 ({CUBE}): resume it with viscover launch {HEX} "
        f"--resume {hexagon_run}, or start a fresh run without --resume"]
    assert _files(hexagon_run) == before
    from agent.config.digest import scenario_digest

    doc = json.loads((hexagon_run / "launch.json").read_text())
    assert doc["scenario_digest"] == scenario_digest(parse_scenario(Path(HEX).read_text(), HEX))


def test_resume_with_the_same_scenario_is_accepted(hexagon_run: Path, tmp_path: Path) -> None:
    """The check refuses only another scenario (here a copy of the same file elsewhere)."""
    copy = tmp_path / "hexagon_copy.toml"
    copy.write_text(Path(HEX).read_text())
    done = _viscover("launch", str(copy), "--resume", str(hexagon_run), "--timeout", "2",
                     "--no-record", cwd=tmp_path, timeout=90)
    assert done.returncode in (0, 3), done.stdout + done.stderr
    assert f"launch: resuming {hexagon_run}" in done.stdout


def test_a_bound_journal_is_checked_before_a_torn_tail_is_cut(tmp_path: Path) -> None:
    from agent.protocol.records import JournalMismatch, StartRec
    from agent.storage.journal import Journal, JournalHeader, read_header

    hexa = JournalHeader(digest="1" * 16, scenario="hexagon_5_3", source="hex.toml")
    cube = JournalHeader(digest="2" * 16, scenario="cube_6_2", source="cube.toml")
    j = Journal(tmp_path / "A", bind=hexa)
    assert j.replay() == []  # a new journal: the header is written, and is no record
    j.append([StartRec(incarnation=1)], sync=True)
    j.close()
    path = tmp_path / "A" / "journal.bin"
    assert read_header(path) == hexa
    torn = path.read_bytes() + b"\x09\x00"  # half a frame header: a torn last write
    path.write_bytes(torn)
    j = Journal(tmp_path / "A", bind=cube)
    with pytest.raises(JournalMismatch, match=r"belongs to scenario hexagon_5_3 \(hex.toml\), "
                       r"not to cube_6_2 \(cube.toml\)"):
        j.replay()
    j.close()
    assert path.read_bytes() == torn  # not even the torn tail was cut
    j = Journal(tmp_path / "A")  # unbound (in-memory missions, tests): read, not checked
    assert j.replay() == [StartRec(incarnation=1)] and j.header == hexa
    j.close()


def test_a_journal_without_a_digest_is_refused_when_bound(tmp_path: Path) -> None:
    from agent.protocol.records import JournalMismatch, StartRec
    from agent.storage.journal import Journal, JournalHeader

    j = Journal(tmp_path / "A")
    j.replay()
    j.append([StartRec(incarnation=1)], sync=True)
    j.close()
    before = (tmp_path / "A" / "journal.bin").read_bytes()
    j = Journal(tmp_path / "A", bind=JournalHeader(digest="1" * 16, scenario="hexagon_5_3",
                                                   source="hex.toml"))
    with pytest.raises(JournalMismatch) as e:
        j.replay()
    j.close()
    assert str(e.value) == (
        f"journal {tmp_path / 'A'} has no scenario digest: it was written by an older, "
        "incompatible viscover version and cannot be checked against scenario hexagon_5_3 "
        "(hex.toml); finish that mission with the version that wrote it, or give it a fresh "
        "--state-dir")
    assert (tmp_path / "A" / "journal.bin").read_bytes() == before


def test_resume_of_a_run_folder_without_a_digest_is_refused(tmp_path: Path) -> None:
    from agent.errors import UsageError
    from agent.mission.runfolder import check_resume

    run = tmp_path / "run"
    (run / "state").mkdir(parents=True)
    (run / "launch.json").write_text(json.dumps({"scenario": HEX, "exit_status": 0}))
    sc = parse_scenario(Path(HEX).read_text(), HEX)
    with pytest.raises(UsageError) as e:
        check_resume(run, sc, HEX)
    assert str(e.value) == (
        f"--resume {run}: no scenario digest in its launch.json (an older viscover wrote it): "
        f"it cannot be checked against hexagon_5_3 ({HEX}); start a fresh run without --resume")
