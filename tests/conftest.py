"""Shared test fixtures: repository paths, a Zenoh router on a free loopback port (open, or
secured for a team of certificates), the
environment of a subprocess that runs this checkout, a polling wait, and an inspection's
tables computed once per scenario for the whole session."""

from __future__ import annotations

import hashlib
import os
import pickle
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING, TypeVar

import pytest

import agent.world.tables
from agent.net.router import start_router_process, stop_router_process

if TYPE_CHECKING:
    from agent.config.scenario import Scenario
    from agent.core.inspection import CaptureTable
    from agent.net.security import TeamDir
    from agent.structure.routes import RouteGrid
    from agent.testing.memsim import MemoryMission

T = TypeVar("T")

ROOT = Path(__file__).resolve().parents[1]
SCENARIOS = ROOT / "scenarios"


def scenario_path(name: str) -> Path:
    """A shipped scenario file, ``scenarios/<name>.toml``."""
    return SCENARIOS / f"{name}.toml"


def repo_env(**extra: str) -> dict[str, str]:
    """This process's environment with this checkout first on PYTHONPATH (for subprocesses)."""
    env = dict(os.environ, **extra)
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(ROOT), env.get("PYTHONPATH")]))
    return env


def reap(procs: Iterable[subprocess.Popen[str]]) -> dict[int, str]:
    """Kill what still runs, then read every process's stderr to the end and close its pipes
    (a pipe left open is a ResourceWarning, an error in a later test): {pid: stderr}."""
    errs: dict[int, str] = {}
    for p in procs:
        if p.poll() is None:
            p.kill()
        try:
            _out, err = p.communicate(timeout=10)
        except (ValueError, OSError):  # already read to the end and closed
            err = ""
        errs[p.pid] = err or ""
    return errs


def stop_process(proc: subprocess.Popen[str], reader: threading.Thread | None = None,
                     grace_s: float = 10.0) -> None:
    """Terminate ``proc`` if it runs (killed after ``grace_s``), wait for the thread reading
    its output (if any), then close its pipes."""
    if proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(grace_s)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(5)
    if reader is not None:
        reader.join(5.0)
    for stream in (proc.stdin, proc.stdout, proc.stderr):
        if stream is not None:
            stream.close()


def decoded(msgs: Iterable[T | None]) -> list[T]:
    """Messages a subscriber kept as its codec decoded them, each of which the test expects
    to have decoded (it fails on a None: one that did not)."""
    kept = list(msgs)
    out = [m for m in kept if m is not None]
    assert len(out) == len(kept), "a message did not decode"
    return out


def wait_until(pred: Callable[[], object], timeout_s: float = 3.0, poll_s: float = 0.01,
               poke: Callable[[], object] | None = None) -> bool:
    """Poll ``pred`` (calling ``poke`` first) every ``poll_s`` until true; False after
    ``timeout_s`` wall seconds."""
    deadline = time.monotonic() + timeout_s
    while True:
        if poke is not None:
            poke()
        if pred():
            return True
        if time.monotonic() > deadline:
            return False
        time.sleep(poll_s)


@pytest.fixture(scope="module")
def router() -> Iterator[str]:
    """A Zenoh router process on a free loopback port for the module's tests; its endpoint."""
    proc, endpoint = start_router_process()
    yield endpoint
    assert stop_router_process(proc) in (0, -15)


def flown_tables(mission: MemoryMission) -> tuple[CaptureTable, RouteGrid | None]:
    """The capture table and route grid an inspection's in-memory agents fly by: the ones
    their mission prepared (:func:`agent.world.prepare.prepare_world` calls
    :func:`agent.world.tables.mission_tables` once per mission; a test that needs them too
    reads them here instead of computing them again, seconds per structure)."""
    tables = mission.world.tables
    assert tables is not None, "not an inspection mission"
    return tables


_mission_tables = agent.world.tables.mission_tables  #: the library's, uncached
_TABLES: dict[str, tuple[CaptureTable, RouteGrid | None]] = {}
#: Where the workers of one ``pytest -n`` session share what they computed (None: this
#: process only); inside the session's own temporary directory, so never across sessions.
_TABLES_DIR: list[Path] = []


def _shared_mission_tables(sc: Scenario) -> tuple[CaptureTable, RouteGrid | None]:
    """:func:`agent.world.tables.mission_tables` of ``sc``, computed once per scenario for the
    session: a pure function of the scenario (its structure's mesh file included), a second or
    two per call, and the test suite asks it dozens of times for the same shipped structures
    (the workers of a ``pytest -n`` session share it through a file). The key is the whole
    scenario pickled, so any difference in any field computes afresh; the cached arrays are
    read-only, so a test or agent writing to one fails loudly instead of changing it for the
    next."""
    try:
        key = hashlib.sha256(pickle.dumps(sc, protocol=pickle.HIGHEST_PROTOCOL)).hexdigest()
    except (pickle.PicklingError, TypeError, AttributeError):  # not a plain scenario
        return _mission_tables(sc)
    hit = _TABLES.get(key)
    if hit is None:
        path = _TABLES_DIR[0] / f"{key}.pickle" if _TABLES_DIR else None
        if path is not None and path.is_file():
            hit = pickle.loads(path.read_bytes())
        else:
            hit = _mission_tables(sc)
            if path is not None:  # whole or not at all: written aside, then renamed
                part = path.with_suffix(f".{os.getpid()}.part")
                part.write_bytes(pickle.dumps(hit, protocol=pickle.HIGHEST_PROTOCOL))
                os.replace(part, path)
        table, grid = hit
        for arr in (table.P, table.V, table.C, table.value, table.reason,
                    *(() if grid is None else (grid.lo, grid.free))):
            arr.flags.writeable = False
        _TABLES[key] = hit
    return hit


@pytest.fixture(autouse=True, scope="session")
def _shared_tables(tmp_path_factory: pytest.TempPathFactory) -> Iterator[None]:
    """Every module's ``mission_tables`` (the name imported from :mod:`agent.world.tables`)
    is :func:`_shared_mission_tables` for the session; restored after."""
    if os.environ.get("PYTEST_XDIST_WORKER"):  # the session's directory, above the worker's
        shared = tmp_path_factory.getbasetemp().parent / "mission_tables"
        shared.mkdir(exist_ok=True)
        _TABLES_DIR.append(shared)
    patched = [m for m in list(sys.modules.values())
               if getattr(m, "mission_tables", None) is _mission_tables]
    for m in patched:
        m.mission_tables = _shared_mission_tables  # type: ignore[attr-defined]
    yield
    for m in patched:
        m.mission_tables = _mission_tables  # type: ignore[attr-defined]
    _TABLES_DIR.clear()


@pytest.fixture(scope="module")
def team(tmp_path_factory: pytest.TempPathFactory) -> TeamDir:
    """A team directory (certificates and signing keys) for drones A, B, C; a module may
    define its own (another team) and :func:`secured_router` serves that one."""
    from agent.net.pki import TeamPlan, make_team

    return make_team(TeamPlan(tmp_path_factory.mktemp("team"), ["A", "B", "C"]))


@pytest.fixture(scope="module")
def secured_router(team: TeamDir) -> Iterator[str]:
    """The team's secured router (mutual TLS, access control) on a free loopback port for the
    module's tests; its endpoint."""
    proc, endpoint = start_router_process(team=team)
    yield endpoint
    assert stop_router_process(proc) in (0, -15)
