"""Smoke test of the trade benchmark (tiny sizes)."""

from __future__ import annotations

from agent.net.router import start_router_process, stop_router_process
from bench.bench_trade import bench_coverage, bench_trade


def test_bench_trade_smoke() -> None:
    proc, ep = start_router_process()
    try:
        rec = bench_trade(ep, n=5, m_each=20)
    finally:
        stop_router_process(proc)
    assert rec["bench"] == "trade_500x500" and rec["n"] == 5
    assert 0.0 < rec["median_s"] <= rec["p99_s"] < 1.0


def test_bench_coverage_smoke() -> None:
    recs = bench_coverage(drops=(0.0, 0.5), seeds=(1,), names=("hexagon_5_3",))
    assert [r["drop"] for r in recs] == [0.0, 0.5]
    assert recs[0]["coverage_mean"] >= recs[0]["initial_coverage"]
    assert recs[1]["coverage_min"] >= recs[1]["initial_coverage"]
