"""A multi-view inspection's landmarks made concrete: each landmark replaced by its view
landmarks, one per view sector (:mod:`agent.core.views`).

With ``inspection.views`` = k > 1 every landmark is to be captured in k images whose viewing
directions differ pairwise by ``parallax_deg``. :func:`expand_views` (called last by
:func:`agent.world.structure.resolve_structure`, after the mesh landmarks are sampled) turns
landmark row j with id i into k rows j·k + s (s = 0 … k − 1) with

* the ids i·k + s (so the landmark of view id v is v // k and its sector v % k; distinct ids
  stay distinct), at most 2^53 − 1 like every landmark id;
* the same position q and normal u, owned by the agent that owned landmark j;
* the unit axis of sector s (``Scenario.view_axis``), the landmark id i
  (``Scenario.view_of``) and, for all, the cone's cosine (``Scenario.view_cos``).

Every capture test then takes ``view_axis`` of its rows: a view landmark is captured only by
an image from inside its sector, so its k views captured are k images pairwise at least the
parallax apart, and the capture table, tours, trades and captured sets need no change.
Expanding once: a scenario with ``view_of`` set is returned as it is. Problems are one-line
:class:`~agent.config.validation.ScenarioError` naming the file and ``inspection.views``.
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING

import numpy as np

from agent.config.limits import MAX_LANDMARK_ID, MAX_LANDMARKS
from agent.config.validation import ScenarioError
from agent.core.views import sector_axes, sector_cone

if TYPE_CHECKING:
    from agent.config.scenario import Scenario


def expand_views(sc: Scenario) -> Scenario:
    """``sc`` with each landmark replaced by its ``inspection.views`` view landmarks
    (unchanged with one view, or when already expanded)."""
    spec = sc.inspection
    if spec is None or spec.views == 1 or sc.view_of is not None:
        return sc
    k = spec.views

    def fail(what: str) -> ScenarioError:
        return ScenarioError(f"{sc.source}: inspection.views: {what}")

    cone = sector_cone(k, spec.parallax, spec.max_incidence)
    if cone is None:  # parse_inspection refuses these; a spec built in code may not
        raise fail(f"{k} views {np.degrees(spec.parallax):g} deg apart do not fit within the "
                   "incidence limit; use a smaller parallax_deg or fewer views")
    m = sc.q.shape[0]
    if m * k > MAX_LANDMARKS:
        raise fail(f"{m:,} landmarks x {k} views are {m * k:,} view landmarks, more than the "
                   f"limit of {MAX_LANDMARKS:,}; use fewer views or fewer landmarks")
    top = max((int(i) for i in sc.landmark_ids), default=0)
    if top * k + k - 1 > MAX_LANDMARK_ID:
        raise fail(f"view landmark ids (landmark id x {k} + view) reach {top * k + k - 1}, "
                   f"over 2^53 - 1 = {MAX_LANDMARK_ID}; use landmark ids up to "
                   f"{(MAX_LANDMARK_ID - k + 1) // k} or fewer views")
    ids = np.asarray(sc.landmark_ids, dtype=np.int64)
    s = np.arange(k, dtype=np.int64)
    agents = [dataclasses.replace(a, landmarks=(np.asarray(a.landmarks, dtype=np.intp)[:, None]
                                                * k + s[None, :]).reshape(-1).astype(np.intp))
              for a in sc.agents]
    return dataclasses.replace(
        sc, q=np.repeat(sc.q, k, axis=0), u=np.repeat(sc.u, k, axis=0),
        landmark_ids=(ids[:, None] * k + s[None, :]).reshape(-1).tolist(), agents=agents,
        view_axis=sector_axes(sc.u, k, cone.tilt).reshape(-1, 3),
        view_of=np.repeat(ids, k), view_cos=cone.cos,
    )
