"""The owners of explicit landmarks, checked vectorised (``agent.config.parse._rows_of``): the
same first offending entry and owner as a per-landmark loop over each agent's list (the
reference below), on random lists with unknown ids, ids owned by an earlier agent and ids
listed twice; and the rows of a valid list in its order."""

from __future__ import annotations

import numpy as np

from agent.config.parse import _rows_of


def reference(ids: list[int], owned_by_0: set[int], listed: list[int]
              ) -> tuple[int | None, int | None]:
    """(first offending position, its owner: None unknown, 0 an earlier agent, -1 listed
    twice by this agent) as a loop over agent 1's list finds it."""
    owner = dict.fromkeys(owned_by_0, 0)
    for k, lid in enumerate(listed):
        if lid not in ids:
            return k, None
        if lid in owner:
            return k, owner[lid] if owner[lid] != 1 else -1
        owner[lid] = 1
    return None, None


def test_vectorised_owner_check_finds_what_the_loop_finds() -> None:
    rng = np.random.default_rng(0)
    for _ in range(3000):
        ids = rng.choice(50, size=int(rng.integers(0, 20)), replace=False).tolist()
        id_arr = np.asarray(ids, dtype=np.int64)
        owner = np.full(id_arr.size, -1, dtype=np.intp)
        taken = rng.random(id_arr.size) < 0.3
        owner[taken] = 0
        listed = rng.integers(0, 50, size=int(rng.integers(0, 8))).tolist()
        rows, bad, prev = _rows_of(id_arr, np.argsort(id_arr, kind="stable"), owner, listed)
        assert (bad, prev) == reference(ids, set(id_arr[taken].tolist()), listed)
        if bad is None:
            assert id_arr[rows].tolist() == listed
