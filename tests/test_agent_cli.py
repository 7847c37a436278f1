"""The router/agent/observe subcommands (through ``viscover``): user mistakes are one line
on stderr, exit 2."""

from __future__ import annotations

from pathlib import Path

import pytest

from agent.cli import main
from tests.agent_helpers import ROOT

HEX = str(ROOT / "scenarios" / "hexagon_5_3.toml")


@pytest.mark.parametrize("argv", [
    ["agent", "--id", "Z", "--scenario", HEX],
    ["agent", "--id", "A", "--scenario", "/nonexistent/x.toml"],
    ["agent", "--id", "A", "--scenario", HEX, "--drop", "1.5"],
    ["agent", "--id", "A", "--scenario", HEX, "--drop-kind", "trade"],
    ["agent", "--id", "A", "--scenario", HEX, "--rate-scale", "0"],
    ["agent", "--id", "A", "--scenario", HEX, "--mission", "bad/name"],
    ["agent", "--id", "A", "--scenario", HEX, "--partition", "B/C"],
    ["agent", "--id", "A", "--scenario", HEX, "--zenoh", "/nonexistent.json5"],
    ["observe", "--scenario", "/nonexistent/x.toml"],
    ["observe", "--scenario", HEX, "--json-out", "/nonexistent/dir/out.json"],
    ["router", "--config", "/nonexistent.json5"],
    ["agent", "--scenario", HEX],
])
def test_user_mistakes_exit_2_one_line(argv: list[str], tmp_path: Path,
                                       capsys: pytest.CaptureFixture[str]) -> None:
    if argv[0] == "agent" and "--state-dir" not in argv:
        argv = [*argv, "--state-dir", str(tmp_path / "state")]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err and "Traceback" not in "\n".join(err)
    assert err[-1].startswith(("viscover: error:", "viscover agent: error:", "usage:")) or \
        "error:" in err[-1]


def test_second_agent_with_same_state_dir_is_refused(tmp_path: Path,
                                                     capsys: pytest.CaptureFixture[str]) -> None:
    from agent.storage.journal import Journal

    j = Journal(tmp_path / "A")
    try:
        code = main(["agent", "--id", "A", "--scenario", HEX, "--state-dir", str(tmp_path / "A"),
                     "--connect", "tcp/127.0.0.1:1"])
    finally:
        j.close()
    assert code == 2
    assert "in use" in capsys.readouterr().err


def test_journal_of_an_incompatible_build_is_a_usage_error(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    import struct
    import zlib

    import msgspec

    from agent.net.router import start_router_process, stop_router_process

    state = tmp_path / "A"
    state.mkdir()
    alien = msgspec.msgpack.encode({"rec": "genesis", "agent": "A", "owned": {"1": 0}})
    frame = struct.pack("<II", len(alien), zlib.crc32(alien)) + alien
    (state / "journal.bin").write_bytes(frame)
    proc, ep = start_router_process()
    try:
        code = main(["agent", "--id", "A", "--scenario", HEX, "--state-dir", str(state),
                     "--connect", ep, "--timeout", "5"])
    finally:
        stop_router_process(proc)
    err = capsys.readouterr().err
    assert code == 2 and "incompatible" in err and "Traceback" not in err
    assert (state / "journal.bin").read_bytes() == frame  # left as it was
