"""Smoke test of the network benchmark (small n)."""

from __future__ import annotations

import io
import json

from bench.bench_net import run


def test_bench_net_prints_json_lines() -> None:
    out = io.StringIO()
    records = run(out, n=30)
    lines = [json.loads(line) for line in out.getvalue().splitlines()]
    assert lines == records
    assert [r["bench"] for r in lines] == ["zenoh_get_rtt", "transport_request_rtt"]
    for r in lines:
        assert r["n"] == 30 and r["lost"] == 0
        assert 0.0 < r["median_s"] <= r["p99_s"] < 1.0
