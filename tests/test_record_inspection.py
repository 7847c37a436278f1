"""The recording and the report of an inspection mission. The recording's landmark
cloud on ``/landmarks/captures`` coloured by capture state, rewritten as the drones'
published captured sets grow: nothing captured at the start, every capturable landmark
captured at the end, the uncapturable ones grey (:mod:`agent.mission.capture_scene`). The
report of a launched run folder: result.json's ``inspection`` block, captures.png and the
summary line (:mod:`agent.sim.run_inspection`)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader

from agent.mission.capture_scene import (
    CAPTURED,
    PENDING,
    UNCAPTURABLE,
    CaptureView,
    capture_states,
    cloud_states,
)
from agent.mission.recorder import Recorder
from agent.sim.run_inspection import run_scenario
from agent.storage import recording as fmt
from agent.testing.memsim import MemoryMission
from agent.wire.peer import pack_bits
from agent.world.tables import mission_tables
from tests.conftest import repo_env, scenario_path
from tests.test_inspection_agents import _scenario


def test_the_recording_shows_captured_and_pending_landmarks(tmp_path: Path) -> None:
    sc = _scenario("inspect_wind_turbine")
    table, _ = mission_tables(sc)
    m = len(sc.landmark_ids)
    mm = MemoryMission(sc, tmp_path / "state", seed=3)
    rec = Recorder(mm.net.transport("rec"), sc, mm.cfg.mission, tmp_path / "rec",
                   pose_hz=5.0, scene_hz=2.0)
    try:
        assert mm.run(300.0)
        for _ in range(20):  # the last states reach the recorder
            mm.step()
    finally:
        rec.close()
        mm.close()
    with (tmp_path / "rec" / fmt.MCAP_NAME).open("rb") as f:
        clouds = [cloud_states(msg.data, m) for _s, ch, msg in make_reader(f).iter_messages()
                  if ch.topic == fmt.CAPTURES_TOPIC]
        f.seek(0)
        summary = make_reader(f).get_summary()
    assert summary is not None
    (schema,) = {summary.schemas[c.schema_id].name for c in summary.channels.values()
                 if c.topic == fmt.CAPTURES_TOPIC}
    assert schema == "foxglove.PointCloud"
    assert len(clouds) > 3  # rewritten as the set grew
    assert not (clouds[0] == CAPTURED).any() and (clouds[0] == PENDING).any()  # the start
    final = clouds[-1]
    assert (final[table.capturable] == CAPTURED).all()
    assert (final[~table.capturable] == UNCAPTURABLE).all() and (~table.capturable).any()
    counts = [int((c == CAPTURED).sum()) for c in clouds]
    assert counts == sorted(counts)  # the captured set only grows


def test_the_recorded_captured_set_is_what_a_majority_of_the_drones_name() -> None:
    sc = _scenario("inspect_wind_turbine")  # drones A, B, C
    m = len(sc.landmark_ids)
    view = CaptureView(sc)
    view.settle()
    assert view.uncapturable is not None
    first = np.zeros(m, dtype=np.bool_)
    first[:3] = True
    view.update("A", pack_bits(first))
    view.update("B", pack_bits(first))
    got = view.update("C", pack_bits(np.ones(m, dtype=np.bool_)))  # C's word: 1 vote of 3
    assert got is None or np.array_equal(got, capture_states(first, view.uncapturable))
    assert np.array_equal(view.states(), capture_states(first, view.uncapturable))


def test_the_scenario_of_a_run_not_found_is_one_line(tmp_path: Path) -> None:
    sc, why = run_scenario(tmp_path, {"source": "nowhere/gone.toml"})
    assert sc is None and why.startswith("scenario file not found (") and "\n" not in why
    assert why.endswith("): no inspection block") and "gone.toml" in why


@pytest.mark.slow
@pytest.mark.serial
# make test-long: make test launches an inspection in test_inspection_end.py::
# test_viscover_launch_of_an_incomplete_inspection_exits_3_and_says_why and builds an
# inspection's result.json from its recording in test_cli_export.py
@pytest.mark.long
def test_the_report_of_a_launched_inspection_has_its_inspection_block(tmp_path: Path) -> None:
    """A kinematic launch of the wind turbine (about 15 s), then ``viscover report``:
    result.json's ``inspection`` (captured / capturable / uncapturable with reasons, as the
    simulator's), captures.png, and the summary line."""
    path = scenario_path("inspect_wind_turbine").resolve()
    sc = _scenario("inspect_wind_turbine")
    assert sc.inspection is not None
    table, _ = mission_tables(sc)
    run = subprocess.run([sys.executable, "-m", "agent.cli", "launch", str(path), "--runs",
                          str(tmp_path / "runs"), "--timeout", "120"], capture_output=True,
                         text=True, env=repo_env(), cwd=tmp_path, timeout=180)
    assert run.returncode == 0, run.stderr[-3000:]
    (folder,) = (tmp_path / "runs").iterdir()
    rep = subprocess.run([sys.executable, "-m", "agent.cli", "report", str(folder)],
                         capture_output=True, text=True, env=repo_env(), cwd=tmp_path,
                         timeout=120)
    assert rep.returncode == 0, rep.stderr[-3000:]
    ids = np.asarray(sc.landmark_ids)
    n, k = int(table.capturable.sum()), int((~table.capturable).sum())
    assert f"captured {n}/{n} at quality >= {sc.inspection.quality:g}; {k} uncapturable (" \
        in rep.stdout
    doc = json.loads((folder / "report" / "result.json").read_text())
    ins = doc["inspection"]
    assert sorted(ins["captured"]) == sorted(ids[table.capturable].tolist())
    assert ins["capturable"] == n and set(ins["best_quality"]) == {str(x) for x in
                                                                     ins["captured"]}
    assert sorted(int(x) for x in ins["uncapturable"]) == sorted(ids[~table.capturable].tolist())
    assert all(ins["uncapturable"].values())
    assert (folder / "report" / "captures.png").stat().st_size > 0
