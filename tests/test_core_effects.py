"""The agent core's one door (issue 32): time and the vehicle enter only as events, every
action leaves as an effect, and the runtime carries the effects out in order.

* The camera of an inspection drone fires only for captures whose record is already in the
  journal, fsynced: a mission of agent runtimes in memory, the journal and the camera
  trigger both spied on.
* The core's import closure reads no clock, takes no lock, sleeps nowhere and does no I/O
  (see :func:`test_the_cores_import_closure_reads_no_clock_takes_no_lock_and_does_no_io`).
"""

from __future__ import annotations

import ast
from collections.abc import Callable, Iterable
from pathlib import Path

from agent.config.parse import load_scenario
from agent.protocol.records import DURABLE, CaptureRec
from agent.storage.journal import Journal
from agent.testing.memsim import MemoryMission
from agent.world.structure import resolve_structure
from tests.conftest import scenario_path


class SpiedJournal(Journal):
    """A journal that remembers the capture ids it wrote fsynced."""

    def __init__(self, path: Path) -> None:
        super().__init__(path)
        self.durable_captures: set[int] = set()

    def append(self, records: Iterable[object], sync: bool | None = None) -> None:
        recs = list(records)
        super().append(recs, sync)
        if sync or (sync is None and any(isinstance(r, DURABLE) for r in recs)):
            for r in recs:
                if isinstance(r, CaptureRec):
                    self.durable_captures.update(r.ids)


def test_the_camera_fires_only_for_captures_already_persisted(tmp_path: Path) -> None:
    sc = resolve_structure(load_scenario(scenario_path("inspect_wind_turbine")))
    journals: dict[str, SpiedJournal] = {}

    def journal(aid: str, path: Path) -> Journal:
        journals[aid] = SpiedJournal(path)
        return journals[aid]

    fired: list[tuple[str, list[int]]] = []
    early: list[str] = []

    def camera(aid: str) -> Callable[[list[int]], None]:
        def trigger(ids: list[int]) -> None:
            fired.append((aid, ids))
            missing = set(ids) - journals[aid].durable_captures
            if missing:
                early.append(f"{aid} fired for {sorted(missing)} before they were persisted")
        return trigger

    mm = MemoryMission(sc, tmp_path, seed=3, journal_factory=journal)
    try:
        for aid, rt in mm.agents.items():
            rt.on_trigger = camera(aid)
        while mm.clock.now() < 60.0 and len(fired) < 12:
            mm.step()
    finally:
        mm.close()
    assert early == []
    assert len(fired) >= 12  # the cameras did fire, one image per capture
    assert all(ids for _aid, ids in fired)


# -- the core's import closure ------------------------------------------------------------

ROOT = Path(__file__).resolve().parent.parent
#: Modules no module of the core may import: clocks, threads, processes, sockets, files,
#: randomness from the OS, the transport, the journal, the vehicle link, the processes above.
FORBIDDEN_MODULES = (
    "time", "threading", "multiprocessing", "asyncio", "concurrent", "socket", "select",
    "selectors", "signal", "subprocess", "secrets", "os", "io", "shutil", "tempfile", "sqlite3",
    "urllib", "http", "zenoh", "pymavlink", "tomllib", "agent.clock", "agent.net.transport",
    "agent.net.session", "agent.net.router", "agent.storage", "agent.flight", "agent.mission",
    "agent.runners", "agent.commands", "agent.sim", "groundstation")
#: Calls that read a clock, sleep, wait, or do I/O, by the called name.
FORBIDDEN_CALLS = frozenset({
    "open", "print", "input", "sleep", "now", "time", "time_ns", "monotonic", "perf_counter",
    "read_text", "read_bytes", "write_text", "write_bytes", "is_file", "is_dir", "exists",
    "mkdir", "unlink", "iterdir", "glob", "load", "loads_file", "save", "savez", "urandom",
    "Lock", "RLock", "Event", "Condition", "Semaphore", "Thread", "wait", "acquire"})
#: The only names of :mod:`random` the core may call: seeded generators, never the global.
SEEDED_RANDOM = frozenset({"Random"})


def _module_file(name: str) -> Path | None:
    base = ROOT / name.replace(".", "/")
    for p in (base.with_suffix(".py"), base / "__init__.py"):
        if p.is_file():
            return p
    return None


def _runtime_imports(tree: ast.Module, name: str, is_pkg: bool) -> set[str]:
    """Modules imported when the module runs (not under ``if TYPE_CHECKING``)."""
    out: set[str] = set()

    def visit(nodes: list[ast.stmt]) -> None:
        for node in nodes:
            if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
                visit(node.orelse)
                continue
            if isinstance(node, ast.Import):
                out.update(a.name for a in node.names)
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    parts = name.split(".")
                    base = parts[:len(parts) - node.level + (1 if is_pkg else 0)]
                    mod = ".".join(base + ([node.module] if node.module else []))
                else:
                    mod = node.module or ""
                out.add(mod)
                out.update(f"{mod}.{a.name}" for a in node.names)
            for field in ("body", "orelse", "finalbody", "handlers"):
                inner = getattr(node, field, None)
                if isinstance(inner, list) and inner and isinstance(inner[0], ast.stmt):
                    visit(inner)
                elif isinstance(inner, list):
                    for h in inner:
                        if isinstance(h, ast.ExceptHandler):
                            visit(h.body)

    visit(tree.body)
    return out


def import_closure(*roots: str) -> dict[str, tuple[Path, set[str]]]:
    """Every project module the ``roots`` import when they run, directly or not: name ->
    (file, everything it imports)."""
    seen: dict[str, tuple[Path, set[str]]] = {}
    todo = list(roots)
    while todo:
        name = todo.pop()
        if name in seen:
            continue
        path = _module_file(name)
        if path is None:
            continue
        imports = _runtime_imports(ast.parse(path.read_text()), name,
                                   path.name == "__init__.py")
        seen[name] = (path, imports)
        parts = name.split(".")
        todo += [".".join(parts[:i]) for i in range(1, len(parts))]
        todo += [m for m in imports if m.split(".")[0] in ("agent", "groundstation")]
    return seen


def impurities(name: str, path: Path, imports: set[str]) -> list[str]:
    """What in module ``name`` reads a clock, locks, sleeps or does I/O."""
    found = [f"{name} imports {m}" for m in sorted(imports)
             if any(m == f or m.startswith(f + ".") for f in FORBIDDEN_MODULES)]
    for node in ast.walk(ast.parse(path.read_text())):
        if not isinstance(node, ast.Call):
            continue
        fn = node.func
        called = fn.id if isinstance(fn, ast.Name) else \
            fn.attr if isinstance(fn, ast.Attribute) else None
        if called in FORBIDDEN_CALLS:
            found.append(f"{name}:{node.lineno} calls {ast.unparse(fn)}()")
        if isinstance(fn, ast.Attribute) and isinstance(fn.value, ast.Name) \
                and fn.value.id == "random" and fn.attr not in SEEDED_RANDOM:
            found.append(f"{name}:{node.lineno} calls the global random.{fn.attr}()")
    return found


def test_the_cores_import_closure_reads_no_clock_takes_no_lock_and_does_no_io() -> None:
    """Everything the agent core imports when it runs (``agent.runtime.core.agent_core``, walked
    through every import not under ``TYPE_CHECKING``) imports no clock, thread, process,
    socket, file or transport module and calls nothing that reads a clock, sleeps, waits,
    locks or does I/O (logging through :mod:`logging` is its one output besides effects).
    The registered moves are imported by name (:func:`agent.runtime.moves.move.move_class`):
    every module of ``agent/runtime/moves/`` is walked too."""
    moves = sorted(f"agent.runtime.moves.{p.stem}"
                   for p in (ROOT / "agent" / "runtime" / "moves").glob("*.py"))
    closure = import_closure("agent.runtime.core.agent_core", *moves)
    assert "agent.runtime.moves.planning" in closure and "agent.protocol.machine" in closure
    assert {"agent.runtime.moves.revert", "agent.runtime.moves.take_work"} <= set(closure)
    found = [x for name, (path, imports) in sorted(closure.items())
             for x in impurities(name, path, imports)]
    assert found == []


def test_the_purity_scan_finds_the_runtimes_clock_lock_and_io() -> None:
    """The scan above is not blind: the runtime around the core reads the clock, holds a
    lock and imports the journal and the seal."""
    closure = import_closure("agent.runtime.shell.runtime")
    found = [x for name, (path, imports) in sorted(closure.items())
             for x in impurities(name, path, imports)]
    assert "agent.runtime.shell.runtime imports threading" in found
    assert any(x.startswith("agent.runtime.shell.runtime:") and x.endswith("calls self.clock.now()")
               for x in found)
    assert "agent.runtime.shell.runtime imports agent.storage.journal" in found
    assert "agent.wire.signed imports secrets" in found
