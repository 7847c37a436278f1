"""Lines of sight through the structure: whether a camera at P sees a landmark q past the
structure's other faces (the structure's ray caster, :mod:`agent.structure.occlusion`). Used by
the capture table's builder (:mod:`agent.structure.inspection`) and by the agents' capture test
(:mod:`agent.runtime.moves.inspecting`): a module of its own so that the agent core imports the
test and not the builder (which casts in threads). Positions [m; world ENU]."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from agent.structure.model import StructureModel

__all__ = ["SIGHT_TOL", "sight_lines"]

Array = NDArray[np.float64]
Mask = NDArray[np.bool_]

#: Hits closer to a landmark than this fraction of the range (at least 1 m) along its line of
#: sight are its own face (the unlifted cast of :func:`sight_lines`).
SIGHT_TOL = 2e-4


def sight_lines(model: StructureModel | None, P: Array, q: Array, u: Array,
                pairs: tuple[NDArray[np.intp], ...]) -> Mask:
    """For (camera row, landmark row) pairs: the line of sight P[k] → q[j] is clear of the
    structure (all clear without a structure). Two batched casts, both must be clear: to the
    landmark lifted off its face (``caster.lift`` along u), and to the landmark itself with
    nothing closer than :data:`SIGHT_TOL` of the range before it (its own face): the first
    alone lets a ray through that grazes an edge standing proud of the face a few
    centimetres away (a part set into another) by less than the lift."""
    k, j = pairs
    if model is None or k.size == 0:
        return np.ones(k.size, dtype=np.bool_)
    caster = model.caster
    clear = np.asarray(caster.segment_clear(P[k], q[j] + caster.lift * u[j]), dtype=np.bool_)
    live = np.flatnonzero(clear)
    if live.size:
        rng = np.linalg.norm(q[j[live]] - P[k[live]], axis=1)
        clear[live] = caster.segment_clear(P[k[live]], q[j[live]],
                                           SIGHT_TOL * np.maximum(1.0, rng))
    return clear
