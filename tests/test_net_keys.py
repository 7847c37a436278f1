"""Key-expression table: builders, parsing, validation."""

from __future__ import annotations

from collections.abc import Callable

import pytest

from agent.wire import keys


@pytest.mark.parametrize(
    ("builder", "kind"),
    [
        (keys.pose_key, "pose"),
        (keys.state_key, "state"),
        (keys.trade_key, "trade"),
        (keys.alive_key, "alive"),
        (keys.status_key, "status"),
    ],
)
@pytest.mark.parametrize("agent", ["a", "drone_7", "X-1", "z" * 32])
def test_agent_keys_round_trip(builder: Callable[[str, str], str], kind: str, agent: str
                               ) -> None:
    key = builder("m1", agent)
    assert key == f"viscover/m1/{kind}/{agent}"
    assert keys.parse_key(key) == ("m1", kind, agent)
    assert keys.agent_of(key) == agent
    assert keys.try_agent_of(key) == agent
    assert keys.kind_of(key) == kind


def test_mission_keys() -> None:
    assert keys.clock_key("m") == "viscover/m/clock"
    assert keys.landmarks_key("m") == "viscover/m/landmarks"
    assert keys.parse_key("viscover/m/clock") == ("m", "clock", None)
    assert keys.try_agent_of("viscover/m/landmarks") is None
    with pytest.raises(keys.KeyFormatError):
        keys.agent_of("viscover/m/clock")
    assert keys.all_agents("m", "pose") == "viscover/m/pose/*"
    assert keys.mission_glob("m") == "viscover/m/**"


@pytest.mark.parametrize("bad", ["", "a/b", "*", "**", "a b", "x" * 33, "é", "a$", "a?"])
def test_invalid_ids_rejected(bad: str) -> None:
    with pytest.raises(keys.KeyFormatError):
        keys.pose_key("m", bad)
    with pytest.raises(keys.KeyFormatError):
        keys.pose_key(bad, "a")


@pytest.mark.parametrize(
    "key",
    [
        "other/m/pose/a",
        "viscover/m/pose",
        "viscover/m/pose/a/b",
        "viscover/m/clock/a",
        "viscover/m/unknown/a",
        "viscover/m/pose/*",
        "viscover",
    ],
)
def test_parse_rejects_foreign_keys(key: str) -> None:
    with pytest.raises(keys.KeyFormatError):
        keys.parse_key(key)
    assert keys.try_agent_of(key) is None


def test_all_agents_rejects_unknown_kind() -> None:
    with pytest.raises(keys.KeyFormatError):
        keys.all_agents("m", "clock")
