"""Agent start-up: from process start to its first published state, N agents started together.

Real ``viscover agent`` processes (kinematic) on a real Zenoh router on loopback, started all at
once as a launch does (the swarm scene of :func:`bench.bench_trade.swarm_scene_toml`). An
in-bench subscriber on ``viscover/<m>/state/*`` notes when each agent's first state arrives;
the time from that agent's ``Popen`` to it is its start-up. One JSON line per size
(``"bench": "agent_startup"``): median and worst over the agents, the time to import the
agent command alone in a fresh interpreter (``import_s``, median of 3), and the 1-minute load
average at the end (12-20 Python processes starting on a shared 2-core machine compete for the
CPU: the start-up of each is mostly the CPU time of its imports and of building its runtime).

Run: ``python -m bench.bench_startup [--sizes 1,12,20] [--reps N] [--tree DIR]`` (``--tree``:
start the agents of another checkout, e.g. an older commit unpacked with ``git archive``, to
compare under the same load).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any, TextIO

from agent.net.router import client_config, start_router_process, stop_router_process
from agent.net.transport import ZenohTransport
from agent.wire import keys
from bench.bench_trade import swarm_scene_toml

ROOT = Path(__file__).resolve().parents[1]
SIZES = (1, 12, 20)
#: the checkout whose agents are started (``--tree``)
TREE = [ROOT]


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(TREE[0]), env.get("PYTHONPATH")]))
    return env


def import_time(reps: int = 3) -> float:
    """Median wall time [s] of importing the agent command in a fresh interpreter."""
    times = []
    for _ in range(reps):
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-c", "import agent.commands.agent"], check=True,
                       env=_env(), cwd=TREE[0])
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def startup(n_agents: int, n_landmarks: int = 200, timeout_s: float = 120.0) -> dict[str, Any]:
    """Start ``n_agents`` agents together; seconds from each one's start to its first state."""
    tmp = Path(tempfile.mkdtemp(prefix="viscover-startup-"))
    scen = tmp / "swarm.toml"
    scen.write_text(swarm_scene_toml(n_agents, n_landmarks))
    mission = f"startup{n_agents}"
    router, ep = start_router_process()
    tp = ZenohTransport(client_config(ep), None, "bench-startup")
    first: dict[str, float] = {}
    lock = threading.Lock()

    def on_state(key: str, _payload: bytes) -> None:
        aid = keys.try_agent_of(key)
        with lock:
            if aid is not None and aid not in first:
                first[aid] = time.monotonic()

    sub = tp.subscribe(keys.all_agents(mission, "state"), on_state)
    started: dict[str, float] = {}
    procs: list[subprocess.Popen[str]] = []
    try:
        for i in range(n_agents):
            aid = f"N{i}"
            cmd = [sys.executable, "-m", "agent.cli", "agent", "--id", aid, "--scenario",
                   str(scen), "--connect", ep, "--mission", mission, "--state-dir",
                   str(tmp / aid), "--rate-scale", "10", "--timeout", str(timeout_s)]
            started[aid] = time.monotonic()
            procs.append(subprocess.Popen(cmd, stdout=subprocess.DEVNULL,
                                          stderr=subprocess.DEVNULL, text=True, env=_env(),
                                          cwd=TREE[0]))
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            with lock:
                if len(first) == n_agents:
                    break
            time.sleep(0.01)
    finally:
        for p in procs:
            if p.poll() is None:
                p.terminate()
        for p in procs:
            try:
                p.wait(15)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()
        sub.undeclare()
        tp.close()
        stop_router_process(router)
        shutil.rmtree(tmp, ignore_errors=True)
    times = sorted(first[a] - started[a] for a in first)
    return {"bench": "agent_startup", "agents": n_agents, "heard": len(times),
            "tree": "this" if TREE[0] == ROOT else str(TREE[0]),
            "first_state_s_median": round(statistics.median(times), 3) if times else None,
            "first_state_s_max": round(times[-1], 3) if times else None,
            "load_1min": round(os.getloadavg()[0], 2)}


def run(out: TextIO, sizes: tuple[int, ...] = SIZES, reps: int = 1) -> None:
    """One JSON line per size and repetition, then the import time."""
    for n in sizes:
        for _ in range(reps):
            out.write(json.dumps(startup(n)) + "\n")
            out.flush()
    out.write(json.dumps({"bench": "agent_import", "import_s": round(import_time(), 3),
                          "module": "agent.commands.agent"}) + "\n")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default=",".join(map(str, SIZES)))
    ap.add_argument("--reps", type=int, default=1)
    ap.add_argument("--tree", type=Path, default=ROOT, help="checkout whose agents start")
    args = ap.parse_args(argv)
    TREE[0] = args.tree.resolve()
    run(sys.stdout, tuple(int(x) for x in args.sizes.split(",")), args.reps)
    return 0


if __name__ == "__main__":
    sys.exit(main())
