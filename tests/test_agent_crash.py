"""Crash recovery: kill an agent at every journal write of a mission in turn (its in-memory
state is discarded, its transport vanishes), restart it from its journal, and check that no
landmark is lost or duplicated and the mission still completes. Plus journal framing tests."""

from __future__ import annotations

import struct
import zlib
from collections.abc import Callable, Iterable
from pathlib import Path

import msgspec
import pytest

from agent.config.scenario import Scenario
from agent.protocol.machine import (
    CommitRec,
    GenesisRec,
    JournalMismatch,
    PoseRec,
    StartRec,
    TradeMachine,
)
from agent.storage.journal import Journal, JournalCorrupt, JournalLocked
from agent.testing.memsim import MemoryMission
from agent.wire.peer import pack
from tests.agent_helpers import fixed_motion, random_scene


class Crash(Exception):
    """Raised by the journal at the chosen write: the process 'dies' there."""


class CrashingJournal(Journal):
    """A journal that kills its agent at its ``at``-th trade-relevant append (pose records
    are not counted), ``before`` or after the write reaches the file."""

    def __init__(self, d: Path, at: int | None, before: bool, kill: Callable[[], None]
                 ) -> None:
        super().__init__(d)
        self.at, self.before, self.kill = at, before, kill
        self.n = 0
        self.dead = False

    def append(self, records: Iterable[object], sync: bool | None = None) -> None:
        recs = list(records)
        if self.dead:
            raise Crash
        if all(isinstance(r, PoseRec) for r in recs):
            super().append(recs, sync)
            return
        self.n += 1
        if self.at is not None and self.n == self.at:
            self.dead = True
            if not self.before:
                super().append(recs, sync)
            # Power loss: what was not fsynced is gone.
            size = self.synced_size
            self.kill()
            with self.path.open("r+b") as fh:
                fh.truncate(size)
            raise Crash
        super().append(recs, sync)


def count_appends(tmp_path: Path, sc: Scenario, seed: int) -> dict[str, int]:
    journals: dict[str, CrashingJournal] = {}

    def factory(aid: str, d: Path) -> Journal:
        journals[aid] = CrashingJournal(d, None, False, lambda: None)
        return journals[aid]

    m = MemoryMission(sc, tmp_path / "count", motion=fixed_motion(seed), journal_factory=factory)
    assert m.run(200.0)
    m.close()
    return {a: j.n for a, j in journals.items()}


def crash_at_write(victim: str, at: int, before: bool,
                   holder: dict[str, MemoryMission]) -> Callable[[str, Path], Journal]:
    """A journal factory: ``victim``'s first journal kills it (``holder["m"].crash``) at its
    ``at``-th trade-relevant write, ``before`` or after the write reaches the file."""
    armed = [True]

    def factory(aid: str, d: Path) -> Journal:
        if aid == victim and armed[0]:
            armed[0] = False
            return CrashingJournal(d, at, before, lambda: holder["m"].crash(victim))
        return Journal(d)

    return factory


def run_with_crash(tmp_path: Path, sc: Scenario, seed: int, victim: str, at: int, before: bool
                   ) -> None:
    holder: dict[str, MemoryMission] = {}
    factory = crash_at_write(victim, at, before, holder)
    m = MemoryMission(sc, tmp_path / f"{victim}-{at}-{before}", motion=fixed_motion(seed),
                      journal_factory=factory, autostart=False)
    holder["m"] = m
    for a in sc.agents:
        try:
            m.start(a.id)
        except Crash:
            pass
    crashed_at: float | None = None
    while m.net.now < 300.0:
        try:
            m.step()
        except Crash:
            pass
        if victim not in m.agents and crashed_at is None:
            crashed_at = m.net.now
        if crashed_at is not None and victim not in m.agents and m.net.now > crashed_at + 0.5:
            m.start(victim)
            crashed_at = None
        if m.complete:
            break
    try:
        assert m.complete, f"not complete (crash of {victim} at write {at}, before={before})"
        assert m.violations == [], m.violations[:5]
        assert m.final_violations() == []
        assert sorted(m.owner_of()) == sorted(sc.landmark_ids)
    finally:
        m.close()


def test_crash_at_every_journal_write(tmp_path: Path) -> None:
    sc = random_scene(3, 9, 5)
    counts = count_appends(tmp_path, sc, 5)
    assert min(counts.values()) >= 4  # genesis, start and at least one trade each
    runs = 0
    for victim, n in counts.items():
        for at in range(1, n + 1):
            for before in (True, False):
                run_with_crash(tmp_path, sc, 5, victim, at, before)
                runs += 1
    assert runs >= 24


def test_journal_torn_tail_and_corruption(tmp_path: Path) -> None:
    j = Journal(tmp_path)
    recs = [GenesisRec(agent="A", owned=pack({1: 0, 2: 0})), StartRec(incarnation=1),
            CommitRec(trade_id="A:1:1", partner="B", i_to_r=pack({1: 0}), r_to_i=pack({3: 4}))]
    j.append(recs)
    j.close()
    good = j.path.read_bytes()
    for cut in range(1, 12):  # torn last record
        j.path.write_bytes(good + good[:cut])
        j2 = Journal(tmp_path)
        assert j2.replay() == recs
        assert j2.torn_bytes == cut
        j2.append([StartRec(incarnation=2)])
        j2.close()
        j3 = Journal(tmp_path)
        assert j3.replay() == [*recs, StartRec(incarnation=2)]
        j3.close()
    # A flipped bit in the last (complete) record is damage, not a torn write: refused, the
    # file kept (issue 21, item 7: it may be a record a message was sent on).
    bad = bytearray(good)
    bad[-1] ^= 0x40
    j.path.write_bytes(bytes(bad))
    j4 = Journal(tmp_path)
    with pytest.raises(JournalCorrupt, match="the last one, is complete but damaged"):
        j4.replay()
    j4.close()
    assert j.path.read_bytes() == bytes(bad)
    # A frame claiming a huge length is torn, not a crash.
    j.path.write_bytes(good + struct.pack("<II", 2**31, 0))
    j5 = Journal(tmp_path)
    assert j5.replay() == recs
    j5.close()


def test_journal_of_another_format_or_scenario_is_refused_not_truncated(tmp_path: Path) -> None:
    j = Journal(tmp_path)
    j.append([GenesisRec(agent="A", owned=pack({1: 0, 2: 0})), StartRec(incarnation=1)])
    # An intact frame (valid CRC) that no record type decodes: another build wrote it.
    alien = msgspec.msgpack.encode({"rec": "genesis", "agent": "A", "owned": {"1": 0}})
    j._fh.write(struct.pack("<II", len(alien), zlib.crc32(alien)) + alien)
    j.close()
    size = j.path.stat().st_size
    j2 = Journal(tmp_path)
    with pytest.raises(JournalMismatch, match="incompatible"):
        j2.replay()
    j2.close()
    assert j.path.stat().st_size == size  # nothing truncated away
    # Decodable records naming landmarks the mission does not have: the wrong scenario.
    m = TradeMachine("A", [1, 2])
    with pytest.raises(JournalMismatch, match="scenario"):
        m.apply(GenesisRec(agent="A", owned=pack({1: 0, 7: 0})))


def test_journal_is_exclusive(tmp_path: Path) -> None:
    j = Journal(tmp_path)
    with pytest.raises(JournalLocked):
        Journal(tmp_path)
    j.close()
    Journal(tmp_path).close()
