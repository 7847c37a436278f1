"""The documentation holds: README.md stays a one-sitting read; every relative link of
README.md and docs/*.md resolves (to a file, and to a heading for ``#anchor`` links, by
GitHub's slug rules); every repository path written in backticks exists; the README's command
table names every command and only options it has; its architecture table names only modules
that exist, at the ranks ``tests/test_layers.py`` enforces; docs/flying.md holds the pre-flight
table the rules generate; and the recipes of docs/extending.md run as written."""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from agent.cli import COMMANDS, build_parser, main
from agent.config.parse import load_scenario
from agent.flight.preflight import readme_table
from agent.world.structure import resolve_structure
from tests.conftest import ROOT
from tests.test_layers import RANKS

README = ROOT / "README.md"
DOCS = ROOT / "docs"
MAX_README_LINES = 400

#: Pages other changes are writing: links and paths to them may dangle while they are missing
#: (once a file exists, it is checked like any other). Remove an entry when its page lands.
PENDING: frozenset[str] = frozenset()

#: Files the recipes of docs/extending.md tell the reader to create (the recipe tests create
#: exactly these, under a temporary root), so they are not in the repository.
WRITTEN_BY_RECIPES = frozenset({"scenarios/my_box.toml", "scenarios/meshes/my_shed.stl",
                                "scenarios/my_shed.toml",
                                "agent/runtime/moves/pause_after_trade.py",
                                "tests/test_pause_after_trade.py"})

#: Top-level folders whose paths written in backticks must exist.
PATH_ROOTS = ("agent", "groundstation", "bench", "tests", "scenarios", "deploy",
              "broker_config", "docs")

FENCE = re.compile(r"^ {0,3}(```|~~~).*?^ {0,3}\1[^\n]*$", re.M | re.S)
HEADING = re.compile(r"^ {0,3}#{1,6}\s+(.+?)\s*#*\s*$", re.M)
LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)(?:\s+\"[^\"]*\")?\)")
CODE_SPAN = re.compile(r"`([^`]+)`")
SCHEME = re.compile(r"^[a-zA-Z][a-zA-Z0-9+.-]*:")
RECIPE = re.compile(r"^<!-- recipe: ([\w-]+) -->\n```\w*\n(.*?)^```$", re.M | re.S)
#: A block of docs/behaviours.md: the file it goes to, and the code.
BEHAVIOUR = re.compile(r"^<!-- behaviour: ([\w./-]+) -->\n```\w*\n(.*?)^```$", re.M | re.S)


def pages() -> list[Path]:
    return [README, *sorted(DOCS.glob("*.md"))]


def prose(text: str) -> str:
    """``text`` without its fenced code blocks (each line blanked: line numbers stay)."""
    return FENCE.sub(lambda m: "\n" * m.group(0).count("\n"), text)


def slug(heading: str) -> str:
    """GitHub's anchor of a heading: lowercase, punctuation but '-' and '_' dropped, spaces
    to '-'."""
    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


def anchors(text: str) -> set[str]:
    """Every heading anchor of a page (repeated headings get -1, -2, ... as on GitHub)."""
    seen: dict[str, int] = {}
    out = set()
    for m in HEADING.finditer(prose(text)):
        s = slug(m.group(1))
        out.add(s if s not in seen else f"{s}-{seen[s]}")
        seen[s] = seen.get(s, 0) + 1
    return out


def broken_links(page: Path, root: Path = ROOT) -> list[str]:
    """Each relative link of ``page`` that names no file, or no heading of its file."""
    bad, root = [], root.resolve()
    for target in LINK.findall(prose(page.read_text(encoding="utf-8"))):
        if SCHEME.match(target):
            continue  # http(s), mailto: not checked here
        path, _, anchor = target.partition("#")
        dest = (page.parent / path).resolve() if path else page
        rel = dest.relative_to(root).as_posix() if dest.is_relative_to(root) else str(dest)
        if not dest.exists():
            if rel not in PENDING:
                bad.append(f"{target}: no file {rel}")
            continue
        if anchor and dest.suffix == ".md" and anchor not in anchors(dest.read_text("utf-8")):
            bad.append(f"{target}: no heading #{anchor} in {rel}")
    return bad


def backticked_paths(text: str) -> list[str]:
    """Repository paths written in backticks: words under one of :data:`PATH_ROOTS`."""
    out = []
    for span in CODE_SPAN.findall(prose(text)):
        for word in re.split(r"[\s,;()=\"'\[\]]+", span):
            word = word.rstrip(".:")
            if word.split("/")[0] in PATH_ROOTS and "/" in word and not re.search(r"[<>{}]|\.\.\.",
                                                                                  word):
                out.append(word)
    return out


def missing_paths(page: Path, root: Path = ROOT) -> list[str]:
    """The backticked repository paths of ``page`` that name nothing (globs: no match)."""
    skip = PENDING | WRITTEN_BY_RECIPES
    return [p for p in backticked_paths(page.read_text(encoding="utf-8"))
            if p.rstrip("/") not in skip
            and not (any(root.glob(p)) if "*" in p else (root / p).exists())]


def recipes() -> dict[str, str]:
    """{name: code} of every fenced block right after a ``<!-- recipe: NAME -->`` line of
    docs/extending.md."""
    return dict(RECIPE.findall((DOCS / "extending.md").read_text(encoding="utf-8")))


# --- the checkers themselves -------------------------------------------------------------

def test_slugs_follow_github() -> None:
    assert slug("Outdoors: GNSS/RTK, the mission origin, the fence") == \
        "outdoors-gnssrtk-the-mission-origin-the-fence"
    assert slug('Coverage beyond the thesis: `strategy = "potential"`') == \
        "coverage-beyond-the-thesis-strategy--potential"
    assert slug("The team's final word") == "the-teams-final-word"
    assert slug("4. Flight controller") == "4-flight-controller"
    assert slug("snake_case and-dash") == "snake_case-and-dash"
    assert anchors("# A\n## A\n```sh\n# not a heading\n```\n") == {"a", "a-1"}


def test_the_link_checker_catches_a_dangling_link(tmp_path: Path) -> None:
    (tmp_path / "docs").mkdir()
    (tmp_path / "docs" / "b.md").write_text("# Here\n", encoding="utf-8")
    page = tmp_path / "docs" / "a.md"
    page.write_text("# Top\n[ok](b.md#here) [self](#top) [web](https://x.org/y) "
                    "\n[gone](c.md) [no anchor](b.md#there) "
                    "[no\nself](#nowhere)\n```md\n[in code](d.md)\n```\n", encoding="utf-8")
    assert broken_links(page, tmp_path) == ["c.md: no file docs/c.md",
                                            "b.md#there: no heading #there in docs/b.md",
                                            "#nowhere: no heading #nowhere in docs/a.md"]


def test_the_path_checker_catches_a_missing_path(tmp_path: Path) -> None:
    (tmp_path / "agent" / "core").mkdir(parents=True)
    (tmp_path / "agent" / "core" / "vision.py").write_text("", encoding="utf-8")
    page = tmp_path / "x.md"
    page.write_text("`agent/core/vision.py`, `viscover x --config agent/core/`, "
                    "`agent/core/*.py`\n`agent/sim/strategy.py` and `agent/core/*.toml`, "
                    "`scenarios/<name>.toml`\n", encoding="utf-8")
    assert missing_paths(page, tmp_path) == ["agent/sim/strategy.py", "agent/core/*.toml"]


# --- the pages ----------------------------------------------------------------------------

def test_readme_is_read_in_one_sitting() -> None:
    lines = README.read_text(encoding="utf-8").count("\n")
    assert lines <= MAX_README_LINES, f"README.md has {lines} lines; move detail to docs/"


@pytest.mark.parametrize("page", pages(), ids=lambda p: p.name)
def test_every_relative_link_resolves(page: Path) -> None:
    assert broken_links(page) == []


@pytest.mark.parametrize("page", pages(), ids=lambda p: p.name)
def test_every_backticked_repository_path_exists(page: Path) -> None:
    assert missing_paths(page) == []


def test_pending_pages_are_linked_from_extending() -> None:
    """The allow-list names pages the docs link to, nothing else."""
    text = (DOCS / "extending.md").read_text(encoding="utf-8")
    assert all(f"]({Path(p).name})" in text for p in PENDING)


def _options(parser: argparse.ArgumentParser, names: list[str]) -> set[str]:
    """The option strings of the subcommand ``names`` (e.g. ["scenario", "check"])."""
    for name in names:
        subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
        parser = subs[0].choices[name]
    return {o for a in parser._actions for o in a.option_strings}


def test_command_table_names_every_command_and_only_its_options() -> None:
    text = README.read_text(encoding="utf-8")
    rows = re.findall(r"^\| `viscover ([^`]+)` \|", text, re.M)
    named = []
    for row in rows:
        name = next(c for c in sorted(COMMANDS, key=len, reverse=True)
                    if row == c or row.startswith(f"{c} "))
        words = [name, "check"] if name == "scenario" else [name]
        named.append(name)
        flags = set(re.findall(r"(?<![\w-])--[a-z][a-z0-9-]*", row))
        unknown = flags - _options(build_parser([name]), words)
        assert not unknown, f"viscover {name}: no option {sorted(unknown)}"
    assert sorted(named) == sorted(COMMANDS)


def test_architecture_table_names_modules_that_exist_at_their_ranks() -> None:
    text = README.read_text(encoding="utf-8").split("## Architecture", 1)[1]
    rows = re.findall(r"^\| (\d+) \| `([^`]+)` \| (.*) \|$", text, re.M)
    assert rows, "no architecture table under '## Architecture'"
    units = set()
    for rank, folder, what in rows:
        base = ROOT / folder
        assert base.exists(), f"{folder}: no such file or folder"
        unit = folder.rstrip("/").removesuffix(".py").replace("/", ".")
        units.add(unit)
        assert RANKS.get(unit) == int(rank), f"{folder}: rank {rank}, test_layers says " \
                                              f"{RANKS.get(unit)}"
        for name in CODE_SPAN.findall(what):
            if not re.fullmatch(r"[\w*./-]+(\.py|/)", name):
                continue
            at = ROOT if name.split("/")[0] in PATH_ROOTS else base
            found = any(at.glob(name)) if "*" in name else (at / name).exists()
            assert base.is_dir() and found, f"{folder}: names {name}, which does not exist"
    assert set(RANKS) <= units, f"layers missing from the table: {sorted(set(RANKS) - units)}"


def test_flying_holds_the_preflight_table_the_rules_generate() -> None:
    assert readme_table() in (DOCS / "flying.md").read_text(encoding="utf-8")


# --- the recipes of docs/extending.md -----------------------------------------------------

def test_extending_has_its_recipes() -> None:
    assert set(recipes()) == {"scenario", "mesh", "structure"}


def test_scenario_recipe_loads_checks_and_trades_as_it_says(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "scenarios" / "my_box.toml"
    path.parent.mkdir()
    path.write_text(recipes()["scenario"], encoding="utf-8")
    sc = load_scenario(path)
    assert (sc.name, len(sc.landmark_ids), [a.id for a in sc.agents]) == ("my_box", 12, ["A", "B"])
    assert main(["scenario", "check", str(path)]) == 0
    assert "12 landmarks, 2 agents (A:7, B:5)" in capsys.readouterr().out
    out = tmp_path / "out"
    assert main(["simulate", str(path), "--out", str(out), "--no-plots", "--quiet"]) == 0
    result = json.loads((out / "result.json").read_text(encoding="utf-8"))
    assert result["complete"]
    assert [t["to_initiator"] + t["to_partner"] for t in result["trades"]] == [[1]]
    assert result["final_partition"] == {"A": [4, 5, 6, 10, 11, 12], "B": [1, 2, 3, 7, 8, 9]}


def test_mesh_and_structure_recipes_load_check_and_complete_as_they_say(
        tmp_path: Path, capsys: pytest.CaptureFixture[str],
        monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)  # the mesh recipe runs from the repository root
    (tmp_path / "scenarios" / "meshes").mkdir(parents=True)
    exec(compile(recipes()["mesh"], "docs/extending.md (recipe: mesh)", "exec"), {})
    assert (tmp_path / "scenarios" / "meshes" / "my_shed.stl").is_file()
    path = tmp_path / "scenarios" / "my_shed.toml"
    path.write_text(recipes()["structure"], encoding="utf-8")
    sc = resolve_structure(load_scenario(path))
    assert sc.structure is not None and len(sc.landmark_ids) == 27
    assert main(["scenario", "check", str(path)]) == 0
    said = capsys.readouterr().out
    assert "mesh: 1 part (1 closed); no repair needed" in said
    assert "inspection: 27/27 landmarks capturable at quality >= 0.3" in said
    out = tmp_path / "out"
    assert main(["simulate", str(path), "--out", str(out), "--no-plots", "--quiet"]) == 0
    inspection = json.loads((out / "result.json").read_text(encoding="utf-8"))["inspection"]
    assert len(inspection["captured"]) == inspection["capturable"] == 27
    assert inspection["verdict"].startswith("complete at t = ")


# --- the recipe of docs/behaviours.md ------------------------------------------------------

def _tree(root: Path) -> dict[str, bytes]:
    """The source files under ``root`` (agent, tests, bench, scenarios): path -> content."""
    return {p.relative_to(root).as_posix(): p.read_bytes()
            for d in ("agent", "tests", "bench", "scenarios") for p in (root / d).rglob("*")
            if p.is_file() and "__pycache__" not in p.parts}


def test_behaviour_recipe_adds_its_example_in_the_files_it_names_and_passes(
        tmp_path: Path) -> None:
    """docs/behaviours.md applied to a copy of the repository: its module and test are new
    files, its registration line goes into ``REGISTRY``; exactly those three files differ,
    and the example's test passes there (a real pytest run in that tree)."""
    blocks = BEHAVIOUR.findall((DOCS / "behaviours.md").read_text(encoding="utf-8"))
    files = [f for f, _ in blocks]
    assert files == ["agent/runtime/moves/pause_after_trade.py", "agent/strategy/registry.py",
                     "tests/test_pause_after_trade.py"]
    root = tmp_path / "repo"
    for d in ("agent", "tests", "bench", "scenarios"):
        shutil.copytree(ROOT / d, root / d, ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copy(ROOT / "pyproject.toml", root)
    for name, code in blocks:
        path = root / name
        if path.exists():  # the registration line, last in the registry
            text = path.read_text(encoding="utf-8")
            end = text.index("\n)}\n")
            path.write_text(text[:end] + "\n" + code.rstrip("\n") + text[end:], "utf-8")
        else:
            path.write_text(code, encoding="utf-8")
    before, after = _tree(ROOT), _tree(root)
    changed = sorted(k for k in after if before.get(k) != after[k])
    assert changed == sorted(files) and set(before) <= set(after)
    run = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
                          "tests/test_pause_after_trade.py"], cwd=root, capture_output=True,
                         text=True, timeout=240, env={**os.environ, "PYTHONPATH": str(root)})
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-3000:]
    assert "1 passed" in run.stdout
