"""A Zenoh router run from Python (``zenohd`` is not packaged on PyPI).

``run_router(config_path)`` opens a session in router mode from a json5 file and blocks until
SIGINT/SIGTERM (or a ``stop_event``); ``viscover router --config FILE`` does the same from a
shell. On its own session it keeps every mission's fence record
(:class:`agent.net.keeper.FenceKeeper`): the team's final word for a drone that comes back
after the others left, answered on ``viscover/<m>/fences``. :func:`start_router_process`
starts one on a free loopback TCP port for tests and benchmarks (the open lab profile, or the
secured one of a team directory, :mod:`agent.net.security`).
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from types import FrameType
from typing import Any

import zenoh

from agent.net.keeper import FenceKeeper
from agent.net.security import TeamDir, router_config

_log = logging.getLogger(f"viscover.{__name__}")

#: Printed on stdout once the router session is open, followed by the listen endpoints.
READY_LINE = "viscover-router ready"


def run_router(
    config_path: str | Path,
    ready_event: threading.Event | None = None,
    *,
    stop_event: threading.Event | None = None,
    listen: list[str] | None = None,
    state_dir: Path | None = None,
) -> None:
    """Open a Zenoh router from ``config_path`` (json5) and block until stopped.

    Stops on SIGINT/SIGTERM when called from the main thread, or when ``stop_event`` is set.
    ``ready_event`` is set once the session is open. The config's ``mode`` is forced to
    ``"router"``; ``listen`` (endpoints) replaces the config's listen endpoints;
    ``state_dir`` keeps the fence record across restarts (:mod:`agent.net.keeper_store`).
    """
    config = zenoh.Config.from_file(str(config_path))
    config.insert_json5("mode", '"router"')
    if listen:
        config.insert_json5("listen/endpoints", json.dumps(listen))
    stop = stop_event if stop_event is not None else threading.Event()
    previous: dict[int, Any] = {}
    if threading.current_thread() is threading.main_thread():

        def _on_signal(signum: int, _frame: FrameType | None) -> None:
            stop.set()

        for sig in (signal.SIGINT, signal.SIGTERM):
            previous[sig] = signal.signal(sig, _on_signal)
    try:
        with zenoh.open(config) as session:
            keeper = FenceKeeper(session, state_dir=state_dir)
            endpoints = config.get_json("listen/endpoints")
            _log.info("router %s listening on %s", session.zid(), endpoints)
            print(f"{READY_LINE} {endpoints}", flush=True)
            if ready_event is not None:
                ready_event.set()
            try:
                while not stop.wait(0.2):
                    pass
            finally:
                keeper.close()
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)


def free_tcp_port(host: str = "127.0.0.1") -> int:
    """Return a TCP port that was free on ``host`` a moment ago."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.bind((host, 0))
        return int(sock.getsockname()[1])


def router_config_json(port: int, connect: list[str] | None = None, lease_ms: int = 1000,
                       team: TeamDir | None = None) -> str:
    """json5 text of a loopback router config listening on ``port``, linked to ``connect``;
    with ``team``, the secured profile (mutual TLS and access control) of that team."""
    if team is not None:
        return json.dumps(router_config(team, [f"tls/127.0.0.1:{port}"], list(connect or []),
                                        lease_ms=lease_ms), indent=2)
    cfg = {
        "mode": "router",
        "listen": {"endpoints": [f"tcp/127.0.0.1:{port}"]},
        "connect": {"endpoints": list(connect or [])},
        "scouting": {"multicast": {"enabled": False}, "gossip": {"enabled": False}},
        "transport": {"link": {"tx": {"lease": lease_ms, "keep_alive": 4}}},
    }
    return json.dumps(cfg, indent=2)


def client_config(
    endpoints: list[str] | str, lease_ms: int = 1000, mode: str = "client"
) -> zenoh.Config:
    """A client-mode ``zenoh.Config`` connecting to ``endpoints``, scouting off."""
    eps = [endpoints] if isinstance(endpoints, str) else list(endpoints)
    cfg = {
        "mode": mode,
        "connect": {"endpoints": eps},
        "scouting": {"multicast": {"enabled": False}, "gossip": {"enabled": False}},
        "transport": {"link": {"tx": {"lease": lease_ms, "keep_alive": 4}}},
    }
    return zenoh.Config.from_json5(json.dumps(cfg))


def _wait_port(host: str, port: int, proc: subprocess.Popen[bytes], timeout_s: float) -> None:
    deadline = time.monotonic() + timeout_s
    while True:
        if proc.poll() is not None:
            raise RuntimeError(f"router process exited early with code {proc.returncode}")
        try:
            with socket.create_connection((host, port), timeout=0.2):
                return
        except OSError:
            if time.monotonic() > deadline:
                raise TimeoutError(f"router on {host}:{port} not up in {timeout_s} s") from None
            time.sleep(0.02)


def start_router_process(
    port: int | None = None,
    *,
    connect: list[str] | None = None,
    lease_ms: int = 1000,
    timeout_s: float = 15.0,
    log_level: str = "WARNING",
    new_session: bool = False,
    team: TeamDir | None = None,
    state_dir: Path | None = None,
) -> tuple[subprocess.Popen[bytes], str]:
    """Start ``viscover router`` on loopback; return ``(process, endpoint)``.

    ``port`` None or 0 picks a free port. ``connect`` lists endpoints of routers to link to.
    ``team``: the secured profile of that team directory (endpoint ``tls/localhost:PORT``).
    ``new_session`` puts it in its own session (a terminal's Ctrl-C does not reach it).
    ``state_dir``: where it keeps the fence record (``--state-dir``).
    Waits until the router accepts TCP connections (at most ``timeout_s`` seconds). The
    caller stops it with :func:`stop_router_process`.
    """
    port = port or free_tcp_port()
    with tempfile.NamedTemporaryFile(
        "w", suffix=".json5", prefix="viscover-router-", delete=False
    ) as fh:
        fh.write(router_config_json(port, connect, lease_ms, team))
        path = fh.name
    repo_root = Path(__file__).resolve().parents[2]
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(repo_root), env.get("PYTHONPATH")]))
    proc = subprocess.Popen(
        [sys.executable, "-m", "agent.cli", "router", "--config", path, "--log-level", log_level,
         *(["--state-dir", str(state_dir)] if state_dir is not None else [])],
        stdout=subprocess.DEVNULL,
        env=env,
        start_new_session=new_session,
    )
    try:
        _wait_port("127.0.0.1", port, proc, timeout_s)
    except BaseException:
        stop_router_process(proc)
        raise
    finally:
        with contextlib.suppress(OSError):
            os.unlink(path)  # read at start-up; the listening socket proves it was read
    return proc, f"tcp/127.0.0.1:{port}" if team is None else f"tls/localhost:{port}"


def stop_router_process(proc: subprocess.Popen[bytes], timeout_s: float = 5.0) -> int:
    """SIGTERM the router, wait up to ``timeout_s`` seconds, then SIGKILL. Returns the code."""
    if proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(timeout_s)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(timeout_s)
    return int(proc.returncode)
