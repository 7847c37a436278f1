"""A mission's world prepared for its agent cores (:class:`~agent.world.inputs.World`): the
mesh read and placed (:func:`~agent.world.structure.structure_model`, cached per placement), an
inspection's capture table and route grid built (:func:`~agent.world.tables.mission_tables`),
the viewpoint environment bound to the placed mesh. The runtime prepares it once and hands it
to the core, which reads no file.
"""

from __future__ import annotations

import functools
from typing import TYPE_CHECKING

from agent.world.environment import environment_for
from agent.world.inputs import World
from agent.world.structure import structure_model
from agent.world.tables import mission_tables

if TYPE_CHECKING:
    from agent.config.scenario import Scenario

__all__ = ["prepare_world"]


def prepare_world(sc: Scenario) -> World:
    """The world of ``sc`` (structure resolved) for its agents."""
    model = None if sc.structure is None else structure_model(sc.structure)
    tables = None if sc.inspection is None else mission_tables(sc)
    return World(model, tables, functools.cache(functools.partial(environment_for, sc, model)))
