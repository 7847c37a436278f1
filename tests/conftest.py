"""Shared test fixtures: repository paths, a Zenoh router on a free loopback port, the
environment of a subprocess that runs this checkout, and a polling wait."""

from __future__ import annotations

import os
import subprocess
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import TypeVar

import pytest

from agent.net.router import start_router_process, stop_router_process

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
