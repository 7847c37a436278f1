"""Trade benchmarks. ``run(out)`` prints one JSON line per measurement:

* ``trade_500x500``: complete trades (Offer -> Accept -> Commit -> CommitAck, journals
  fsynced) between two :class:`~agent.runtime.shell.runtime.AgentRuntime` s owning 500 landmarks
  each,
  each on its own Zenoh session through a router on loopback; every trade swaps all 1,000
  landmarks. Median and p99 [s].
* ``swarm``: N agent processes (default 20) and a router converge a scene of M landmarks
  (default 2,000) under a drop rate (default 30 %): wall time [s], messages per agent, bytes
  per trade, completion.
* ``coverage_vs_loss``: final coverage against drop rate (0-50 %) on the thesis' multi-agent
  scenarios, agents on the in-process :class:`~agent.net.memory.MemoryNetwork` (same runtime
  code, seeded faults), beside the loss-free kinematic simulator.

Run: ``python -m bench.bench_trade [--quick]``.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any, TextIO

import numpy as np

from agent.clock import ManualClock
from agent.config.parse import load_scenario
from agent.config.scenario import AgentSpec, Scenario
from agent.core.avoidance import MissionSpace
from agent.core.planner import PlannerParams
from agent.net.faults import FaultConfig
from agent.net.router import client_config, start_router_process, stop_router_process
from agent.net.transport import ZenohTransport
from agent.runtime.shell.pose import KinematicPoseSource, fix_of
from agent.runtime.shell.runtime import AgentConfig, AgentRuntime
from agent.sim.kinematic import simulate
from agent.storage.journal import Journal
from agent.testing.memsim import MemoryMission

ROOT = Path(__file__).resolve().parents[1]


def _emit(out: TextIO, rec: dict[str, Any]) -> dict[str, Any]:
    out.write(json.dumps(rec) + "\n")
    out.flush()
    return rec


def _pct(xs: list[float], q: float) -> float:
    s = sorted(xs)
    return s[min(len(s) - 1, max(0, round(q * (len(s) - 1))))]


# -- 1. one trade, 500 x 500 ----------------------------------------------------------------


def two_cluster_scenario(m_each: int = 500) -> Scenario:
    """A at x = 0 and B at x = 10 look along +x; cluster 1 sits 1 m in front of A, cluster 2
    1 m in front of B, normals facing the cameras. A owns cluster 2 and B cluster 1, so
    Algorithm 7 swaps everything; swapping the poses makes the next trade swap back."""
    rng = np.random.default_rng(0)
    spread = rng.uniform(-0.2, 0.2, size=(2 * m_each, 2))
    q = np.zeros((2 * m_each, 3))
    q[:m_each, 0] = 1.0
    q[m_each:, 0] = 11.0
    q[:, 1:] = spread
    u = np.tile([-1.0, 0.0, 0.0], (2 * m_each, 1))
    ids = list(range(1, 2 * m_each + 1))
    agents = [
        AgentSpec("A", np.array([0.0, 0.0, 0.0]), np.array([1.0, 0.0, 0.0]),
                  np.arange(m_each, 2 * m_each)),
        AgentSpec("B", np.array([10.0, 0.0, 0.0]), np.array([1.0, 0.0, 0.0]),
                  np.arange(0, m_each)),
    ]
    return Scenario(name="bench2", seed=0, planar=False, d_opt=1.0, duration=60.0, q=q, u=u,
                    landmark_ids=ids, agents=agents, params=PlannerParams(),
                    space=MissionSpace.unbounded(), source="<bench>")


def _ping_pong(rt: AgentRuntime) -> AgentRuntime:
    """Make ``rt`` stay converged and, after each successful trade, move to the other agent's
    pose (x = 0 <-> x = 10), so that the next trade swaps every landmark back."""
    pose = rt.pose
    assert isinstance(pose, KinematicPoseSource)

    def swap() -> None:
        rt.core.shared.converge()
        pose.p = np.array([10.0 - pose.p[0], 0.0, 0.0])
        rt.core.pose.fix = fix_of(pose)  # teleported between ticks: the core's view too

    rt.core.shared.on_success.append(swap)
    return rt


def _serve_b(endpoint: str, state_dir: str, m_each: int) -> int:
    """Responder process of :func:`bench_trade`: answers queries until stdin closes."""
    sc = two_cluster_scenario(m_each)
    tp = ZenohTransport(client_config(endpoint), None, "B")
    journal = Journal(state_dir)
    # A teleports between the two poses after every trade, faster than its pose publications
    # travel: B's check of offered poses (agent.runtime.ends.pose_check) is not what this measures.
    rt = _ping_pong(AgentRuntime("B", sc, tp, journal, ManualClock(),
                                 config=AgentConfig(mission="bench", pose_tolerance_m=1e6,
                                                    pose_tolerance_rad=4.0)))
    rt.core.shared.converge()
    rt.start()
    print("ready", flush=True)
    try:
        sys.stdin.read()
    finally:
        rt.stop()
        tp.close()
        journal.close()
        print(json.dumps({"syncs": journal.syncs}), flush=True)
    return 0


def _one_trade(a: AgentRuntime, clock: ManualClock, i: int) -> float:
    """One complete trade offered by ``a`` [s, the successful try's]. B checks an offered set
    against A's published ledger (agent.runtime.ends.trade_server): A publishes its state after
    each trade, and an offer B answers Busy (it has not heard that state yet) is made again,
    its back-off skipped on A's manual clock."""
    for _ in range(50):
        a.core.shared.partners.reset()
        ok_before = a.core.machine.ok
        t0 = time.perf_counter()
        a.core.client.maybe_offer(clock.now())
        a.drive(a.core.client.attempt_offer(clock.now()))
        a.drive(a.core.client.service_pending(clock.now()))
        dt = time.perf_counter() - t0
        done = not a.core.machine.pending_ids and a.core.machine.ok == ok_before + 1
        if not done:  # past the Busy back-off (at most backoff_cap_s) and pause; not so far
            clock.advance(0.5)  # that B, which publishes no state here, turns silent
        a.core.shared.partners.pending.clear()  # the tick publishes; it offers nothing itself
        a.tick()
        time.sleep(0.03)  # B hears the state before the next offer
        if done:
            return dt
    raise RuntimeError(f"trade {i} did not complete: {a.core.shared.counters.outcomes}")


def bench_trade(endpoint: str, n: int = 200, m_each: int = 500,
                state_root: str | None = None) -> dict[str, Any]:
    """Time ``n`` complete trades [s]: initiator A here, responder B in its own process
    (two drones), each with its own Zenoh session and fsynced journal (under ``state_root``,
    default the system temp dir; ``/dev/shm`` shows the cost without disk fsyncs)."""
    sc = two_cluster_scenario(m_each)
    tmp = Path(tempfile.mkdtemp(prefix="viscover-bench-", dir=state_root))
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(ROOT), env.get("PYTHONPATH")]))
    b = subprocess.Popen([sys.executable, "-m", "bench.bench_trade", "--serve-b", endpoint,
                          str(tmp / "B"), str(m_each)], stdin=subprocess.PIPE,
                         stdout=subprocess.PIPE, text=True, env=env)
    clock = ManualClock()
    tp = ZenohTransport(client_config(endpoint), None, "A")
    journal = Journal(tmp / "A")
    a = _ping_pong(AgentRuntime("A", sc, tp, journal, clock,
                                config=AgentConfig(mission="bench", request_timeout_s=1.0)))
    times: list[float] = []
    syncs_a = syncs_b = 0
    try:
        assert b.stdout is not None and b.stdout.readline().strip() == "ready"
        a.start()
        deadline = time.monotonic() + 10.0
        while "B" not in a.core.members.live and time.monotonic() < deadline:
            time.sleep(0.01)
        a.core.shared.converge()
        for i in range(n + 10):
            if i == 10:
                syncs_a = journal.syncs
            dt = _one_trade(a, clock, i)
            if i >= 10:  # warm-up
                times.append(dt)
    finally:
        a.stop()
        tp.close()
        journal.close()
        if b.stdin is not None:
            b.stdin.close()
        if b.stdout is not None:
            tail = b.stdout.read().strip().splitlines()
            syncs_b = json.loads(tail[-1])["syncs"] if tail else 0
            b.stdout.close()
        b.wait(10.0)
    # B's syncs include its warm-up trades; both journals also sync once at start.
    fsyncs = (journal.syncs - syncs_a) / len(times) + (syncs_b - 2) / (n + 10)
    return {"bench": "trade_500x500", "median_s": statistics.median(times),
            "p99_s": _pct(times, 0.99), "n": len(times), "landmarks_each": m_each,
            "moved_per_trade": 2 * m_each, "fsyncs_per_trade": round(fsyncs, 2),
            "state_dir": str(tmp.parent), "target_median_s": 0.003}


# -- 2. a swarm of processes ----------------------------------------------------------------


def swarm_scene_toml(n_agents: int, n_landmarks: int, seed: int = 0, r: float = 8.0) -> str:
    """2-D scene: landmarks on a circle of radius ``r`` [m] facing out, agents 3 m outside
    it, each agent starting with the arc that runs from its own bearing to its neighbour's,
    except 10 % of the landmarks dealt to random agents (those have to be traded across the
    swarm)."""
    h = r + 12.0
    lines = [f'name = "swarm_{n_agents}_{n_landmarks}"', "dims = 2", f"seed = {seed}",
             "d_opt = 1.0", "duration = 600.0", "", "[space]", f"lo = [{-h}, {-h}]",
             f"hi = [{h}, {h}]", "", "[planner]", "dt = 0.1", 'avoidance = "smooth"',
             "r_s = 0.6", "d_w = 0.3", ""]
    for k in range(n_landmarks):
        a = 2 * np.pi * k / n_landmarks
        lines += ["[[landmarks]]", f"id = {k + 1}",
                  f"position = [{r * np.cos(a):.6f}, {r * np.sin(a):.6f}]",
                  f"normal = [{np.cos(a):.6f}, {np.sin(a):.6f}]", ""]
    rng = np.random.default_rng(seed)
    owner = (np.floor(np.arange(n_landmarks) * n_agents / n_landmarks - 0.5).astype(int)
             % n_agents)
    stray = rng.random(n_landmarks) < 0.1  # 10 % dealt to a random agent
    owner[stray] = rng.integers(0, n_agents, int(stray.sum()))
    for i in range(n_agents):
        a = 2 * np.pi * i / n_agents
        own = [int(k) + 1 for k in np.flatnonzero(owner == i)]
        lines += ["[[agents]]", f'id = "N{i}"',
                  f"position = [{(r + 3) * np.cos(a):.6f}, {(r + 3) * np.sin(a):.6f}]",
                  f"yaw = {a + np.pi:.6f}", f"landmarks = {own}", ""]
    return "\n".join(lines)


def bench_swarm(n_agents: int = 20, n_landmarks: int = 2000, drop: float = 0.3,
                rate_scale: float = 2.0, timeout_s: float = 600.0) -> dict[str, Any]:
    """Start a router and ``n_agents`` agent processes; wait for all to finish."""
    tmp = Path(tempfile.mkdtemp(prefix="viscover-swarm-"))
    scen = tmp / "swarm.toml"
    scen.write_text(swarm_scene_toml(n_agents, n_landmarks))
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(ROOT), env.get("PYTHONPATH")]))
    proc, ep = start_router_process()
    procs: list[subprocess.Popen[str]] = []
    t0 = time.monotonic()
    try:
        for i in range(n_agents):
            cmd = [sys.executable, "-m", "agent.cli", "agent", "--id",
                   f"N{i}", "--scenario", str(scen), "--connect", ep, "--state-dir",
                   str(tmp / f"N{i}"), "--rate-scale", str(rate_scale), "--exit-on-complete",
                   "--timeout", str(timeout_s), "--drop", str(drop), "--fault-seed", str(i),
                   "--request-timeout", "0.15"]
            procs.append(subprocess.Popen(cmd, stdout=subprocess.PIPE,
                                          stderr=subprocess.PIPE, text=True, env=env))
        results = []
        codes = []
        for p in procs:
            out, _err = p.communicate()
            codes.append(p.returncode)
            for line in out.splitlines():
                if line.startswith("{"):
                    results.append(json.loads(line))
        wall = time.monotonic() - t0
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
                p.communicate()
        stop_router_process(proc)
    trades = sum(r["ok"] for r in results) / 2 if results else 0
    msgs = [r["requests"] + r["published"] for r in results]
    return {
        "bench": "swarm", "agents": n_agents, "landmarks": n_landmarks, "drop": drop,
        "rate_scale": rate_scale, "wall_s": wall,
        "complete": len(results) == n_agents and all(c == 0 for c in codes),
        "agents_complete": len(results), "trades": trades,
        "messages_per_agent": statistics.mean(msgs) if msgs else None,
        "bytes_per_trade": (sum(r["bytes_out"] for r in results) / trades) if trades else None,
        "first_complete_wall_s": (min(r["completed_at_s"] for r in results) / rate_scale
                                  if results else None),
        "last_complete_wall_s": (max(r["completed_at_s"] for r in results) / rate_scale
                                 if results else None),
        "coverage": sum(r["vision"] for r in results),
        "owned_total": sum(len(r["owned"]) for r in results),
    }


# -- 3. coverage against loss -----------------------------------------------------------------


def bench_coverage(drops: tuple[float, ...] = (0.0, 0.1, 0.2, 0.3, 0.4, 0.5),
                   seeds: tuple[int, ...] = (1, 2, 3),
                   names: tuple[str, ...] = ("hexagon_5_3", "cube_6_2", "two_agents_5_2"),
                   ) -> list[dict[str, Any]]:
    """Final coverage per drop rate (mean/min over seeds) beside the kinematic simulator."""
    out = []
    for name in names:
        sc = load_scenario(ROOT / "scenarios" / f"{name}.toml")
        ref = simulate(sc)
        for drop in drops:
            covs, times = [], []
            for seed in seeds:
                with tempfile.TemporaryDirectory() as d:
                    m = MemoryMission(sc, d, FaultConfig(drop_default=drop) if drop else None,
                                      seed=seed, config=AgentConfig(mission="cov", seed=seed))
                    ok = m.run(600.0)
                    covs.append(m.coverage() if ok else float("nan"))
                    times.append(m.net.now)
                    m.close()
            out.append({"bench": "coverage_vs_loss", "scenario": name, "drop": drop,
                        "coverage_mean": statistics.mean(covs), "coverage_min": min(covs),
                        "kinematic_coverage": float(ref.coverage[-1]),
                        "initial_coverage": float(ref.coverage[0]),
                        "mission_time_mean_s": statistics.mean(times), "seeds": len(seeds)})
    return out


def run(out: TextIO | None = None, quick: bool = False) -> list[dict[str, Any]]:
    """Run all trade benchmarks; print JSON lines to ``out`` (stdout)."""
    stream = out if out is not None else sys.stdout
    recs: list[dict[str, Any]] = []
    proc, ep = start_router_process()
    try:
        recs.append(_emit(stream, bench_trade(ep, n=30 if quick else 300)))
        if not quick and Path("/dev/shm").is_dir():  # same trade, journal on tmpfs
            recs.append(_emit(stream, bench_trade(ep, n=300, state_root="/dev/shm")))
    finally:
        stop_router_process(proc)
    for rec in bench_coverage(seeds=(1,) if quick else (1, 2, 3),
                              drops=(0.0, 0.3) if quick else (0.0, 0.1, 0.2, 0.3, 0.4, 0.5)):
        recs.append(_emit(stream, rec))
    if quick:
        recs.append(_emit(stream, bench_swarm(n_agents=4, n_landmarks=80, rate_scale=5.0,
                                              timeout_s=120.0)))
    else:
        recs.append(_emit(stream, bench_swarm()))
    return recs


def main(argv: list[str] | None = None) -> int:
    """Command-line entry point."""
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--quick", action="store_true", help="small sizes (smoke run)")
    p.add_argument("--only", choices=["trade", "swarm", "coverage"])
    p.add_argument("--agents", type=int, default=20)
    p.add_argument("--landmarks", type=int, default=2000)
    p.add_argument("--drop", type=float, default=0.3)
    p.add_argument("--rate-scale", type=float, default=2.0)
    p.add_argument("--serve-b", nargs=3, metavar=("ENDPOINT", "STATE_DIR", "M_EACH"),
                   help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.serve_b:
        return _serve_b(args.serve_b[0], args.serve_b[1], int(args.serve_b[2]))
    if args.only == "trade":
        proc, ep = start_router_process()
        try:
            _emit(sys.stdout, bench_trade(ep, n=300))
        finally:
            stop_router_process(proc)
    elif args.only == "swarm":
        _emit(sys.stdout, bench_swarm(args.agents, args.landmarks, args.drop, args.rate_scale))
    elif args.only == "coverage":
        for rec in bench_coverage():
            _emit(sys.stdout, rec)
    else:
        run(sys.stdout, quick=args.quick)
    return 0


if __name__ == "__main__":
    sys.exit(main())
