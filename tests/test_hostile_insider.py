"""Issue 33 with real processes on a TLS router: a hostile drone holding drone N2's team
certificate and signing key while the real N2 flies (``strategy = "potential"``: re-split legs
are taken from stage 2 on) tries every attack of the insider campaign once
(:mod:`bench.chaos_insider`): a re-split leg from a made-up pose taking a peer's landmarks, a
re-split leg and an ordinary offer handing a peer a third drone's landmarks, a made-up pose
published under N2's certificate then offered from, a flood of new incarnation tokens, forged
states claiming a peer's landmarks. Each offer is refused (or answered Busy until the thief
gives up), the replay memory evicts and says so, the journals hold nothing lost or doubled and
the observer reports no violation. Before issue 33 the same mission lost 6 landmarks and
doubled 3 (the first four attacks)."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from bench.chaos_insider import ATTACKS, mission

pytestmark = [pytest.mark.serial]


def test_an_insider_with_a_drones_certificate_and_key_gets_nothing() -> None:
    got = mission(list(ATTACKS), seed=1)
    try:
        for name, t in got["attacks"].items():
            assert t["tries"] >= 1 and t["accepted"] == 0 and t["refused"] == t["tries"], \
                (name, t)
        assert got["attacks"]["seal_flood"]["evicted"] > 0
        assert got["lost"] == [] and got["doubled"] == [], got
        assert got["violations"] == [], got["violations"]
        assert all(got["agents_alive"]), got
    finally:
        shutil.rmtree(Path(got["tmp"]), ignore_errors=True)
