"""Seeded, replayable fault injection for the transports.

A :class:`FaultInjector` is asked once per message (kind, peer, direction) and answers with a
:class:`Decision`: how many copies to deliver and the delay of each, in seconds. An empty
``delays_s`` means the message is dropped. Decisions are a pure function of the seed, the
config and the sequence of calls, so a run with the same seed and the same call order sees
the same faults. Every decision other than "deliver once now" is written as one JSON line to
the fault log (if a path is given) and kept in memory; :class:`ReplayInjector` replays such a
log by call number.

Directions: ``"out"`` (publish, query or reply leaving this node) and ``"in"`` (sample arriving
at this node). Peers in ``partition`` are unreachable both ways: anything to or from them is
dropped.
"""

from __future__ import annotations

import random
import threading
from pathlib import Path
from typing import IO, Literal

import msgspec

Direction = Literal["out", "in"]


class FaultConfig(msgspec.Struct, kw_only=True):
    """Fault probabilities and delays.

    Attributes:
        drop_out: probability of dropping an outgoing message, per kind.
        drop_in: probability of dropping an incoming message, per kind.
        drop_default: probability used for kinds not in ``drop_out``/``drop_in``.
        delay_s: fixed delay added to every delivered copy, seconds.
        jitter_s: extra uniform random delay in [0, jitter_s) per copy, seconds; copies and
            consecutive messages may overtake each other, which is how reordering happens.
        duplicate: probability that a delivered message is delivered twice.
        partition: peer ids that are unreachable.
    """

    drop_out: dict[str, float] = msgspec.field(default_factory=dict)
    drop_in: dict[str, float] = msgspec.field(default_factory=dict)
    drop_default: float = 0.0
    delay_s: float = 0.0
    jitter_s: float = 0.0
    duplicate: float = 0.0
    partition: list[str] = msgspec.field(default_factory=list)

    def __post_init__(self) -> None:
        probs = [self.drop_default, self.duplicate, *self.drop_out.values(), *self.drop_in.values()]
        if any(not 0.0 <= p <= 1.0 for p in probs):
            raise ValueError("fault probabilities must be within [0, 1]")
        if self.delay_s < 0.0 or self.jitter_s < 0.0:
            raise ValueError("delay_s and jitter_s must be >= 0 seconds")

    def drop_probability(self, kind: str, direction: Direction) -> float:
        """Drop probability for one kind and direction."""
        table = self.drop_out if direction == "out" else self.drop_in
        return table.get(kind, self.drop_default)


class Decision(msgspec.Struct, frozen=True):
    """What to do with one message: deliver ``len(delays_s)`` copies, each after its delay
    in seconds. ``reason`` is ``"ok"``, ``"partition"``, ``"drop"``, ``"duplicate"`` or
    ``"delay"``."""

    delays_s: tuple[float, ...]
    reason: str = "ok"

    @property
    def dropped(self) -> bool:
        """True if no copy is delivered."""
        return not self.delays_s

    @property
    def copies(self) -> int:
        """Number of copies delivered."""
        return len(self.delays_s)


DELIVER_NOW = Decision(delays_s=(0.0,))


class FaultLogRecord(msgspec.Struct, kw_only=True):
    """One line of the JSONL fault log."""

    seq: int
    kind: str
    peer: str | None
    direction: str
    reason: str
    delays_s: list[float]


class FaultInjector:
    """Seeded fault decisions, safe to call from several threads.

    Args:
        config: the fault model.
        seed: RNG seed; same seed + same call sequence gives the same decisions.
        log: optional JSONL path; every non-trivial decision is appended as one line.
        keep_records: also keep those decisions in :attr:`records` (memory grows with them).
    """

    def __init__(
        self,
        config: FaultConfig,
        seed: int = 0,
        log: str | Path | None = None,
        *,
        keep_records: bool = True,
    ) -> None:
        self.config = config
        self.seed = seed
        self._rng = random.Random(seed)
        self._lock = threading.Lock()
        self._seq = 0
        self._partition = frozenset(config.partition)
        self.keep_records = keep_records
        self.records: list[FaultLogRecord] = []
        self._file: IO[bytes] | None = open(log, "ab") if log is not None else None
        self._encoder = msgspec.json.Encoder()

    def decide(self, kind: str, peer: str | None, direction: Direction) -> Decision:
        """Decide the fate of one message of ``kind`` to/from ``peer`` going ``direction``."""
        cfg = self.config
        with self._lock:
            seq = self._seq
            self._seq += 1
            # A fixed number of draws per call keeps the stream aligned across configs.
            u_drop = self._rng.random()
            u_dup = self._rng.random()
            j1 = self._rng.random()
            j2 = self._rng.random()
            if peer is not None and peer in self._partition:
                decision = Decision(delays_s=(), reason="partition")
            elif u_drop < cfg.drop_probability(kind, direction):
                decision = Decision(delays_s=(), reason="drop")
            else:
                delays = [cfg.delay_s + cfg.jitter_s * j1]
                if u_dup < cfg.duplicate:
                    delays.append(cfg.delay_s + cfg.jitter_s * j2)
                if len(delays) > 1:
                    decision = Decision(delays_s=tuple(delays), reason="duplicate")
                elif delays[0] > 0.0:
                    decision = Decision(delays_s=tuple(delays), reason="delay")
                else:
                    decision = DELIVER_NOW
            if decision is not DELIVER_NOW:
                self._record(seq, kind, peer, direction, decision)
        return decision

    def _record(
        self, seq: int, kind: str, peer: str | None, direction: str, decision: Decision
    ) -> None:
        rec = FaultLogRecord(
            seq=seq,
            kind=kind,
            peer=peer,
            direction=direction,
            reason=decision.reason,
            delays_s=list(decision.delays_s),
        )
        if self.keep_records:
            self.records.append(rec)
        if self._file is not None:
            self._file.write(self._encoder.encode(rec) + b"\n")
            self._file.flush()

    @property
    def calls(self) -> int:
        """Number of decisions made so far."""
        with self._lock:
            return self._seq

    def close(self) -> None:
        """Close the log file, if any."""
        with self._lock:
            if self._file is not None:
                self._file.close()
                self._file = None


def read_fault_log(path: str | Path) -> list[FaultLogRecord]:
    """Read a JSONL fault log written by :class:`FaultInjector`."""
    decoder = msgspec.json.Decoder(FaultLogRecord)
    with open(path, "rb") as fh:
        return [decoder.decode(line) for line in fh if line.strip()]


class ReplayInjector(FaultInjector):
    """Replays a fault log: call number ``seq`` gets the logged decision, others deliver now.

    Kind, peer and direction are not checked against the log; the replay is faithful when the
    call sequence is the same as in the recorded run.
    """

    def __init__(self, records: list[FaultLogRecord] | str | Path) -> None:
        super().__init__(FaultConfig(), seed=0, log=None)
        recs = read_fault_log(records) if isinstance(records, (str, Path)) else records
        self._replay = {r.seq: Decision(delays_s=tuple(r.delays_s), reason=r.reason) for r in recs}

    def decide(self, kind: str, peer: str | None, direction: Direction) -> Decision:
        """Return the logged decision for this call number."""
        with self._lock:
            seq = self._seq
            self._seq += 1
            decision = self._replay.get(seq, DELIVER_NOW)
            if decision is not DELIVER_NOW:
                self._record(seq, kind, peer, direction, decision)
        return decision
