"""Which published state of a sender is its latest, when anyone may publish anything (the open
profile is unauthenticated by design). Pure: times are passed in.

A sender's states form a stream: its incarnation (one per process start, from its journal) and
a sequence number that grows within the process. The newest (incarnation, seq) is normally
the latest. But one forged state with a huge incarnation (or sequence number) would then make
every genuine state look old for ever: the agents would wait on a state that never changes
and the observer would keep stale claims (false "lost" landmarks, no completion).

:class:`LatestStates` bounds what a single message can hold up: the current stream keeps its
place only while it speaks; once it has been silent for ``quiet_s`` a lower stream takes over
as soon as two of its states (same incarnation, growing sequence numbers) arrive. A genuine
restart is never undone (the old process is dead: its stream never speaks again), and a single
late or duplicated old state changes nothing (it would need a second one after it).
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass
class _Head:
    incarnation: int
    seq: int
    heard: float  #: when a state of this stream was last accepted [s]


class LatestStates:
    """The current stream of each sender (see the module docstring).

    Args:
        quiet_s: how long [s] the current stream must be silent before another takes over.
    """

    def __init__(self, quiet_s: float) -> None:
        self.quiet_s = quiet_s
        self._head: dict[str, _Head] = {}
        self._candidate: dict[str, tuple[int, int]] = {}

    def offer(self, sender: str, incarnation: int, seq: int, now: float) -> bool:
        """Whether the state (``incarnation``, ``seq``) of ``sender`` heard at ``now`` [s] is
        its latest (then it becomes the current head)."""
        head = self._head.get(sender)
        if head is None or (incarnation, seq) > (head.incarnation, head.seq):
            self._head[sender] = _Head(incarnation, seq, now)
            self._candidate.pop(sender, None)
            return True
        if (incarnation, seq) == (head.incarnation, head.seq) or now - head.heard <= self.quiet_s:
            return False
        cand = self._candidate.get(sender)
        if cand is not None and cand[0] == incarnation and seq > cand[1]:
            self._head[sender] = _Head(incarnation, seq, now)
            del self._candidate[sender]
            return True
        self._candidate[sender] = (incarnation, seq)
        return False

    def forget(self, sender: str) -> None:
        """Drop what is known of ``sender``."""
        self._head.pop(sender, None)
        self._candidate.pop(sender, None)
