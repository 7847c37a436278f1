"""The scenario digest: what a journal or a run folder means, in 16 hex digits.

An agent's journal records landmark ids, versions and trades; those records only mean
something for the mission they were written in. :func:`scenario_digest` hashes exactly what
decides that meaning, so that a journal (:mod:`agent.storage.journal`) and a run folder's
``launch.json`` (:mod:`agent.mission.launcher`) can be bound to their scenario and a mismatch
refused before anything is written:

* the mission name (``name``: the default key prefix and journal folder);
* the mode (``dims``: 2-D planar or 3-D);
* every landmark: its id, position and normal (after a mesh structure has been sampled, so a
  structure scenario's digest covers the landmarks its mesh gave), rounded to 1 µm and 10⁻⁶
  so that the last bits of a sampling on another machine do not matter;
* the team and the initial sets: each agent's id and the ids of the landmarks it starts with.

Not in it: where the file is, the seed alone (it only matters through the landmarks it
samples), the planner's constants, ``d_opt``, ``duration``, the space, strategy, visibility,
``lost_after`` and the agents' start poses. Those change how the mission is flown, not which
landmarks a journal's records name or whom they belonged to at the start.
"""

from __future__ import annotations

import hashlib
from typing import TYPE_CHECKING

import msgspec
import numpy as np
from numpy.typing import NDArray

if TYPE_CHECKING:
    from agent.config.scenario import Scenario

#: Changes when the definition above changes (old digests then no longer match).
DIGEST_VERSION = "viscover-scenario-digest/1"


def scenario_digest(sc: Scenario) -> str:
    """16 hex digits of SHA-256 over what a journal of ``sc`` means (module docstring)."""
    ids = np.asarray(sc.landmark_ids, dtype=np.int64)
    order = np.argsort(ids, kind="stable")
    doc = {
        "v": DIGEST_VERSION,
        "name": sc.name,
        "dims": sc.dims,
        "ids": ids[order].tolist(),
        "q": _rounded(np.asarray(sc.q, dtype=np.float64)[order]),
        "u": _rounded(np.asarray(sc.u, dtype=np.float64)[order]),
        "team": sorted((a.id, sorted(int(ids[r]) for r in a.landmarks)) for a in sc.agents),
    }
    return hashlib.sha256(msgspec.msgpack.encode(doc)).hexdigest()[:16]


def _rounded(a: NDArray[np.float64]) -> list[list[int]]:
    """Coordinates as integers of 10⁻⁶ (µm for positions): exact, platform-independent."""
    out: list[list[int]] = np.rint(a * 1e6).astype(np.int64).tolist()
    return out
