"""The tables an inspection flies by, computed once before take-off from the scenario alone
(so every drone and the simulator compute the same): the capture table
(:func:`agent.structure.inspection.capture_table`) and the route grid around the structure
(:class:`agent.structure.routes.RouteGrid`)."""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np

from agent.core.inspection import CaptureTable
from agent.structure.inspection import capture_table
from agent.structure.routes import RouteGrid
from agent.world.structure import structure_model

if TYPE_CHECKING:
    from agent.config.scenario import Scenario


def mission_tables(sc: Scenario, progress: Callable[[str], None] | None = None
                   ) -> tuple[CaptureTable, RouteGrid | None]:
    """The capture table of an inspection scenario (structure resolved; view landmarks
    captured from their sectors) and, with a structure, its route grid (cells of edge
    ``margin`` over the mission space bounded to the structure plus 3·d_opt); ``progress``
    gets a line now and then."""
    assert sc.inspection is not None, "not an inspection mission"
    model = None if sc.structure is None else structure_model(sc.structure)
    table = capture_table(sc.q, sc.u, sc.d_opt, sc.inspection, sc.space.lo, sc.space.hi,
                          model, sc.visibility == "occlusion", sc.view_axis, sc.view_cos,
                          progress)
    if model is None:
        return table, None
    pad = 3.0 * sc.d_opt + model.margin
    lo = np.maximum(model.mesh.bounds[0] - pad, sc.space.lo)
    hi = np.minimum(model.mesh.bounds[1] + pad, sc.space.hi)
    return table, RouteGrid(model.mesh, lo, hi, model.margin, model.margin)
