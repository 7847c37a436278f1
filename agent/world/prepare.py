"""A mission's world prepared for its agent cores (:class:`~agent.world.inputs.World`): the
mesh read and placed (:func:`~agent.world.structure.structure_model`, cached per placement), an
inspection's capture table and route grid built (:func:`~agent.world.tables.mission_tables`),
the viewpoint environment bound to the placed mesh. The runtime prepares it once and hands it
to the core, which reads no file. An inspection's tables come from a prepared file when one
is named (:mod:`agent.world.prepared`: built once for the whole team by ``viscover prepare``
or ``viscover launch``), else are built here.
"""

from __future__ import annotations

import functools
import os
from pathlib import Path
from typing import TYPE_CHECKING

from agent.world.environment import environment_for
from agent.world.inputs import World
from agent.world.prepared import PREPARED_ENV, load_prepared
from agent.world.structure import structure_model
from agent.world.tables import mission_tables

if TYPE_CHECKING:
    from agent.config.scenario import Scenario

__all__ = ["prepare_world"]


def prepare_world(sc: Scenario, prepared: str | Path | None = None) -> World:
    """The world of ``sc`` (structure resolved) for its agents. An inspection's tables are
    loaded from the prepared file ``prepared`` (default: the file named by the environment
    variable :data:`~agent.world.prepared.PREPARED_ENV`, if set) when given, checked against
    ``sc`` (:func:`~agent.world.prepared.load_prepared`: a mismatch is a one-line
    :class:`~agent.world.prepared.PreparedError`), else built here."""
    model = None if sc.structure is None else structure_model(sc.structure)
    path = prepared if prepared is not None else os.environ.get(PREPARED_ENV) or None
    tables = None if sc.inspection is None else \
        mission_tables(sc) if path is None else load_prepared(path, sc)
    return World(model, tables, functools.cache(functools.partial(environment_for, sc, model)))
