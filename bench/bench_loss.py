"""Mission time against message loss (loss should cost little time).

Real agent processes (``viscover agent``, kinematic, ``--rate-scale 10``) on a real Zenoh
router on loopback, as :func:`bench.bench_trade.bench_swarm` starts them, fly the swarm scene
of :func:`bench.bench_trade.swarm_scene_toml` (landmarks on a circle, 10 % of them dealt to
random agents so they must be traded across the swarm) at 0 / 10 / 30 / 50 % loss
(``--drop P``: every message, both directions, so a query and its reply each get lost with
probability P) until every agent has exited on completion.

One JSON line per cell (``"bench": "mission_time_vs_loss"``):

* ``wall_s``: from the first agent process started to the last one's result line (the
  mission is complete and the agent leaves; includes the processes' start-up, 4-40 s here,
  and the exit linger, 1.2 s), median over the cell's seeds;
* ``mission_s``: the same from the moment every agent has logged that it started (loss does
  not change the start-up, the machine's load does, a lot);
* ``ratio`` / ``ratio_mission``: over the lossless cell of the same size (same seeds);
* per agent (means): requests (tries), timeouts (tries that got no answer); trades per
  mission. A mission not complete within 300 s per agent, or with an agent still running 30 s
  after all the others finished, is reported ``complete: false`` with the agents' exit
  statuses and last complaints (``incomplete``).

Sizes: the issue's 4 x 100, 8 x 400 and 12 x 1,000, and 20 x 500 (``--issue``: the first
three only). Seeds: 2 for 4 and 8 drones, 1 for 12 and 20 (fewer for the big cells, so that the
whole run, 24 missions of 4-20 processes, takes ~15-18 min on a shared 2-core machine;
``--seeds N`` for more). Timings depend on the machine's load: each line carries the 1-minute
load average at its end, and the start-up of 12-20 Python processes on 2 cores varies by tens
of seconds, hence ``mission_s``; which trades happen (and how many) also varies from run to
run, loss or not.

``--legacy`` runs the agents with the legacy timing (``request_copies = 0``: one query per try
waiting the fixed ``request_timeout_s``, retried after the mission-time back-off;
``busy_pause = 0``), to compare under the same load (rows carry ``"mode": "legacy"``).

Run: ``python -m bench.bench_loss [--quick] [--issue] [--legacy] [--seeds N]
[--sizes 4x100,8x400] [--drops 0,0.3]`` (``make bench`` runs the default cells).
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

from agent.net.router import start_router_process, stop_router_process
from bench.bench_trade import swarm_scene_toml

ROOT = Path(__file__).resolve().parents[1]
RATE_SCALE = 10.0
DROPS = (0.0, 0.1, 0.3, 0.5)
SIZES = ((4, 100), (8, 400), (12, 1000), (20, 500))
ISSUE_SIZES = ((4, 100), (8, 400), (12, 1000))


def _emit(out: TextIO, rec: dict[str, Any]) -> dict[str, Any]:
    out.write(json.dumps(rec) + "\n")
    out.flush()
    return rec


def _seeds(n_agents: int, n: int | None = None) -> tuple[int, ...]:
    return tuple(range(1, n + 1)) if n else (1, 2) if n_agents <= 8 else (1,)


#: Agents still running this long [s] after the last result line are stopped (the mission is
#: complete for every other agent; one that never sees it waits for its --timeout otherwise).
STRAGGLER_GRACE_S = 30.0


def _wait_all(procs: list[subprocess.Popen[str]], finished: dict[int, float],
              lock: threading.Lock) -> list[int]:
    """Every process's exit status; stragglers (see :data:`STRAGGLER_GRACE_S`) get SIGTERM,
    then SIGKILL, and count as failed (their status is negative or non-zero)."""
    while any(p.poll() is None for p in procs):
        with lock:
            last = max(finished.values()) if finished else None
        if last is not None and time.monotonic() - last > STRAGGLER_GRACE_S:
            for p in procs:
                if p.poll() is None:
                    p.terminate()
            for p in procs:
                try:
                    p.wait(15.0)
                except subprocess.TimeoutExpired:
                    p.kill()
            break
        time.sleep(0.2)
    return [p.wait() for p in procs]


def run_mission(n_agents: int, n_landmarks: int, drop: float, seed: int = 1,
                rate_scale: float = RATE_SCALE, timeout_s: float = 300.0,
                extra_args: tuple[str, ...] = (), legacy: bool = False) -> dict[str, Any]:
    """One mission: a router and ``n_agents`` agent processes; wall times [s] and the agents'
    result lines. Agent ``i`` gets fault seed ``1000 * seed + i``. ``legacy``: the agents
    retry with the legacy timing (see the module docstring)."""
    tmp = Path(tempfile.mkdtemp(prefix="viscover-loss-"))
    scen = tmp / "swarm.toml"
    scen.write_text(swarm_scene_toml(n_agents, n_landmarks))
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(ROOT), env.get("PYTHONPATH")]))
    env.setdefault("OMP_NUM_THREADS", "1")
    env.setdefault("OPENBLAS_NUM_THREADS", "1")
    router, ep = start_router_process()
    procs: list[subprocess.Popen[str]] = []
    started: dict[int, float] = {}
    finished: dict[int, float] = {}
    results: dict[int, dict[str, Any]] = {}
    lock = threading.Lock()

    def pump_out(i: int, p: subprocess.Popen[str]) -> None:
        assert p.stdout is not None
        for line in p.stdout:
            if line.startswith("{"):
                with lock:
                    finished[i] = time.monotonic()
                    results[i] = json.loads(line)

    errors: dict[int, list[str]] = {}

    def pump_err(i: int, p: subprocess.Popen[str]) -> None:
        assert p.stderr is not None
        for line in p.stderr:
            if " started (mission" in line:
                with lock:
                    started.setdefault(i, time.monotonic())
            elif "WARNING" in line or "ERROR" in line or "Traceback" in line \
                    or line.startswith("viscover"):
                with lock:
                    errors.setdefault(i, []).append(line.rstrip()[:300])

    threads: list[threading.Thread] = []
    t0 = time.monotonic()
    try:
        for i in range(n_agents):
            entry = ["bench.bench_loss", LEGACY_AGENT] if legacy else ["agent.cli"]
            cmd = [sys.executable, "-m", *entry, "agent", "--id", f"N{i}",
                   "--scenario", str(scen), "--connect", ep, "--state-dir", str(tmp / f"N{i}"),
                   "--rate-scale", str(rate_scale), "--exit-on-complete",
                   "--timeout", str(timeout_s), "--log-level", "INFO", *extra_args]
            if drop > 0.0:
                cmd += ["--drop", str(drop), "--fault-seed", str(1000 * seed + i)]
            p = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                 text=True, env=env)
            procs.append(p)
            for fn in (pump_out, pump_err):
                th = threading.Thread(target=fn, args=(i, p), daemon=True)
                th.start()
                threads.append(th)
        codes = _wait_all(procs, finished, lock)
        for th in threads:
            th.join(5.0)
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
                p.wait()
        stop_router_process(router)
        shutil.rmtree(tmp, ignore_errors=True)
    res = [results[i] for i in sorted(results)]
    complete = len(res) == n_agents and all(c == 0 for c in codes)
    ready = max(started.values()) if len(started) == n_agents else t0
    last = max(finished.values()) if finished else time.monotonic()
    out: dict[str, Any] = {
        "complete": complete, "wall_s": last - t0, "mission_s": last - ready,
        "startup_s": ready - t0, "results": res,
    }
    if not complete:  # say why: exit statuses and the agents' last complaints
        out["exit_codes"] = codes
        out["no_result"] = [f"N{i}" for i in range(n_agents) if i not in results]
        out["errors"] = {f"N{i}": lines[-3:] for i, lines in sorted(errors.items())}
    return out


def bench_cell(n_agents: int, n_landmarks: int, drop: float, seeds: tuple[int, ...],
               base: dict[str, Any] | None = None, legacy: bool = False) -> dict[str, Any]:
    """Median over ``seeds`` of one (size, loss) cell; ratios to ``base`` (the lossless
    cell) when given."""
    runs = [run_mission(n_agents, n_landmarks, drop, seed, legacy=legacy) for seed in seeds]
    res = [r for run in runs for r in run["results"]]

    def mean(key: str) -> float | None:
        xs = [float(r[key]) for r in res if key in r]
        return round(statistics.mean(xs), 2) if xs else None

    rec: dict[str, Any] = {
        "bench": "mission_time_vs_loss", "agents": n_agents, "landmarks": n_landmarks,
        "drop": drop, "rate_scale": RATE_SCALE, "mode": "legacy" if legacy else "adaptive",
        "seeds": len(seeds),
        "complete": all(run["complete"] for run in runs),
        "wall_s": round(statistics.median(run["wall_s"] for run in runs), 2),
        "mission_s": round(statistics.median(run["mission_s"] for run in runs), 2),
        "startup_s": round(statistics.median(run["startup_s"] for run in runs), 2),
        "wall_s_each": [round(run["wall_s"], 2) for run in runs],
        "requests_per_agent": mean("requests"), "timeouts_per_agent": mean("timeouts"),
        "trades": round(sum(float(r["ok"]) for r in res) / 2 / len(runs), 1),
        "load_avg_1m": round(os.getloadavg()[0], 2),
    }
    for run in runs:
        if not run["complete"]:
            rec.setdefault("incomplete", []).append(
                {k: run[k] for k in ("exit_codes", "no_result", "errors", "wall_s")})
    if base is not None:
        rec["ratio"] = round(rec["wall_s"] / base["wall_s"], 2)
        rec["ratio_mission"] = round(rec["mission_s"] / max(1e-9, base["mission_s"]), 2)
    return rec


def run(out: TextIO | None = None, quick: bool = False,
        sizes: tuple[tuple[int, int], ...] = SIZES,
        drops: tuple[float, ...] = DROPS, legacy: bool = False,
        seeds: int | None = None) -> list[dict[str, Any]]:
    """Every (size, loss) cell, lossless first; one JSON line each to ``out`` (stdout)."""
    stream = out if out is not None else sys.stdout
    if quick:
        sizes, drops = ((4, 100),), (0.0, 0.3)
    recs: list[dict[str, Any]] = []
    for n, m in sizes:
        cell_seeds = _seeds(n, seeds)
        base: dict[str, Any] | None = None
        for drop in sorted(set(drops) | {0.0}):
            rec = _emit(stream, bench_cell(n, m, drop, cell_seeds, base, legacy))
            recs.append(rec)
            if drop == 0.0:
                base = rec
    return recs


def _sizes(text: str) -> tuple[tuple[int, int], ...]:
    out = []
    for cell in text.split(","):
        n, m = cell.lower().split("x")
        out.append((int(n), int(m)))
    return tuple(out)


LEGACY_AGENT = "--legacy-agent"


def legacy_agent(argv: list[str]) -> int:
    """``viscover`` ``argv`` with the agents' runtime config patched to the
    legacy timing (one query per try, fixed timeout, mission-time back-off, no Busy pause)."""
    from dataclasses import replace

    from agent.cli import main as viscover
    from agent.runners import process

    fresh = process.AgentOptions.runtime_config

    def runtime_config(self: process.AgentOptions, time_scale: float) -> Any:
        return replace(fresh(self, time_scale), request_copies=0, busy_pause=0.0)

    process.AgentOptions.runtime_config = runtime_config  # type: ignore[method-assign]
    return viscover(argv)


def main(argv: list[str] | None = None) -> int:
    """Command-line entry point."""
    args_in = sys.argv[1:] if argv is None else argv
    if args_in[:1] == [LEGACY_AGENT]:
        return legacy_agent(args_in[1:])
    p = argparse.ArgumentParser(description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--quick", action="store_true", help="4 x 100 at 0 and 30 %% only")
    p.add_argument("--issue", action="store_true", help="the issue's sizes (4x100, 8x400, "
                   "12x1000)")
    p.add_argument("--sizes", type=_sizes, default=None, metavar="NxM,...")
    p.add_argument("--drops", default=None, metavar="P,...")
    p.add_argument("--legacy", action="store_true",
                   help="agents retry with the legacy timing (one query per try, fixed timeout)")
    p.add_argument("--seeds", type=int, default=None, metavar="N",
                   help="seeds per cell (default 2 up to 8 drones, else 1)")
    args = p.parse_args(args_in)
    sizes = args.sizes or (ISSUE_SIZES if args.issue else SIZES)
    drops = tuple(float(x) for x in args.drops.split(",")) if args.drops else DROPS
    run(sys.stdout, quick=args.quick, sizes=sizes, drops=drops, legacy=args.legacy,
        seeds=args.seeds)
    return 0


if __name__ == "__main__":
    sys.exit(main())
