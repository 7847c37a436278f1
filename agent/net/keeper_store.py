"""The fence record on disk: a router restarted (a power cut, a crash, an upgrade) still tells
a drone that comes back late what its team decided (:mod:`agent.net.keeper`).

``viscover router --state-dir DIR`` keeps ``DIR/fence-record.msgpack``: every mission's
proofs (per sender), the incarnations heard and who reported complete, rewritten whole after
each change (write to a temporary file, fsync, rename: a crash leaves the old file or the new
one, never half of one). The liveliness times are not stored: after a restart every agent the
record heard counts as silent since the restart and every live agent as up since then, so a
drone whose journal is new is still refused while its team is live (the conservative side).

A file that does not decode is set aside (``.damaged``), said in one line, and the keeper
starts empty: the router must come up, and an empty record is what a router without
``--state-dir`` has.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path
from typing import Annotated, Final

import msgspec

from agent.wire.peer import MAX_FENCE_PROOFS, MAX_IDS, AgentId, FenceProof, Incarnation

_log = logging.getLogger(f"viscover.{__name__}")

#: File name of the record in ``--state-dir``.
RECORD_FILE: Final = "fence-record.msgpack"
#: Schema of :class:`StoredRecords`.
STORE_SCHEMA: Final = 1


class StoredMission(msgspec.Struct, kw_only=True):
    """What a keeper keeps of one mission across restarts."""

    proofs: Annotated[dict[AgentId, Annotated[list[FenceProof], msgspec.Meta(
        max_length=MAX_FENCE_PROOFS)]], msgspec.Meta(max_length=MAX_IDS)] = \
        msgspec.field(default_factory=dict)
    seen: Annotated[dict[AgentId, Incarnation], msgspec.Meta(max_length=MAX_IDS)] = \
        msgspec.field(default_factory=dict)
    complete: Annotated[list[AgentId], msgspec.Meta(max_length=MAX_IDS)] = \
        msgspec.field(default_factory=list)


class StoredRecords(msgspec.Struct, kw_only=True):
    """The file's content: mission name -> what was kept of it."""

    missions: dict[AgentId, StoredMission] = msgspec.field(default_factory=dict)
    schema: int = STORE_SCHEMA


_DECODER = msgspec.msgpack.Decoder(StoredRecords)


def load_records(state_dir: Path) -> StoredRecords:
    """The records kept in ``state_dir`` (empty if none; a damaged file is set aside, said in
    one line)."""
    path = state_dir / RECORD_FILE
    try:
        raw = path.read_bytes()
    except FileNotFoundError:
        return StoredRecords()
    try:
        got = _DECODER.decode(raw)
        if got.schema != STORE_SCHEMA:
            raise msgspec.ValidationError(f"schema {got.schema}, this build reads "
                                          f"{STORE_SCHEMA}")
        return got
    except (msgspec.DecodeError, msgspec.ValidationError) as e:
        aside = path.with_suffix(".damaged")
        os.replace(path, aside)
        _log.error("router: the fence record %s does not decode (%s): set aside as %s; "
                   "starting with an empty record", path, e, aside.name)
        return StoredRecords()


def save_records(state_dir: Path, records: StoredRecords) -> None:
    """Replace the file in ``state_dir`` by ``records`` atomically (tmp, fsync, rename)."""
    path = state_dir / RECORD_FILE
    tmp = path.with_suffix(".tmp")
    with open(tmp, "wb") as fh:
        fh.write(msgspec.msgpack.encode(records))
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, path)
    fd = os.open(state_dir, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)
