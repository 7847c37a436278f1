"""A scenario made concrete for the drones, used alike by the simulator and the agent
processes (neither imports the other for it): the structure resolved and its per-agent
planner inputs (:mod:`~agent.world.structure`), where viewpoints may be and how a transit
moves (:mod:`~agent.world.environment`), an inspection's capture table and route grid
(:mod:`~agent.world.tables`), built once for a team into a file its agents load
(:mod:`~agent.world.prepared`)."""
