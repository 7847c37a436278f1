"""Generic msgspec codec: round trip and rejection counting."""

from __future__ import annotations

import logging
import threading

import msgspec
import pytest

from agent.net.rejects import LockedRejectCounter, rate_limited_log
from agent.wire.codec import (
    REASON_NONFINITE,
    REASON_SCHEMA,
    REASON_UNDECODABLE,
    Codec,
    RateLimitedLogger,
    RejectCounter,
    all_finite,
)


class PoseMsg(msgspec.Struct, tag=True, tag_field="kind"):
    """Example wire type (tests only)."""

    agent: str
    t_s: float
    xyz_m: list[float]
    schema: int = 2


class HelloMsg(msgspec.Struct, tag=True, tag_field="kind"):
    agent: str
    extras: dict[str, float] = msgspec.field(default_factory=dict)
    schema: int = 1


Msg = PoseMsg | HelloMsg


def test_round_trip_union() -> None:
    codec: Codec[Msg] = Codec(Msg)
    pose = PoseMsg("a", 1.5, [1.0, 2.0, 3.0])
    hello = HelloMsg("b", {"v": 1.0})
    assert codec.decode(codec.encode(pose), "k") == pose
    assert codec.decode(codec.encode(hello), "k") == hello
    assert codec.counter.total == 0


@pytest.mark.parametrize(
    "data",
    [b"", b"\xc1", b"not msgpack at all", msgspec.msgpack.encode({"kind": "Nope"}), 12345],
)
def test_undecodable_counted(data: object) -> None:
    codec: Codec[Msg] = Codec(Msg)
    # 12345 is deliberately not bytes: a wrong type is refused and counted too.
    assert codec.decode(data, "viscover/m/pose/a") is None  # type: ignore[arg-type]
    assert codec.counter.by_reason == {REASON_UNDECODABLE: 1}
    assert codec.counter.by_key == {"viscover/m/pose/a": 1}


def test_wrong_schema_rejected() -> None:
    codec: Codec[Msg] = Codec(Msg)
    old = PoseMsg("a", 0.0, [0.0], schema=1)
    assert codec.decode(codec.encode(old), "k1") is None
    assert codec.decode(codec.encode(HelloMsg("b", schema=3)), "k2") is None
    assert codec.counter.by_reason == {REASON_SCHEMA: 2}
    assert codec.counter.by_key == {"k1": 1, "k2": 1}


def test_explicit_schema_overrides_defaults() -> None:
    codec: Codec[PoseMsg] = Codec(PoseMsg, schema=7)
    assert codec.decode(codec.encode(PoseMsg("a", 0.0, [], schema=7))) is not None
    assert codec.decode(codec.encode(PoseMsg("a", 0.0, []))) is None


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), -float("inf")])
def test_nonfinite_rejected(bad: float) -> None:
    codec: Codec[Msg] = Codec(Msg)
    assert codec.decode(codec.encode(PoseMsg("a", bad, [0.0]))) is None
    assert codec.decode(codec.encode(PoseMsg("a", 0.0, [0.0, bad]))) is None
    assert codec.decode(codec.encode(HelloMsg("a", {"x": bad}))) is None
    assert codec.counter.by_reason == {REASON_NONFINITE: 3}


def test_all_finite_walks_nested_and_arrays() -> None:
    np = pytest.importorskip("numpy")
    assert all_finite({"a": [1.0, (2.0, {3.0})]})
    assert not all_finite({"a": [1.0, (2.0, {float("nan")})]})
    assert all_finite(np.zeros(3))
    assert not all_finite(np.array([0.0, np.inf]))
    assert all_finite(np.arange(3))


def test_codec_requires_schema_field() -> None:
    class NoSchema(msgspec.Struct):
        x: int

    class NoDefault(msgspec.Struct):
        schema: int

    with pytest.raises(TypeError):
        Codec(NoSchema)
    with pytest.raises(TypeError):
        Codec(NoDefault)
    with pytest.raises(TypeError):
        Codec(int)
    assert Codec(NoDefault, schema=1).decode(msgspec.msgpack.encode(NoDefault(1))) == NoDefault(1)


def test_rate_limited_logger(caplog: pytest.LogCaptureFixture) -> None:
    now = [0.0]
    log = RateLimitedLogger(logging.getLogger("test.codec"), interval_s=5.0, clock=lambda: now[0])
    with caplog.at_level(logging.WARNING, logger="test.codec"):
        assert log.log("schema", "m1")
        for _ in range(9):
            assert not log.log("schema", "m")
        assert log.log("nonfinite", "other reason is independent")
        now[0] = 5.0
        assert log.log("schema", "m2")
    lines = [r.getMessage() for r in caplog.records]
    assert len(lines) == 3
    assert "9 similar suppressed" in lines[2]


def test_codec_logs_are_rate_limited(caplog: pytest.LogCaptureFixture) -> None:
    """On the wall clock (shared by transport threads): one line in a burst."""
    counter = LockedRejectCounter()
    codec: Codec[Msg] = Codec(Msg, counter=counter, log=rate_limited_log(interval_s=60.0))
    with caplog.at_level(logging.WARNING, logger="viscover.agent.wire.codec"):
        for _ in range(100):
            assert codec.decode(b"\xc1", "k") is None
    assert counter.total == 100
    assert counter.snapshot() == {"by_reason": {"undecodable": 100}, "by_key": {"k": 100}}
    assert len(caplog.records) == 1


def test_without_a_clock_the_1st_10th_and_100th_lines_are_logged(
        caplog: pytest.LogCaptureFixture) -> None:
    """The pure logger (an agent core's, no clock read): a flood shows at a logarithmic rate,
    each line saying how many were suppressed before it."""
    counter = RejectCounter()
    codec: Codec[Msg] = Codec(Msg, counter=counter, log=RateLimitedLogger())
    with caplog.at_level(logging.WARNING, logger="viscover.agent.wire.codec"):
        for _ in range(120):
            assert codec.decode(b"\xc1", "k") is None
    lines = [r.getMessage() for r in caplog.records]
    assert len(lines) == 3 and counter.total == 120
    assert "similar suppressed" not in lines[0]
    assert lines[1].endswith("(8 similar suppressed)")
    assert lines[2].endswith("(89 similar suppressed)")


def test_the_locked_counter_counts_every_rejection_from_many_threads() -> None:
    counter = LockedRejectCounter()

    def add() -> None:
        for i in range(2000):
            counter.add("schema", f"k{i % 50}")

    threads = [threading.Thread(target=add) for _ in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert counter.total == 16000
    assert counter.snapshot()["by_reason"] == {"schema": 16000}
    assert sum(counter.snapshot()["by_key"].values()) == 16000
