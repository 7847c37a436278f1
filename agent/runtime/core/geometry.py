"""The landmarks of one agent's mission indexed by landmark id (rows into the scenario's q, u,
subsets in column layout) and Algorithm 7 over them, as the trade machine asks it
(:data:`~agent.protocol.machine.DecideFn`); part of :class:`~agent.runtime.core.shared.Shared`."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from agent.config.scenario import Scenario
from agent.core.trading import trade_stacked
from agent.core.vision import Landmarks, as_distance_term
from agent.protocol.records import Vec3
from agent.structure.model import StructureModel
from agent.world.inputs import trade_sight_lines

IntArray = NDArray[np.int64]


class Geometry:
    """Landmark geometry indexed by landmark id: rows, subsets, Algorithm 7."""

    def __init__(self, scenario: Scenario, model: StructureModel | None) -> None:
        self.ids = np.asarray(scenario.landmark_ids, dtype=np.int64)
        self.order = np.argsort(self.ids, kind="stable")
        self.sorted_ids = self.ids[self.order]
        self.cols = Landmarks.of(scenario.q, scenario.u)  #: every landmark, column layout
        self.term = as_distance_term(scenario.d_opt)
        #: the placed mesh whose lines of sight count (visibility "occlusion"), else None
        self.occluder = model if scenario.visibility == "occlusion" else None

    def rows(self, lids: IntArray) -> NDArray[np.intp]:
        """Row indices (into the scenario's q, u) of landmark ids ``lids`` (all known)."""
        return self.order[np.searchsorted(self.sorted_ids, lids)]

    def subset(self, rows: NDArray[np.intp]) -> Landmarks:
        """The landmarks at ``rows``, column layout."""
        return Landmarks(np.take(self.cols.qT, rows, axis=1), np.take(self.cols.uT, rows, axis=1))

    def decide(
        self, p_i: Vec3, v_i: Vec3, ids_i: IntArray, p_r: Vec3, v_r: Vec3, ids_r: IntArray
    ) -> tuple[NDArray[np.bool_], NDArray[np.bool_]]:
        """Algorithm 7 with A = initiator I, B = responder R (poses [m; world ENU], unit
        camera directions); with occlusion, over fresh casts from both cameras as the
        simulator does (a :data:`~agent.protocol.machine.DecideFn`)."""
        pi, vi = np.asarray(p_i, dtype=np.float64), np.asarray(v_i, dtype=np.float64)
        pr, vr = np.asarray(p_r, dtype=np.float64), np.asarray(v_r, dtype=np.float64)
        rows = self.rows(np.concatenate((ids_i, ids_r)))
        clear_i = clear_r = None
        if self.occluder is not None:
            clear_i, clear_r = trade_sight_lines(self.occluder, pi, pr, self.cols.qT.T[rows],
                                                 self.cols.uT.T[rows])
        out = trade_stacked(pi, vi, pr, vr, self.subset(rows), ids_i.size, self.term,
                            clear_i, clear_r)
        return out.a_to_b, out.b_to_a
