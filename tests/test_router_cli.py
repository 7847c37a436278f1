"""``viscover router``: --listen overrides the config, and a port already in use is one line
naming the endpoint and the fix."""

from __future__ import annotations

import json
import socket
import subprocess
import sys
from pathlib import Path

from agent.net.router import READY_LINE, free_tcp_port
from tests.conftest import reap, repo_env


def _config(tmp_path: Path, port: int) -> Path:
    path = tmp_path / "r.json5"
    path.write_text(json.dumps({"mode": "router",
                                "listen": {"endpoints": [f"tcp/127.0.0.1:{port}"]},
                                "scouting": {"multicast": {"enabled": False}}}))
    return path


def _router(*args: str) -> subprocess.Popen[str]:
    return subprocess.Popen([sys.executable, "-m", "agent.cli", "router", *args],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=repo_env())


def test_port_in_use_is_one_line(tmp_path: Path) -> None:
    with socket.socket() as held:
        held.bind(("127.0.0.1", 0))
        held.listen()
        port = held.getsockname()[1]
        proc = _router("--config", str(_config(tmp_path, port)))
        _out, err = proc.communicate(timeout=30)
    assert proc.returncode == 2
    assert err == (f"viscover: error: router: tcp/127.0.0.1:{port} is already in use "
                   "(another router?): stop it, or listen elsewhere with --listen "
                   "tcp/0.0.0.0:PORT\n")


def test_listen_replaces_the_configured_endpoints(tmp_path: Path) -> None:
    busy, free = free_tcp_port(), free_tcp_port()
    proc = _router("--config", str(_config(tmp_path, busy)), "--listen",
                   f"tcp/127.0.0.1:{free}")
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline()
        assert line.startswith(READY_LINE) and f"tcp/127.0.0.1:{free}" in line
        assert f":{busy}" not in line
        with socket.create_connection(("127.0.0.1", free), timeout=5):
            pass
    finally:
        reap([proc])
