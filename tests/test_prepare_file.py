"""Prepared once (agent.world.prepared, ``viscover prepare``): the capture table and route
grid written once and loaded by every agent are bit for bit the ones an agent builds, and a
team flying from the file does exactly what a team building its own tables does; a file of
another scenario, of other settings, of another version or not one at all is refused with
one line; the command's mistakes are one line and exit 2; ``launch`` names the file to its
agents. Loading scenarios with many explicit landmarks is linear (ids assigned in one pass,
checked here as a property; the timing is in bench/bench_prepare.py)."""

from __future__ import annotations

import dataclasses
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from agent.config.parse import load_scenario, parse_scenario
from agent.config.scenario import Scenario
from agent.config.validation import ScenarioError
from agent.testing.memsim import MemoryMission
from agent.world.prepare import prepare_world
from agent.world.prepared import (
    PREPARED_ENV,
    PreparedError,
    check_prepared,
    load_prepared,
    prepare_file,
    save_prepared,
)
from agent.world.structure import resolve_structure
from agent.world.tables import mission_tables
from tests.conftest import repo_env, scenario_path

HOUSE = "inspect_gabled_house"


def _house() -> Scenario:
    return resolve_structure(load_scenario(scenario_path(HOUSE)))


def _written(tmp_path: Path, sc: Scenario) -> Path:
    return save_prepared(tmp_path / "house.prepared.npz", sc, mission_tables(sc))


def test_the_loaded_tables_are_the_built_ones_bit_for_bit(tmp_path: Path) -> None:
    sc = _house()
    built_table, built_grid = mission_tables(sc)
    table, grid = load_prepared(_written(tmp_path, sc), sc)
    for a, b in ((table.P, built_table.P), (table.V, built_table.V),
                 (table.C, built_table.C), (table.value, built_table.value),
                 (table.reason, built_table.reason),
                 (table.rows.indptr, built_table.rows.indptr),
                 (table.rows.indices, built_table.rows.indices)):
        assert a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()
    assert built_grid is not None and grid is not None
    assert grid.shape == built_grid.shape and grid.pitch == built_grid.pitch
    assert grid.lo.tobytes() == built_grid.lo.tobytes()
    assert np.array_equal(grid.free, built_grid.free)
    a = np.array([-6.0, -6.0, 2.0], dtype=np.float64)  # around the house
    b = np.array([20.0, 14.0, 3.0], dtype=np.float64)
    assert np.array_equal(grid.route(a, b), built_grid.route(a, b))


def _team_trace(sc: Scenario, root: Path, until: float) -> list[tuple[bytes, object, object,
                                                                       object]]:
    """What each agent publishes at mission time ``until``: its captured set, pose and set."""
    mm = MemoryMission(sc, root, seed=1)
    try:
        while mm.clock.now() < until and not mm.complete:
            mm.step()
        states = [mm.agents[a.id].state_message() for a in sc.agents]
        return [(st.captured, st.p, st.v, st.owned) for st in states]
    finally:
        mm.close()


def test_a_team_from_the_file_flies_as_a_team_building_its_own(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The same in-memory mission (no faults: deterministic) for 12 s of mission time, once
    with tables built in the process, once with every agent loading the prepared file (named
    by the environment, as launch does): the same captures and the same positions."""
    sc = _house()
    path = _written(tmp_path, sc)
    built = _team_trace(sc, tmp_path / "built", 12.0)
    monkeypatch.setenv(PREPARED_ENV, str(path))

    def no_build(_sc: Scenario) -> None:
        raise AssertionError("an agent built its tables although a prepared file was named")

    monkeypatch.setattr("agent.world.prepare.mission_tables", no_build)
    assert prepare_world(sc).tables is not None  # from the file (the env names it)
    loaded = _team_trace(sc, tmp_path / "loaded", 12.0)
    assert any(any(t[0]) for t in built), "nothing captured in 12 s"
    assert loaded == built


def test_a_file_of_another_scenario_is_refused_in_one_line(tmp_path: Path) -> None:
    path = _written(tmp_path, _house())
    other = resolve_structure(load_scenario(scenario_path("inspect_house_parts")))
    with pytest.raises(PreparedError) as err:
        load_prepared(path, other)
    msg = str(err.value)
    assert "\n" not in msg and msg.startswith(f"{path}: prepared for mission "
                                              f"'{HOUSE}' (scenario digest ")
    assert f"not for {other.source} (digest " in msg
    assert msg.endswith(f"write it again with `viscover prepare {other.source} -o {path}`")
    with pytest.raises(PreparedError, match="prepared for mission"):
        prepare_world(other, path)  # what an agent given the wrong file does
    with pytest.raises(PreparedError, match="prepared for mission"):
        check_prepared(path, other)


def test_a_file_of_other_settings_is_refused(tmp_path: Path) -> None:
    """Same landmarks and team (same digest), another d_opt: the table differs."""
    sc = _house()
    path = _written(tmp_path, sc)
    moved = dataclasses.replace(sc, d_opt=sc.d_opt * 1.1)
    with pytest.raises(PreparedError, match="prepared for this scenario's landmarks but "
                       "other settings"):
        load_prepared(path, moved)


def test_not_a_prepared_file_is_refused(tmp_path: Path) -> None:
    sc = _house()
    junk = tmp_path / "junk.npz"
    junk.write_bytes(b"not a zip")
    for p, why in ((junk, "not a viscover prepared file; write it again"),
                   (tmp_path / "none.npz", "no such prepared file"),
                   (tmp_path, "is a directory")):
        with pytest.raises(PreparedError) as err:
            load_prepared(p, sc)
        assert str(err.value).startswith(f"{p}: {why}") and "\n" not in str(err.value)
    other = tmp_path / "other.npz"
    np.savez(other, format=np.array("viscover-prepared"), version=np.array(99))
    with pytest.raises(PreparedError, match="a prepared file of version 99, this viscover "
                       "reads version 1"):
        load_prepared(other, sc)


def test_prepare_file_keeps_a_right_file_and_rebuilds_a_stale_one(tmp_path: Path) -> None:
    sc = _house()
    path = tmp_path / "p.npz"
    assert prepare_file(sc, path) is False  # built
    assert prepare_file(sc, path) is True  # kept
    other = resolve_structure(load_scenario(scenario_path("inspect_house_parts")))
    assert prepare_file(other, path) is False  # another scenario's: rebuilt
    load_prepared(path, other)


def _viscover(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "agent.cli", *args], capture_output=True,
                          text=True, env=repo_env(), cwd=cwd, timeout=120, check=False)


def test_the_command_writes_the_file_the_agents_load(tmp_path: Path) -> None:
    out = tmp_path / "h.npz"
    r = _viscover("prepare", str(scenario_path(HOUSE)), "-o", str(out), cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert r.stdout.startswith(f"prepared {out}: {HOUSE}, 61 landmarks (61 capturable), ")
    assert "prepare: " in r.stderr  # progress
    load_prepared(out, _house())


def test_the_command_with_a_bad_path_says_one_line_and_exits_2(tmp_path: Path) -> None:
    scen = str(scenario_path(HOUSE))
    bad = tmp_path / "no" / "x.npz"
    r = _viscover("prepare", scen, "-o", str(bad), cwd=tmp_path)
    assert (r.returncode, r.stdout) == (2, "")
    assert r.stderr == (f"viscover: error: -o {bad}: no such folder "
                        f"'{bad.parent}'; create it or choose another path\n")
    r = _viscover("prepare", scen, "-o", str(tmp_path), cwd=tmp_path)
    assert r.returncode == 2 and r.stderr.startswith(f"viscover: error: -o {tmp_path}: is a "
                                                     "directory; name the file to write")
    assert r.stderr.count("\n") == 1
    r = _viscover("prepare", str(scenario_path("cube_6_2")), cwd=tmp_path)
    assert r.returncode == 2 and r.stderr.count("\n") == 1
    assert "not an inspection mission" in r.stderr
    r = _viscover("prepare", str(tmp_path / "none.toml"), cwd=tmp_path)
    assert r.returncode == 2
    assert r.stderr == f"viscover: error: {tmp_path / 'none.toml'}: no such file; check the path\n"


# -- linear loading: ids in one pass ---------------------------------------------------------------


def _text(ids: list[int | None], gen: int) -> str:
    rows = "".join(("" if i is None else f"id = {i}\n").join(
        ["[[landmarks]]\n", f"position = [{k}.0, 0.0, 1.0]\nnormal = [0.0, -1.0, 0.0]\n"])
        for k, i in enumerate(ids))
    box = (f'[[generators]]\nkind = "box"\ncenter = [0.0, 5.0, 1.0]\nsize = 1.0\n'
           f"count = {gen}\nfaces = [\"+x\"]\n") if gen else ""
    return (f'name = "ids"\ndims = 3\nd_opt = 1.0\nduration = 1.0\n{rows}{box}'
            '[[agents]]\nid = "A"\nposition = [0.0, -3.0, 1.0]\n')


def _expected(ids: list[int | None], gen: int) -> list[int]:
    """The documented rule, written the slow way: a missing id is one more than the largest
    so far (from 1); generated ids follow the largest."""
    out: list[int] = []
    for i in ids:
        out.append(max(out, default=0) + 1 if i is None else i)
    top = max(out, default=0)
    return out + list(range(top + 1, top + 1 + gen))


@settings(max_examples=60, deadline=None)
@given(st.lists(st.one_of(st.none(), st.integers(0, 60)), max_size=25), st.integers(0, 3))
def test_ids_are_assigned_as_documented(ids: list[int | None], gen: int) -> None:
    want = _expected(ids, gen)
    text = _text(ids, gen)
    if len(set(want)) < len(want) or not want:
        with pytest.raises(ScenarioError):
            parse_scenario(text.replace('id = "A"\n', 'id = "A"\nlandmarks = []\n'))
        return
    owned = ", ".join(map(str, want))
    sc = parse_scenario(text.replace('id = "A"\n', f'id = "A"\nlandmarks = [{owned}]\n'))
    assert sc.landmark_ids == want


def test_many_landmarks_without_ids_are_numbered_in_order() -> None:
    """30,000 explicit landmarks with no ids (the case that was quadratic): 1..m."""
    m = 30_000
    rows = "[[landmarks]]\nposition = [0.0, 0.0, 1.0]\nnormal = [0.0, -1.0, 0.0]\n" * m
    owned = ", ".join(str(i) for i in range(1, m + 1))
    sc = parse_scenario(f'name = "n"\ndims = 3\nd_opt = 1.0\nduration = 1.0\n{rows}'
                        f'[[agents]]\nid = "A"\nposition = [0.0, -3.0, 1.0]\n'
                        f"landmarks = [{owned}]\n")
    assert sc.landmark_ids == list(range(1, m + 1))


# -- launch prepares once -------------------------------------------------------------------------


def test_launch_prepares_once_and_names_the_file_to_its_agents(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The table is built once into the run folder, kept on a resume, and every child's
    environment names it; a coverage mission has nothing to prepare."""
    import io

    from agent.mission.launcher import Launcher, LaunchPlan

    monkeypatch.delenv("VISCOVER_TLS_DIR", raising=False)
    sc = _house()
    out = io.StringIO()
    plan = LaunchPlan(scenario_path=str(scenario_path(HOUSE)), scenario=sc, mission="m",
                      run_dir=tmp_path, ids=("A",), out=out)
    launcher = Launcher(plan)
    launcher.prepare()
    path = tmp_path / "prepared.npz"
    assert launcher.child_env == {PREPARED_ENV: str(path.resolve())}
    load_prepared(path, sc)
    assert "launch: capture table prepared once for the team: " in out.getvalue()
    Launcher(plan).prepare()  # a resumed run: the file is this scenario's, kept
    assert "launch: capture table kept once for the team: " in out.getvalue()
    cube = load_scenario(scenario_path("cube_6_2"))
    other = Launcher(LaunchPlan(str(scenario_path("cube_6_2")), cube, "m", tmp_path / "c",
                                out=out))
    other.prepare()
    assert other.child_env == {}


def test_an_agent_named_the_file_reads_the_mesh_landmarks_instead_of_sampling(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The file carries the sampled mesh landmarks under their key (mesh bytes, placement,
    spacing, filters, seed): resolving the scenario with the file named gives the same
    scenario without sampling; with another seed (another key) the mesh is sampled."""
    import agent.world.samples as samples

    sc = _house()
    path = _written(tmp_path, sc)
    monkeypatch.setenv(PREPARED_ENV, str(path))
    monkeypatch.setattr(samples, "_KEPT", {})

    def no_sampling(*_a: object, **_k: object) -> None:
        raise AssertionError("sampled although the prepared file holds the landmarks")

    monkeypatch.setattr(samples, "sample_landmarks", no_sampling)
    again = resolve_structure(load_scenario(scenario_path(HOUSE)))
    assert np.array_equal(again.q, sc.q) and np.array_equal(again.u, sc.u)
    assert again.landmark_ids == sc.landmark_ids
    load_prepared(path, again)
    with pytest.raises(AssertionError, match="sampled although"):
        resolve_structure(dataclasses.replace(load_scenario(scenario_path(HOUSE)), seed=7))
