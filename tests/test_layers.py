"""The layering written in :mod:`agent`'s docstring holds: every import of every module points
down (or stays in its own package), and nothing in ``agent`` but ``agent.cli`` imports
``groundstation``."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

from tests.conftest import ROOT

#: Package (or module) → rank, as in agent/__init__.py.
RANKS = {
    "agent.core": 0, "agent.clock": 0, "agent.errors": 0,
    "agent.wire": 1, "agent.strategy": 1,
    "agent.protocol": 2, "agent.config": 2, "agent.structure": 2,
    "agent.net": 3, "agent.storage": 3, "agent.world": 3,
    "agent.flight": 4,
    "agent.runtime": 5, "agent.sim": 5,  # same rank: neither imports the other
    "agent.mission": 6,
    "agent.runners": 7, "agent.testing": 7,
    "agent.commands": 8,
    "agent.cli": 9,
    "groundstation": 10,
    "viscover": 11,  # the scripting API: above every layer, imported by nothing of them
}


def unit_of(module: str) -> str | None:
    """The layered unit a dotted module name belongs to (None: outside the project)."""
    parts = module.split(".")
    for n in (2, 1):
        name = ".".join(parts[:n])
        if name in RANKS:
            return name
    return None


def module_name(path: Path, root: Path = ROOT) -> str:
    """Dotted module name of a source file under ``root``."""
    rel = path.relative_to(root).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def imports_of(path: Path) -> list[tuple[int, str]]:
    """(line, imported module) of every import statement, lazy ones included."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out += [(node.lineno, a.name) for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            out.append((node.lineno, node.module))
            out += [(node.lineno, f"{node.module}.{a.name}") for a in node.names]
    return out


def sources() -> list[Path]:
    return sorted(p for d in ("agent", "groundstation", "viscover")
                  for p in (ROOT / d).rglob("*.py"))


def violations(files: list[Path], root: Path = ROOT) -> list[str]:
    """Every import that points the wrong way, as ``file:line: what``."""
    bad = []
    for path in files:
        me = module_name(path, root)
        if me == "agent":  # the package docstring that states the layering
            continue
        unit = unit_of(me)
        if unit is None:
            bad.append(f"{me}: not in any layer of agent/__init__.py")
            continue
        seen: set[tuple[int, str]] = set()
        for line, target in imports_of(path):
            other = unit_of(target)
            if other is None or other == unit or target == "agent" or (line, other) in seen:
                continue
            seen.add((line, other))
            if RANKS[other] >= RANKS[unit] and not (unit == "agent.cli"
                                                    and other == "groundstation"):
                bad.append(f"{path.relative_to(root)}:{line}: {me} (rank {RANKS[unit]}) "
                           f"imports {target} (rank {RANKS[other]})")
            if other == "groundstation" and unit != "agent.cli":
                bad.append(f"{path.relative_to(root)}:{line}: agent imports groundstation")
    return sorted(set(bad))


def test_every_import_points_down() -> None:
    assert violations(sources()) == []


def test_the_checker_catches_an_upward_import(tmp_path: Path) -> None:
    """A core module importing the runtime, and a runtime module importing the ground station,
    are both reported (so the test above can fail)."""
    core = tmp_path / "agent" / "core" / "probe.py"
    runtime = tmp_path / "agent" / "runtime" / "probe.py"
    core.parent.mkdir(parents=True)
    runtime.parent.mkdir(parents=True)
    core.write_text("from agent.runtime.shell.runtime import AgentRuntime\n")
    runtime.write_text("def f():\n    import groundstation.station\n")
    found = violations([core, runtime], tmp_path)
    assert len(found) == 3, found
    assert any("agent.core.probe (rank 0) imports agent.runtime.shell.runtime" in v for v in found)
    assert any("agent imports groundstation" in v for v in found)


@pytest.mark.parametrize("path", sources(), ids=lambda p: str(p.relative_to(ROOT)))
def test_module_is_small_or_says_why(path: Path) -> None:
    """A module over 400 lines states at its top why it is not split."""
    text = path.read_text(encoding="utf-8")
    if text.count("\n") > 400:
        head = text[:3000].lower()
        assert "not split" in head, f"{path.relative_to(ROOT)}: {text.count(chr(10))} lines"


def import_graph(files: list[Path], root: Path = ROOT) -> dict[str, set[str]]:
    """Module → the project modules it imports (lazy and ``TYPE_CHECKING`` ones included);
    ``from pkg import sub`` of a submodule is an edge to ``pkg.sub``, not to ``pkg``."""
    mods = {module_name(p, root): p for p in files}
    graph: dict[str, set[str]] = {m: set() for m in mods}
    for me, path in mods.items():
        found = [t for _, t in imports_of(path)]
        for target in found:
            subs = [x for x in found if x.startswith(target + ".") and x in mods]
            if target in mods and target != me and not subs:
                graph[me].add(target)
            graph[me].update(x for x in subs if x != me)
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Every set of modules that import each other in a circle (strongly connected
    components of more than one module), iteratively (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []
    for root in graph:
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on.add(root)
        while work:
            v, it = work[-1]
            w = next(it, None)
            if w is not None:
                if w not in index:
                    index[w] = low[w] = len(index)
                    stack.append(w)
                    on.add(w)
                    work.append((w, iter(sorted(graph[w]))))
                elif w in on:
                    low[v] = min(low[v], index[w])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[v])
            if low[v] == index[v]:
                comp = []
                while True:
                    x = stack.pop()
                    on.discard(x)
                    comp.append(x)
                    if x == v:
                        break
                if len(comp) > 1:
                    out.append(sorted(comp))
    return out


def test_no_import_cycle() -> None:
    """No two modules import each other, directly or around a circle, not even for type
    checking (the agent's parts once did: completion and membership)."""
    assert cycles(import_graph(sources())) == []


def test_the_cycle_checker_finds_a_circle(tmp_path: Path) -> None:
    """A circle of three modules is found, and a package importing its own submodule is
    not one."""
    pkg = tmp_path / "agent" / "runtime"
    pkg.mkdir(parents=True)
    (pkg / "__init__.py").write_text("from agent.runtime import a\n")
    (pkg / "a.py").write_text("from agent.runtime import b\n")
    (pkg / "b.py").write_text("if False:\n    from agent.runtime.c import X\n")
    (pkg / "c.py").write_text("def f():\n    from agent.runtime.a import Y\n")
    files = sorted(pkg.glob("*.py"))
    assert cycles(import_graph(files, tmp_path)) == [
        ["agent.runtime.a", "agent.runtime.b", "agent.runtime.c"]]
    (pkg / "c.py").write_text("X = 1\n")
    assert cycles(import_graph(files, tmp_path)) == []


#: The agent runtime's sub-package that is not its core: the runtime that carries the core's
#: effects out (transport, journal, the turn, sealing) and the pose sources (adapters of the
#: vehicle).
RUNTIME_SHELL = "agent.runtime.shell"
#: What the agent core may not import: transports, storage, threads, the wall clock, files.
IMPURE = ("agent.net.transport", "agent.net.memory", "agent.net.session", "agent.storage",
          "agent.flight", "threading", "time", "os", "socket", "zenoh", "pymavlink", "subprocess")


def impure_imports(files: list[Path], root: Path = ROOT) -> list[str]:
    """Imports of :data:`IMPURE` modules by the agent core (``agent.runtime`` but the shell)."""
    bad = []
    for path in files:
        me = module_name(path, root)
        if not me.startswith("agent.runtime.") or me.startswith(RUNTIME_SHELL + "."):
            continue
        lines: set[int] = set()
        for line, target in imports_of(path):  # the module first, then the names it gives
            if line not in lines and any(target == m or target.startswith(m + ".")
                                         for m in IMPURE):
                lines.add(line)
                bad.append(f"{path.relative_to(root)}:{line}: the agent core imports {target}")
    return sorted(set(bad))


def test_the_agent_core_does_no_io() -> None:
    """The agent core (``step(event) -> effects``) imports no transport, journal, thread or
    clock of its own: the runtime does the I/O."""
    assert impure_imports(sources()) == []


def test_the_purity_checker_catches_a_journal_in_the_core(tmp_path: Path) -> None:
    part = tmp_path / "agent" / "runtime" / "part.py"
    part.parent.mkdir(parents=True)
    part.write_text("import threading\nfrom agent.storage.journal import Journal\n")
    shell = tmp_path / "agent" / "runtime" / "shell" / "runtime.py"
    shell.parent.mkdir()
    shell.write_text("import threading\n")
    assert impure_imports([part, shell], tmp_path) == [
        "agent/runtime/part.py:1: the agent core imports threading",
        "agent/runtime/part.py:2: the agent core imports agent.storage.journal",
    ]


#: How the agent core's parts name its shared state (:class:`agent.runtime.core.shared.Shared`).
SHARED_REFS = {"s", "shared", "self.s", "self.shared", "core.shared", "rt.shared",
               "self.core.shared"}


def _dotted(node: ast.expr) -> str | None:
    """``a.b.c`` of a Name / Attribute chain, else None."""
    if isinstance(node, ast.Name):
        return node.id
    if isinstance(node, ast.Attribute) and (base := _dotted(node.value)) is not None:
        return f"{base}.{node.attr}"
    return None


def shared_writes(files: list[Path], root: Path = ROOT) -> list[str]:
    """Assignments to an attribute (or an item of one) of the core's shared state outside
    ``agent/runtime/core/shared.py``: each change goes through a named method of ``Shared``."""
    bad = []
    for path in files:
        if path.name == "shared.py":
            continue
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            targets: list[ast.expr] = []
            if isinstance(node, ast.Assign):
                targets = list(node.targets)
            elif isinstance(node, ast.AugAssign | ast.AnnAssign):
                targets = [node.target]
            flat = [e for t in targets for e in (t.elts if isinstance(t, ast.Tuple) else [t])]
            for t in flat:
                if isinstance(t, ast.Subscript):
                    t = t.value
                if isinstance(t, ast.Attribute) and _dotted(t.value) in SHARED_REFS:
                    bad.append(f"{path.relative_to(root)}:{t.lineno}: assigns "
                               f"{_dotted(t.value)}.{t.attr}")
    return sorted(bad)


def test_the_cores_parts_change_its_shared_state_only_through_its_methods() -> None:
    """No blackboard: no part of the agent core (nor a runner) assigns the shared state's
    attributes; each change is a named method of ``Shared`` (publish_soon, begin_offer,
    enter_stage, ...), so every write can be found from one file."""
    files = [p for d in ("runtime", "runners", "mission", "testing")
             for p in sorted((ROOT / "agent" / d).rglob("*.py"))]
    assert shared_writes(files) == []


def test_the_shared_state_checker_catches_a_write(tmp_path: Path) -> None:
    part = tmp_path / "part.py"
    part.write_text("def f(s, self):\n    s.dirty = True\n    self.s.goals['t'] = 1\n"
                    "    s.a, s.b = 1, 2\n    s.counters.busy += 1\n    s.count(1)\n")
    assert shared_writes([part], tmp_path) == [
        "part.py:2: assigns s.dirty", "part.py:3: assigns self.s.goals",
        "part.py:4: assigns s.a", "part.py:4: assigns s.b"]
