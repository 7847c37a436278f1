"""What the secured profile costs. ``run(out)`` prints one JSON line per measurement:

* ``trade_security``: complete trades (Offer -> Accept -> Commit -> CommitAck, journals fsynced)
  between two :class:`~agent.runtime.shell.runtime.AgentRuntime` s, each on its own Zenoh session,
  through a router on loopback: ``profile`` ``open`` (TCP, unsigned) or ``secured`` (mutual
  TLS, access control, every request and reply signed and checked with Ed25519). Median and
  p99 per trade [s], bytes sent per trade.
* ``seal_cost``: median time of one Ed25519 seal and one check of an offer [s]; a trade is two
  exchanges (Offer/Accept, Commit/CommitAck), so four seals and four checks on its critical
  path (``per_trade_s``); the envelope's size overhead [bytes].

Run: ``python -m bench.bench_security [--quick]``.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any, TextIO

from agent.clock import ManualClock
from agent.net.pki import TeamPlan, make_team
from agent.net.router import client_config, start_router_process, stop_router_process
from agent.net.security import TeamDir, drone_name, load_signing
from agent.net.security import client_config as secure_config
from agent.net.transport import ZenohTransport
from agent.runtime.shell.runtime import AgentConfig, AgentRuntime
from agent.storage.journal import Journal
from agent.wire.codec import Codec
from agent.wire.peer import Offer, Request, pack
from agent.wire.signed import TradeSeal
from bench.bench_trade import _emit, _pct, _ping_pong, two_cluster_scenario
from bench.timing import time_calls


def _runtime(aid: str, endpoint: str, team: TeamDir | None, state: Path, m_each: int,
             ) -> AgentRuntime:
    """A converged ping-pong agent ``aid`` on the open (``team`` None) or secured profile."""
    cfg = (client_config(endpoint) if team is None
           else secure_config(team, [endpoint], drone_name(aid)))
    signing = None if team is None else load_signing(team, aid)
    rt = _ping_pong(AgentRuntime(aid, two_cluster_scenario(m_each), ZenohTransport(cfg, None, aid),
                                 Journal(state / aid), ManualClock(),
                                 config=AgentConfig(mission="bench", request_timeout_s=1.0,
                                                    signing=signing)))
    rt.core.shared.converge()
    rt.start()
    return rt


def bench_profile(team: TeamDir | None, n: int, m_each: int, state_root: Path) -> dict[str, Any]:
    """Time ``n`` complete trades between two agents through a fresh router of the profile."""
    proc, ep = start_router_process(team=team)
    state = Path(tempfile.mkdtemp(prefix="viscover-bench-sec-", dir=state_root))
    a = b = None
    try:
        b = _runtime("B", ep, team, state, m_each)
        a = _runtime("A", ep, team, state, m_each)
        deadline = time.monotonic() + 10.0
        while "B" not in a.core.members.live and time.monotonic() < deadline:
            time.sleep(0.01)
        times: list[float] = []
        bytes0 = 0
        for i in range(n + 10):
            if i == 10:
                bytes0 = a.core.shared.counters.bytes_out
            a.core.shared.partners.reset()
            ok = a.core.machine.ok
            t0 = time.perf_counter()
            a.core.client.maybe_offer(0.0)
            a.drive(a.core.client.attempt_offer(0.0))
            a.drive(a.core.client.service_pending(0.0))
            dt = time.perf_counter() - t0
            if a.core.machine.pending_ids or a.core.machine.ok != ok + 1:
                raise RuntimeError(f"trade {i} did not complete: {a.core.shared.counters.outcomes}")
            if i >= 10:  # warm-up
                times.append(dt)
        return {"bench": "trade_security", "profile": "open" if team is None else "secured",
                "median_s": statistics.median(times), "p99_s": _pct(times, 0.99),
                "n": len(times), "landmarks_each": m_each,
                "request_bytes_per_trade": (a.core.shared.counters.bytes_out - bytes0) / n,
                "rejected": a.core.rejects.total + b.core.rejects.total}
    finally:
        for rt in (a, b):
            if rt is not None:
                rt.stop()
                rt.tp.close()
        stop_router_process(proc)


def bench_seal(team: TeamDir, reps: int, m_each: int) -> dict[str, Any]:
    """Seal and check cost of one offer of ``m_each`` landmarks [s], and its size overhead."""
    a = TradeSeal(load_signing(team, "A"), "bench")
    b = TradeSeal(load_signing(team, "B"), "bench")
    a.know("B", b.boot)  # as after a first contact
    requests: Codec[Request] = Codec(Request)
    body = requests.encode(Offer(sender="A", trade_id="A:1:1", p=(0.0, 0.0, 0.0),
                                       v=(1.0, 0.0, 0.0), owned=pack(dict.fromkeys(
                                           range(m_each), 0))))
    sealed = [a.seal_request(body, "B")[0] for _ in range(reps)]
    seal_t = time_calls(lambda: a.seal_request(body, "B"), reps)
    it = iter(sealed)
    check_t = time_calls(lambda: b.open_request(next(it)), reps)
    seal_s, check_s = statistics.median(seal_t), statistics.median(check_t)
    return {"bench": "seal_cost", "seal_median_s": seal_s, "check_median_s": check_s,
            "per_trade_s": 4 * (seal_s + check_s), "overhead_bytes": len(sealed[0]) - len(body),
            "body_bytes": len(body), "reps": reps}


def run(out: TextIO | None = None, quick: bool = False) -> list[dict[str, Any]]:
    """Run the security benchmarks; print JSON lines to ``out`` (stdout)."""
    stream = out if out is not None else sys.stdout
    n, m_each = (30, 50) if quick else (300, 50)
    with tempfile.TemporaryDirectory(prefix="viscover-bench-team-") as tmp:
        team = make_team(TeamPlan(Path(tmp) / "team", ["A", "B"]))
        recs = [_emit(stream, bench_seal(team, 200 if quick else 2000, m_each))]
        for profile in (None, team):
            recs.append(_emit(stream, bench_profile(profile, n, m_each, Path(tmp))))
    return recs


def main(argv: list[str] | None = None) -> int:
    """Command-line entry point."""
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--quick", action="store_true", help="small sizes (smoke run)")
    run(quick=p.parse_args(argv).quick)
    return 0


if __name__ == "__main__":
    sys.exit(main())
