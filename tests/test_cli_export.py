"""A run folder as ``viscover launch`` leaves it (journals, ``captures.jsonl``, the
recording; no ``report/``) is taken as it is: ``export-plan`` builds the ``result.json`` it
needs from the recording (``report/result.json``, as ``viscover report --no-plots`` writes
it) and says so; without a recording it says what is missing, in one line."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from agent.cli import main
from agent.mission.recorder import Recorder
from agent.mission.runfolder import write_captures
from agent.testing.memsim import MemoryMission
from tests.test_inspection_agents import _scenario

ORIGIN = "47.3977,8.5456,488"


@pytest.fixture(scope="module")
def launched_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """An inspection flown in memory into a run folder laid out as a launch's: ``state/<id>``
    journals, the recording, and ``captures.jsonl`` written from the journals at the end."""
    run = tmp_path_factory.mktemp("run")
    sc = _scenario("inspect_wind_turbine")
    mm = MemoryMission(sc, run / "state", seed=3)
    rec = Recorder(mm.net.transport("rec"), sc, mm.cfg.mission, run, pose_hz=5.0,
                   scene_hz=2.0)
    try:
        assert mm.run(300.0)
        for _ in range(20):  # the last states reach the recorder
            mm.step()
    finally:
        rec.close()
        mm.close()
    write_captures(run, sc)
    return run


def test_export_plan_takes_a_launched_run_folder_as_it_is(
        launched_run: Path, capsys: pytest.CaptureFixture[str]) -> None:
    run = launched_run
    assert not (run / "report").exists()
    assert main(["export-plan", str(run), "--origin", ORIGIN]) == 0
    out, err = capsys.readouterr()
    built = run / "report" / "result.json"
    assert err.splitlines()[0] == (f"viscover: {built}: built from the run's recording "
                                   f"(viscover report {run} adds the plots and report.html)")
    doc = json.loads(built.read_text())
    agents = sorted({c["agent"] for c in doc["captures"]})
    assert agents and sorted(p.name for p in (run / "plans").iterdir()) == [
        f"{a}.plan" for a in agents]
    assert [line.split(":")[0] for line in out.splitlines()] == [
        str(run / "plans" / f"{a}.plan") for a in agents]
    # once built, it is read as any result.json: nothing said
    assert main(["export-plan", str(run), "--origin", ORIGIN, "--out", str(run / "p2")]) == 0
    assert "built from" not in capsys.readouterr().err


def test_without_a_recording_it_says_what_is_missing(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "state").mkdir()
    assert main(["export-plan", str(tmp_path), "--origin", ORIGIN]) == 2
    assert capsys.readouterr().err == (
        f"viscover: error: {tmp_path}: no result.json here or in report/, and no recording to "
        "build one from (run viscover simulate, or record the mission)\n")
