"""Append-only journal of an agent's durable state (records of :mod:`agent.protocol.records`).

File format: a sequence of frames ``[u32 length][u32 crc32(payload)][payload]`` (little
endian), the payload being one msgpack-encoded record. :meth:`Journal.replay` returns every
record up to the first frame that is incomplete or fails its CRC (a torn write from a crash)
and truncates the file there so later appends follow valid data. An intact frame that does not
decode (another build's format) raises :class:`~agent.protocol.records.JournalMismatch` instead.

Durability: :meth:`Journal.append` ``fsync``s when asked, by default when a record is in
:data:`agent.protocol.records.DURABLE` (prepared, commit, committed, genesis, start: what a
message about to be sent depends on); other records (offers, restored, done, poses) are only
flushed to the OS and reach the disk with the next ``fsync``. Losing them in a crash is
harmless by design (see :mod:`agent.protocol.machine`).

One process at a time: the journal takes an exclusive ``flock`` on its file; a second agent
process with the same id and state directory fails with :class:`JournalLocked`.
"""

from __future__ import annotations

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


class JournalLocked(UsageError, RuntimeError):
    """Another live process holds this journal."""


def default_state_dir(mission: str, agent_id: str) -> Path:
    """``$XDG_STATE_HOME/viscover/<mission>/<id>`` (default ``~/.local/state/...``)."""
    base = os.environ.get("XDG_STATE_HOME") or str(Path.home() / ".local" / "state")
    return Path(base) / "viscover" / mission / agent_id


class Journal:
    """The journal file ``<state_dir>/journal.bin`` (created with its directory)."""

    def __init__(self, state_dir: str | Path) -> None:
        self.dir = Path(state_dir)
        self.dir.mkdir(parents=True, exist_ok=True)
        self.path = self.dir / "journal.bin"
        self._lock = threading.Lock()
        self._fh = open(self.path, "a+b")  # closed in close()
        try:
            fcntl.flock(self._fh.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            self._fh.close()
            raise JournalLocked(f"journal {self.path} is in use by another process") from None
        self._enc = msgspec.msgpack.Encoder()
        self._dec = msgspec.msgpack.Decoder(Record)
        self.records_written = 0
        self.syncs = 0
        self.synced_size = 0  #: file size [bytes] at the last fsync
        self.torn_bytes = 0

    def replay(self) -> list[Record]:
        """Read every valid record; truncate a torn or corrupt tail. Call once, before appends."""
        with self._lock:
            self._fh.seek(0)
            data = self._fh.read()
            out: list[Record] = []
            pos = 0
            n = len(data)
            while pos + _HEADER.size <= n:
                length, crc = _HEADER.unpack_from(data, pos)
                end = pos + _HEADER.size + length
                if length > MAX_RECORD or end > n:
                    break
                payload = data[pos + _HEADER.size:end]
                if zlib.crc32(payload) != crc:
                    break
                try:
                    out.append(self._dec.decode(payload))
                except (msgspec.DecodeError, msgspec.ValidationError) as e:
                    # An intact frame (its CRC holds) that does not decode was written by an
                    # incompatible build: never truncate it away.
                    raise JournalMismatch(
                        f"journal {self.path}: record {len(out) + 1} was written by an "
                        f"incompatible viscover version ({e}); move the file away or use a "
                        "fresh --state-dir") from None
                pos = end
            if pos < n:
                self.torn_bytes = n - pos
                self._fh.truncate(pos)
                self._fh.flush()
                os.fsync(self._fh.fileno())
            self._fh.seek(0, os.SEEK_END)
            self.synced_size = self._fh.tell()
            return out

    def append(self, records: Iterable[object], sync: bool | None = None) -> None:
        """Append ``records``; ``fsync`` if ``sync`` is True, or (None) if any is durable."""
        recs = list(records)
        if not recs:
            return
        frames = []
        for rec in recs:
            payload = self._enc.encode(rec)
            frames.append(_HEADER.pack(len(payload), zlib.crc32(payload)) + payload)
        if sync is None:
            sync = any(isinstance(r, DURABLE) for r in recs)
        with self._lock:
            if self._fh.closed:
                raise RuntimeError("journal is closed")
            self._fh.write(b"".join(frames))
            self._fh.flush()
            if sync:
                os.fsync(self._fh.fileno())
                self.syncs += 1
                self.synced_size = self._fh.tell()
            self.records_written += len(recs)

    def close(self) -> None:
        """Flush, fsync, release the lock and close; idempotent."""
        with self._lock:
            if self._fh.closed:
                return
            try:
                self._fh.flush()
                os.fsync(self._fh.fileno())
            finally:
                self._fh.close()  # closing releases the flock
