"""Append-only journal of an agent's durable state (records of :mod:`agent.protocol.records`).

File format: a sequence of frames ``[u32 length][u32 crc32(payload)][payload]`` (little
endian), the payload being one msgpack-encoded record. :meth:`Journal.replay` tells a **torn
write** from **damage**:

* torn: the file ends inside the last frame (its header or its payload is incomplete), or
  ends in zeros (a file extended by a crash before its data reached the disk). That frame was
  being written when the process died, so nothing was sent that depends on it (every record
  a message depends on is fsynced before the message): it is cut off and later appends follow
  valid data;
* damaged: a *complete* frame whose CRC fails (a flipped bit, a bad block), or a bad frame
  followed by valid ones (damage in the middle). Such a record
  may be one a message was sent on (a vote, a prepared trade), so it is never dropped:
  :class:`JournalCorrupt` is raised and the file is left untouched. The drone then stays out
  of the mission and the team fences it and adopts its landmarks (README: "Lost drones");
  it rejoins under a new id with ``--join-at``. Moving the journal away and restarting under
  the same id would start from the scenario's sets (doubling what it gave away, losing what
  it received), so a drone whose journal is new but whose id the team already heard is
  refused (:mod:`agent.runners.recovery`).

An intact frame that does not decode (another build's format) raises
:class:`~agent.protocol.records.JournalMismatch`.

Scenario binding: a journal opened with ``bind`` (a :class:`JournalHeader`: the scenario's
digest, :mod:`agent.config.digest`) starts with that header frame, written and fsynced when the
journal is created. Replay checks it first, before a torn tail is cut or anything appended: a
journal of another scenario raises :class:`~agent.protocol.records.JournalMismatch`, and so
does a journal without a header (written before journals were bound: it cannot be checked,
and using the wrong one silently loses landmarks, so it is refused rather than trusted).
Without ``bind`` (in-memory missions, tests) the header, if any, is read and not checked.

Write failures (ENOSPC, EIO): the append raises :class:`JournalFailed`, and so does every
later one, so no message that depends on a record that is not durable can be sent. The file is
written unbuffered (one ``write`` per append, retried until every byte is written), so nothing
is left in a buffer to be written later, and :meth:`Journal.close` never raises: a disk that
fails while the agent stops leaves at most a torn last frame.

Durability: :meth:`Journal.append` ``fsync``s when asked, by default when a record is in
:data:`agent.protocol.records.DURABLE` (prepared, commit, committed, genesis, start: what a
message about to be sent depends on); other records (offers, restored, done, poses) are only
flushed to the OS and reach the disk with the next ``fsync``. Losing them in a crash is
harmless by design (see :mod:`agent.protocol.machine`).

One process at a time: the journal takes an exclusive ``flock`` on its file; a second agent
process with the same id and state directory fails with :class:`JournalLocked`.
"""

from __future__ import annotations

import errno
import fcntl
import os
import struct
import threading
import zlib
from collections.abc import Iterable
from pathlib import Path

import msgspec

from agent.errors import UsageError
from agent.protocol.records import DURABLE, JournalMismatch, Record

_HEADER = struct.Struct("<II")
#: Largest accepted record payload [bytes] (a frame claiming more is treated as torn).
MAX_RECORD = 64 * 1024 * 1024


class JournalHeader(msgspec.Struct, tag_field="rec", tag="journal", kw_only=True):
    """The first frame of a journal bound to a scenario (never a record: a build that does
    not know it reports the journal as incompatible)."""

    digest: str  #: :func:`agent.config.digest.scenario_digest`
    scenario: str  #: the scenario's name
    source: str = ""  #: the scenario file the journal was created with

    def names(self) -> str:
        """``name (file)``, for messages."""
        return f"{self.scenario} ({self.source})" if self.source else self.scenario


class JournalLocked(UsageError, RuntimeError):
    """Another live process holds this journal."""


class JournalCorrupt(UsageError):
    """The journal holds a damaged record (not a torn last write): it is not truncated."""


class JournalFailed(UsageError):
    """A record could not be written or made durable (ENOSPC, EIO). Nothing that depends on
    it may be sent: every later append raises this too, and the agent leaves the mission."""


def _frame_at(data: bytes, pos: int) -> bytes | None:
    """The payload of an intact frame at ``pos`` (complete, plausible length, CRC holds)."""
    length, crc = _HEADER.unpack_from(data, pos)
    end = pos + _HEADER.size + length
    if length > MAX_RECORD or end > len(data):
        return None
    payload = data[pos + _HEADER.size:end]
    return payload if zlib.crc32(payload) == crc else None


def _torn(data: bytes, pos: int) -> bool:
    """Whether the bytes from ``pos`` on are a torn last write: an incomplete frame (header
    or payload cut short) or zeros (a crash extended the file before its data was written)."""
    rest = len(data) - pos
    if rest < _HEADER.size or not data[pos:].strip(b"\0"):
        return True
    length: int = _HEADER.unpack_from(data, pos)[0]
    return pos + _HEADER.size + length > len(data)


def _next_valid_frame(data: bytes, start: int) -> int | None:
    """Offset of the first intact, non-empty frame at or after ``start`` (None: none)."""
    for pos in range(start, len(data) - _HEADER.size + 1):
        length = int.from_bytes(data[pos:pos + 4], "little")
        if 0 < length <= len(data) - pos - _HEADER.size and _frame_at(data, pos) is not None:
            return pos
    return None


def _frame(payload: bytes) -> bytes:
    """``payload`` framed: length, CRC, payload."""
    return _HEADER.pack(len(payload), zlib.crc32(payload)) + payload


def _header_of(payload: bytes) -> JournalHeader | None:
    """The header in a frame's payload, or None (a record, or anything else)."""
    try:
        return msgspec.msgpack.decode(payload, type=JournalHeader)
    except (msgspec.DecodeError, msgspec.ValidationError):
        return None


def read_header(path: str | Path) -> JournalHeader | None:
    """The header of the journal file ``path`` without locking or writing anything (None: no
    file, or no intact header frame first)."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(_HEADER.size)
            if len(head) < _HEADER.size:
                return None
            length, _crc = _HEADER.unpack(head)
            data = head + fh.read(min(length, 1 << 16))
    except OSError:
        return None
    payload = _frame_at(data, 0)
    return None if payload is None else _header_of(payload)


def default_state_dir(mission: str, agent_id: str) -> Path:
    """``$XDG_STATE_HOME/viscover/<mission>/<id>`` (default ``~/.local/state/...``)."""
    base = os.environ.get("XDG_STATE_HOME") or str(Path.home() / ".local" / "state")
    return Path(base) / "viscover" / mission / agent_id


class Journal:
    """The journal file ``<state_dir>/journal.bin`` (created with its directory), bound to
    the scenario of ``bind`` if given (module docstring)."""

    def __init__(self, state_dir: str | Path, bind: JournalHeader | None = None) -> None:
        self.dir = Path(state_dir)
        self.bind = bind
        self.header: JournalHeader | None = None  #: the journal's header (after replay)
        self.dir.mkdir(parents=True, exist_ok=True)
        self.path = self.dir / "journal.bin"
        self._lock = threading.Lock()
        # Unbuffered: every append is written at once (nothing waits in a buffer to be
        # written, or to fail, later); closed in close().
        self._fh = open(self.path, "a+b", buffering=0)
        self._closed = False
        try:
            fcntl.flock(self._fh.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            self._fh.close()
            raise JournalLocked(f"journal {self.path} is in use by another process") from None
        self._enc = msgspec.msgpack.Encoder()
        self._dec = msgspec.msgpack.Decoder(Record)
        self.records_written = 0
        self.failed: JournalFailed | None = None
        self._replayed: list[Record] | None = None
        self.syncs = 0
        self.synced_size = 0  #: file size [bytes] at the last fsync
        self.torn_bytes = 0

    def replay(self) -> list[Record]:
        """Read every valid record; truncate a torn tail. Call before appends (later calls
        return the same records).

        An incomplete last frame (or a zero-filled tail) is the torn last write of a crash:
        it is cut off. A complete frame whose CRC fails, at the end or followed by valid
        frames, is damage (a flipped bit, a lost block): :class:`JournalCorrupt` is raised
        and the file is left as it is (module docstring)."""
        with self._lock:
            if self._replayed is not None:
                return list(self._replayed)
            self._fh.seek(0)
            data = self._fh.read()
            out: list[Record] = []
            pos = 0
            n = len(data)
            while pos + _HEADER.size <= n:
                payload = _frame_at(data, pos)
                if payload is None:
                    break
                if pos == 0:
                    self.header = _header_of(payload)
                    self._check_binding()  # before anything is cut off or appended
                    if self.header is not None:
                        pos += _HEADER.size + len(payload)
                        continue
                try:
                    out.append(self._dec.decode(payload))
                except (msgspec.DecodeError, msgspec.ValidationError) as e:
                    # An intact frame (its CRC holds) that does not decode was written by an
                    # incompatible build: never truncate it away.
                    raise JournalMismatch(
                        f"journal {self.path}: record {len(out) + 1} was written by an "
                        f"incompatible viscover version ({e}); move the file away or use a "
                        "fresh --state-dir") from None
                pos += _HEADER.size + len(payload)
            if pos < n:
                self._cut_or_refuse(data, pos, len(out) + 1)
            if pos == 0 and self.bind is not None:  # a new journal: bind it to its scenario
                try:
                    self._write(_frame(msgspec.msgpack.encode(self.bind)))
                    os.fsync(self._fh.fileno())
                except OSError as e:
                    self.failed = JournalFailed(
                        f"journal {self.path}: cannot write its header ({e.strerror or e}); "
                        "free space on that disk (or give --state-dir on another) and start "
                        "again")
                    raise self.failed from None
                self.header = self.bind
            self._fh.seek(0, os.SEEK_END)
            self.synced_size = self._fh.tell()
            self._replayed = out
            return list(out)

    def _cut_or_refuse(self, data: bytes, pos: int, record: int) -> None:
        """The frame at ``pos`` (record number ``record``) is not intact: cut a torn last
        write off; raise :class:`JournalCorrupt` for damage (module docstring)."""
        later = _next_valid_frame(data, pos + 1)
        stay_out = ("this drone's ledger cannot be trusted, so it stays out of the mission: "
                    "the team fences it after lost_after and adopts its landmarks; put the "
                    "drone back to work under a new id with --join-at, or restore the file "
                    "from a copy (do not move it away and restart under the same id)")
        if later is not None:
            raise JournalCorrupt(
                f"journal {self.path}: record {record} (byte {pos}) is damaged but valid "
                f"records follow it (from byte {later}); {stay_out}")
        if not _torn(data, pos):
            raise JournalCorrupt(
                f"journal {self.path}: record {record} (byte {pos}), the last one, is complete "
                f"but damaged (its checksum fails: not a torn write); {stay_out}")
        self.torn_bytes = len(data) - pos
        self._fh.truncate(pos)
        os.fsync(self._fh.fileno())

    def _write(self, data: bytes) -> None:
        """Write every byte of ``data`` at the end (an unbuffered write may be short)."""
        view = memoryview(data)
        while view:
            n = self._fh.write(view)
            if not n:
                raise OSError(errno.EIO, "short write")
            view = view[n:]

    def _check_binding(self) -> None:
        """With ``bind``: a :class:`JournalMismatch` unless the header read is of the same
        scenario (one line naming the journal's folder, both scenarios and the fix)."""
        want, got = self.bind, self.header
        if want is None or (got is not None and got.digest == want.digest):
            return
        fresh = "give it a fresh --state-dir"
        if got is None:
            raise JournalMismatch(
                f"journal {self.dir} has no scenario digest: it was written by an older, "
                f"incompatible viscover version and cannot be checked against scenario "
                f"{want.names()}; finish that mission with the version that wrote it, or {fresh}")
        if got.scenario == want.scenario:
            raise JournalMismatch(
                f"journal {self.dir} belongs to another version of scenario {got.names()} "
                f"(digest {got.digest}), not to {want.names()} (digest {want.digest}): start "
                f"this agent with the scenario file the journal was written with, or {fresh}")
        raise JournalMismatch(
            f"journal {self.dir} belongs to scenario {got.names()}, not to {want.names()}: start "
            f"this agent with --scenario {got.source or got.scenario}, or {fresh}")

    def append(self, records: Iterable[object], sync: bool | None = None) -> None:
        """Append ``records``; ``fsync`` if ``sync`` is True, or (None) if any is durable."""
        recs = list(records)
        if not recs:
            return
        frames = []
        for rec in recs:
            frames.append(_frame(self._enc.encode(rec)))
        if sync is None:
            sync = any(isinstance(r, DURABLE) for r in recs)
        with self._lock:
            if self._closed:
                raise RuntimeError("journal is closed")
            if self.failed is not None:
                raise self.failed
            try:
                self._write(b"".join(frames))
                if sync:
                    os.fsync(self._fh.fileno())
            except OSError as e:
                self.failed = JournalFailed(
                    f"journal {self.path}: cannot write ({e.strerror or e}); this agent stops "
                    "answering and leaves the mission")
                raise self.failed from None
            if sync:
                self.syncs += 1
                self.synced_size = self._fh.tell()
            self.records_written += len(recs)

    def close(self) -> None:
        """fsync (unless the journal failed), release the lock and close; idempotent; never
        raises (a disk failing now leaves at most a torn last frame)."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
            try:
                if self.failed is None:
                    os.fsync(self._fh.fileno())
            except OSError:
                pass  # the disk failed now: nothing more can be made durable
            try:
                self._fh.close()  # closing releases the flock
            except OSError:
                pass
