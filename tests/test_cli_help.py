"""``viscover --help`` and the README agree: the version from the installed package; every
option the README's command table writes outside brackets is required by the command (and
its ``--help`` usage shows it so: not in brackets), and every option a command requires is
written so in the README; every command takes ``--log-level`` and the network options the
README promises; every option says what it is for; a required option missing is one line."""

from __future__ import annotations

import argparse
import re
from importlib import metadata

import pytest

from agent.cli import COMMANDS, build_parser, main
from tests.conftest import ROOT

README = (ROOT / "README.md").read_text(encoding="utf-8")
ROW = re.compile(r"^\| `viscover ([^`]+)` \|", re.M)
FLAG = re.compile(r"(?<![\w-])--[a-z][a-z0-9-]*")
NETWORK = ("--connect", "--zenoh", "--connect-wait", "--mission", "--tls-dir", "--identity")


def _leaves(parser: argparse.ArgumentParser) -> list[argparse.ArgumentParser]:
    """The parsers of the commands under ``parser`` that run something."""
    subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    if not subs:
        return [parser]
    return [leaf for s in subs for p in dict.fromkeys(s.choices.values()) for leaf in _leaves(p)]


def _command(row: str) -> str:
    return next(c for c in sorted(COMMANDS, key=len, reverse=True)
                if row == c or row.startswith(f"{c} "))


def _parser(name: str) -> argparse.ArgumentParser:
    """The parser of command ``name`` (``scenario``: ``scenario check``)."""
    (leaf,) = [p for p in _leaves(build_parser([name]))
               if p.prog.split()[1] == name]
    return leaf


def _unbracketed(text: str) -> str:
    """``text`` without its ``[...]`` parts (nested too)."""
    out, depth = [], 0
    for ch in text:
        depth += ch == "["
        if depth == 0:
            out.append(ch)
        depth -= ch == "]" and depth > 0
    return "".join(out)


def _required(p: argparse.ArgumentParser) -> set[str]:
    """The options ``p`` requires: alone, or one of a required group."""
    req = {o for a in p._actions if a.required for o in a.option_strings}
    for g in p._mutually_exclusive_groups:
        if g.required:
            req |= {o for a in g._group_actions for o in a.option_strings}
    return req


def test_version_is_the_installed_packages(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["--version"]) == 0
    assert capsys.readouterr().out == f"viscover {metadata.version('viscover')}\n"


@pytest.mark.parametrize("row", ROW.findall(README), ids=lambda r: r.split()[0])
def test_readme_writes_required_options_as_help_does(row: str) -> None:
    name = _command(row)
    p = _parser(name)
    written = set(FLAG.findall(_unbracketed(row)))
    assert written == _required(p), f"viscover {name}: README {sorted(written)}, " \
        f"--help {sorted(_required(p))}"
    usage = _unbracketed(p.format_usage())
    assert all(re.search(rf"(?<![\w-]){o}(?![\w-])", usage) for o in _required(p)), usage
    assert set(FLAG.findall(row)) <= set(p._option_string_actions)


def test_every_command_takes_log_level_and_says_what_each_option_is() -> None:
    assert "every\ncommand logs under the `viscover` logger (`--log-level`)" in README
    for p in _leaves(build_parser()):
        assert "--log-level" in p._option_string_actions, p.prog
        quiet = [a.option_strings for a in p._actions if a.option_strings and not a.help]
        assert quiet == [], f"{p.prog}: no help text for {quiet}"
        if "--connect" in p._option_string_actions:  # a network command, as README says
            assert set(NETWORK) <= set(p._option_string_actions), p.prog


def test_mocap_host_says_what_it_is() -> None:
    help_text = _parser("groundstation")._option_string_actions["--mocap-host"].help
    assert help_text == ("motioncapture source: the host (name or IP address) of the motion "
                         "capture server (default: flight.mocap.host of the flight file)")


@pytest.mark.parametrize(("argv", "line"), [
    (["groundstation", "--scenario", "s.toml"],
     "viscover: error: --source is required: sim (simulated vehicles, rehearsals) or "
     "motioncapture (real drones); the systemd unit takes it from VISCOVER_GS_SOURCE in "
     "/etc/viscover/viscover.env\n"),
    (["export-plan", "run"],
     "viscover: error: --origin LAT,LON,ALT is required: the scenario carries no geodetic "
     "origin (latitude, longitude [degrees] and altitude [m] of its (0, 0, 0))\n"),
    (["record", "--scenario", "s.toml"],  # argparse's own, for an option without a line
     "viscover record: error: the following arguments are required: --out\n"),
])
def test_a_required_option_missing_is_one_line(argv: list[str], line: str,
                                               capsys: pytest.CaptureFixture[str]) -> None:
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.splitlines()[-1] + "\n" == line
    if argv[0] != "record":
        assert err == line
