"""Seeded fault injection: determinism, statistics, logging and replay."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from agent.net.faults import (
    DELIVER_NOW,
    Direction,
    FaultConfig,
    FaultInjector,
    ReplayInjector,
    read_fault_log,
)

KINDS = ["pose", "trade", "state"]


def _calls(n: int) -> list[tuple[str, str | None, Direction]]:
    peers = ["a", "b", None]
    return [(KINDS[i % 3], peers[i % 3], "out" if i % 2 else "in") for i in range(n)]


def _config() -> FaultConfig:
    return FaultConfig(
        drop_out={"pose": 0.3},
        drop_in={"trade": 0.2},
        drop_default=0.05,
        delay_s=0.01,
        jitter_s=0.02,
        duplicate=0.1,
        partition=["b"],
    )


def test_same_seed_same_decisions() -> None:
    calls = _calls(2000)
    a = FaultInjector(_config(), seed=42)
    b = FaultInjector(_config(), seed=42)
    c = FaultInjector(_config(), seed=43)
    da = [a.decide(*call) for call in calls]
    db = [b.decide(*call) for call in calls]
    dc = [c.decide(*call) for call in calls]
    assert da == db
    assert da != dc
    assert a.records == b.records


def test_no_faults_delivers_once_now() -> None:
    inj = FaultInjector(FaultConfig(), seed=1)
    assert all(inj.decide("pose", "a", "out") is DELIVER_NOW for _ in range(100))
    assert inj.records == []


def test_partition_drops_both_ways() -> None:
    inj = FaultInjector(FaultConfig(partition=["b"]), seed=1)
    assert inj.decide("pose", "b", "in").reason == "partition"
    assert inj.decide("trade", "b", "out").dropped
    assert not inj.decide("trade", "a", "out").dropped


@pytest.mark.parametrize("p", [0.1, 0.5])
def test_drop_rate_within_binomial_bounds(p: float) -> None:
    n = 10_000
    inj = FaultInjector(FaultConfig(drop_out={"pose": p}), seed=7)
    drops = sum(inj.decide("pose", "a", "out").dropped for _ in range(n))
    sigma = math.sqrt(n * p * (1 - p))
    assert abs(drops - n * p) < 5 * sigma
    # Other kinds and the other direction use the default (0).
    assert not any(inj.decide("trade", "a", "out").dropped for _ in range(100))
    assert not any(inj.decide("pose", "a", "in").dropped for _ in range(100))


def test_duplicates_and_jitter_statistics() -> None:
    n = 10_000
    cfg = FaultConfig(delay_s=0.1, jitter_s=0.05, duplicate=0.2)
    inj = FaultInjector(cfg, seed=3)
    decisions = [inj.decide("state", None, "out") for _ in range(n)]
    dups = sum(d.copies == 2 for d in decisions)
    assert abs(dups - 0.2 * n) < 5 * math.sqrt(n * 0.2 * 0.8)
    delays = [x for d in decisions for x in d.delays_s]
    assert all(0.1 <= x < 0.15 for x in delays)
    assert abs(sum(delays) / len(delays) - 0.125) < 0.002
    assert len(inj.records) == n  # every delayed decision is logged


def test_log_file_and_replay(tmp_path: Path) -> None:
    path = tmp_path / "faults.jsonl"
    calls = _calls(500)
    inj = FaultInjector(_config(), seed=9, log=path)
    original = [inj.decide(*call) for call in calls]
    inj.close()
    records = read_fault_log(path)
    assert records == inj.records
    assert records and all(r.reason != "ok" for r in records)
    replay = ReplayInjector(path)
    assert [replay.decide(*call) for call in calls] == original


def test_invalid_config_rejected() -> None:
    with pytest.raises(ValueError):
        FaultConfig(drop_default=1.5)
    with pytest.raises(ValueError):
        FaultConfig(delay_s=-1.0)
