"""The captured set of an inspection: a grow-only set of landmark ids merged by union.

Every drone keeps its own copy and merges what its peers say they captured. Union is
idempotent, commutative and associative, so copies that have heard the same captures agree
whatever the order, duplication or loss of the messages in between, and a landmark once
captured is never un-captured (a state-based grow-only set). The caller journals what
:meth:`CapturedSet.merge` reports as new before it publishes it.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np
from numpy.typing import NDArray

from agent.wire.peer import unpack_bits


class CapturedSet:
    """Landmark ids captured so far (grow-only)."""

    def __init__(self, ids: Iterable[int] = ()) -> None:
        self._ids: set[int] = {int(i) for i in ids}

    def merge(self, ids: Iterable[int]) -> list[int]:
        """Union with ``ids``; returns the ids that were not in the set before, sorted."""
        new = {int(i) for i in ids} - self._ids
        self._ids |= new
        return sorted(new)

    def __contains__(self, lid: object) -> bool:
        return lid in self._ids

    def __len__(self) -> int:
        return len(self._ids)

    def ids(self) -> list[int]:
        """The captured ids, sorted."""
        return sorted(self._ids)

    def mask(self, landmark_ids: NDArray[np.int64]) -> NDArray[np.bool_]:
        """Per landmark row (ids ``landmark_ids`` (m,)): captured or not."""
        if not self._ids:
            return np.zeros(landmark_ids.shape, dtype=np.bool_)
        return np.isin(landmark_ids, np.fromiter(self._ids, dtype=np.int64, count=len(self)))


def union_of_bits(sets: Iterable[bytes], m: int) -> NDArray[np.bool_]:
    """The union (m,) of published captured sets (bit sets of m landmarks); a malformed one
    counts for nothing."""
    out = np.zeros(m, dtype=np.bool_)
    for bits in sets:  # one set per drone
        mask = unpack_bits(bits, m) if bits else None
        if mask is not None:
            out |= mask
    return out


def captured_count(sets: Iterable[bytes], m: int) -> int:
    """How many of m landmarks the published captured sets name, together."""
    return int(union_of_bits(sets, m).sum())
