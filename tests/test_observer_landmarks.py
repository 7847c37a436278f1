"""The observer's check that no landmark is lost between ledgers
(:class:`agent.runtime.observer.LandmarkWatch`): in flight is fine, gone for good is a
violation, held by a fenced agent is orphaned (not a violation) until adopted."""

from __future__ import annotations

from agent.runtime.observer import LandmarkWatch, VersionHistory


def claims(*agents: dict[int, int]) -> list[tuple[dict[int, int], dict[int, int]]]:
    return [(owned, {}) for owned in agents]


def test_a_landmark_in_flight_is_not_lost() -> None:
    h, w = VersionHistory(), LandmarkWatch([1, 2, 3], lost_s=5.0)
    h.add("A", {1: 0, 2: 0}, {})
    h.add("B", {3: 0}, {})
    assert w.update(claims({1: 0, 2: 0}, {3: 0}), 0.0, h) == []
    # A gave 2 to B; A's state arrives first, B's (with 2 at version 1) 4 s later.
    assert w.update(claims({1: 0}, {3: 0}), 1.0, h) == []
    assert w.update(claims({1: 0}, {3: 0}), 4.9, h) == []
    h.add("B", {3: 0, 2: 1}, {})
    assert w.update(claims({1: 0}, {2: 1, 3: 0}), 5.0, h) == []
    assert w.since == {}


def test_a_landmark_that_arrives_nowhere_is_reported_once() -> None:
    h, w = VersionHistory(), LandmarkWatch([1, 2], lost_s=5.0)
    h.add("A", {1: 0, 2: 3}, {})
    w.update(claims({1: 0, 2: 3}), 0.0, h)
    assert w.update(claims({1: 0}), 1.0, h) == []
    found = w.update(claims({1: 0}), 6.5, h)
    assert found == ["landmark 2: in no agent's ledger for 5.5 s (last claimed at version 3 "
                     "by A): lost"]
    assert w.update(claims({1: 0}), 9.0, h) == []


def test_landmarks_of_a_fenced_agent_are_orphaned_until_adopted() -> None:
    h, w = VersionHistory(), LandmarkWatch([1, 2, 3], lost_s=5.0)
    h.add("A", {1: 0}, {})
    h.add("F", {2: 0, 3: 4}, {})
    w.update(claims({1: 0}, {2: 0, 3: 4}), 0.0, h)
    w.fenced_touched |= h.forget("F")
    assert w.update(claims({1: 0}), 1.0, h) == []
    assert w.update(claims({1: 0}), 30.0, h) == []
    assert w.orphaned(30.0) == {2: 29.0, 3: 29.0}
    h.add("A", {1: 0, 2: 1, 3: 1}, {})  # adopted (F's versions are void)
    assert w.update(claims({1: 0, 2: 1, 3: 1}), 31.0, h) == []
    assert w.orphaned(31.0) == {}
