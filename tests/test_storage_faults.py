"""Storage faults: a journal damaged in the middle is refused (never truncated), and a disk
that fills or fails mid-mission never lets an agent send a message whose record is not
durable; after the disk is fixed the agent restarts from its journal and nothing is lost or
doubled."""

from __future__ import annotations

import errno
from collections.abc import Iterable
from pathlib import Path

import pytest

from agent.cli import main
from agent.protocol.records import PoseRec, Record
from agent.storage.journal import Journal, JournalCorrupt, JournalFailed
from agent.testing.memsim import MemoryMission
from tests.agent_helpers import fixed_motion, random_scene
from tests.conftest import scenario_path


def _mission_journal(tmp_path: Path) -> Path:
    """The journal of agent A after a whole in-memory mission (many records)."""
    sc = random_scene(3, 9, 5)
    m = MemoryMission(sc, tmp_path / "m", motion=fixed_motion(5))
    assert m.run(200.0)
    m.close()
    return tmp_path / "m" / sc.agents[0].id / "journal.bin"


def _replay(state: Path) -> list[Record]:
    """Open, replay and close the journal in ``state``."""
    j = Journal(state)
    try:
        return j.replay()
    finally:
        j.close()


def _frame_offsets(data: bytes) -> list[int]:
    out, pos = [], 0
    while pos + 8 <= len(data):
        out.append(pos)
        pos += 8 + int.from_bytes(data[pos:pos + 4], "little")
    return out


def test_a_flipped_bit_in_the_middle_is_refused_and_the_file_kept(tmp_path: Path) -> None:
    path = _mission_journal(tmp_path)
    data = bytearray(path.read_bytes())
    offs = _frame_offsets(bytes(data))
    assert len(offs) > 6
    k = len(offs) // 2
    data[offs[k] + 8] ^= 0x10  # one bit of record k + 1's payload
    path.write_bytes(bytes(data))
    with pytest.raises(JournalCorrupt) as e:
        _replay(path.parent)
    assert str(e.value) == (
        f"journal {path}: record {k + 1} (byte {offs[k]}) is damaged but valid records follow "
        f"it (from byte {offs[k + 1]}); this drone's ledger cannot be trusted, so it stays out "
        "of the mission: the team fences it after lost_after and adopts its landmarks; put the "
        "drone back to work under a new id with --join-at, or restore the file from a copy (do "
        "not move it away and restart under the same id)")
    assert path.read_bytes() == bytes(data)  # untouched


def test_a_block_lost_in_the_middle_is_refused(tmp_path: Path) -> None:
    path = _mission_journal(tmp_path)
    data = path.read_bytes()
    offs = _frame_offsets(data)
    k = len(offs) // 3
    cut = data[:offs[k] + 5] + data[offs[k + 1] + 3:]  # part of two records gone
    path.write_bytes(cut)
    with pytest.raises(JournalCorrupt, match=rf"record {k + 1} \(byte {offs[k]}\) is damaged"):
        _replay(path.parent)
    assert path.read_bytes() == cut


def test_a_torn_last_write_is_cut_off(tmp_path: Path) -> None:
    path = _mission_journal(tmp_path)
    data = path.read_bytes()
    offs = _frame_offsets(data)
    n = len(_replay(path.parent))
    path.write_bytes(data[:offs[-1] + 11])  # the last record half written
    j = Journal(path.parent)
    assert len(j.replay()) == n - 1 and j.torn_bytes == 11
    j.close()
    assert path.read_bytes() == data[:offs[-1]]


def test_the_agent_command_refuses_a_damaged_journal_in_one_line(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    state = tmp_path / "A"
    j = Journal(state)
    j.replay()
    for k in range(5):
        j.append([PoseRec(p=(float(k), 0.0, 0.0), v=(1.0, 0.0, 0.0), t=float(k))], sync=True)
    j.close()
    path = state / "journal.bin"
    data = bytearray(path.read_bytes())
    data[12] ^= 0x01
    path.write_bytes(bytes(data))
    code = main(["agent", "--id", "A", "--scenario", str(scenario_path("hexagon_5_3")),
                 "--state-dir", str(state), "--connect", "tcp/127.0.0.1:9", "--connect-wait",
                 "0"])
    err = capsys.readouterr().err
    assert code == 2
    assert err.startswith(f"viscover: error: journal {path}: record 1 (byte 0) is damaged")
    assert err.count("\n") == 1 and path.read_bytes() == bytes(data)


class _Disk:
    """A disk whose writes fail with ENOSPC once ``full`` is set."""

    def __init__(self) -> None:
        self.full = False

    def check_write(self) -> None:
        if self.full:
            raise OSError(errno.ENOSPC, "No space left on device")


class FillingJournal(Journal):
    """A journal whose disk fills at its ``at``-th trade-relevant append."""

    def __init__(self, d: Path, at: int) -> None:
        self.disk = _Disk()
        super().__init__(d)
        self.at, self.n = at, 0

    def _write(self, data: bytes) -> None:
        self.disk.check_write()
        super()._write(data)

    def append(self, records: Iterable[object], sync: bool | None = None) -> None:
        recs = list(records)
        if not all(isinstance(r, PoseRec) for r in recs):
            self.n += 1
            if self.n == self.at:
                self.disk.full = True
        super().append(recs, sync)


def test_journal_failure_is_sticky(tmp_path: Path) -> None:
    j = FillingJournal(tmp_path / "A", at=1)
    j.replay()
    j.disk.full = True
    rec = PoseRec(p=(0.0, 0.0, 0.0), v=(1.0, 0.0, 0.0), t=0.0)
    with pytest.raises(JournalFailed, match="cannot write \\(No space left on device\\)"):
        j.append([rec, rec.__class__(p=(1.0, 0.0, 0.0), v=(1.0, 0.0, 0.0), t=1.0)])
    j.disk.full = False  # space comes back: the journal still refuses (its state is unknown)
    with pytest.raises(JournalFailed):
        j.append([rec], sync=True)
    j.close()


@pytest.mark.parametrize("victim", ["N0", "N1"])
def test_disk_full_at_every_write_loses_and_doubles_nothing(tmp_path: Path, victim: str) -> None:
    """The victim's disk fills at its n-th trade write, for every n of a mission: it answers
    nothing from then on and leaves; restarted on a fixed disk from its journal, the mission
    completes with every landmark owned once."""
    sc = random_scene(3, 9, 5)
    runs = 0
    for at in range(3, 14):
        holder: dict[str, MemoryMission] = {}
        armed = [True]

        def factory(aid: str, d: Path, at: int = at, armed: list[bool] = armed) -> Journal:
            if aid == victim and armed[0]:
                armed[0] = False
                return FillingJournal(d, at)
            return Journal(d)

        m = MemoryMission(sc, tmp_path / f"{victim}-{at}", motion=fixed_motion(5),
                          journal_factory=factory)
        holder["m"] = m
        left_at: float | None = None
        while m.net.now < 300.0 and not m.complete:
            try:
                m.step()
            except JournalFailed:
                m.crash(victim)  # the agent leaves the mission (the process exits)
                left_at = m.net.now
            if left_at is not None and m.net.now > left_at + 1.0:
                m.start(victim)  # disk fixed; restart from the journal
                left_at = None
        try:
            assert m.complete, f"not complete (disk of {victim} full at write {at})"
            assert m.violations == [], m.violations[:5]
            assert m.final_violations() == []
            assert sorted(m.owner_of()) == sorted(sc.landmark_ids)
        finally:
            m.close()
        runs += 1
    assert runs == 11
