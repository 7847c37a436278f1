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
    "agent.wire": 1,
    "agent.protocol": 2, "agent.config": 2, "agent.structure": 2, "agent.strategy": 2,
    "agent.net": 3, "agent.storage": 3, "agent.world": 3,
    "agent.flight": 4,
    "agent.runtime": 5, "agent.sim": 5,  # same rank: neither imports the other
    "agent.mission": 6,
    "agent.runners": 7, "agent.testing": 7,
    "agent.commands": 8,
    "agent.cli": 9,
    "groundstation": 10,
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
    return sorted(p for d in ("agent", "groundstation") for p in (ROOT / d).rglob("*.py"))


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
    core.write_text("from agent.runtime.agent import AgentRuntime\n")
    runtime.write_text("def f():\n    import groundstation.station\n")
    found = violations([core, runtime], tmp_path)
    assert len(found) == 3, found
    assert any("agent.core.probe (rank 0) imports agent.runtime.agent" in v for v in found)
    assert any("agent imports groundstation" in v for v in found)


@pytest.mark.parametrize("path", sources(), ids=lambda p: str(p.relative_to(ROOT)))
def test_module_is_small_or_says_why(path: Path) -> None:
    """A module over 400 lines states at its top why it is not split."""
    text = path.read_text(encoding="utf-8")
    if text.count("\n") > 400:
        head = text[:3000].lower()
        assert "not split" in head, f"{path.relative_to(ROOT)}: {text.count(chr(10))} lines"
