"""The agent core: one drone's decisions as a pure state machine
(:class:`~agent.runtime.core.agent_core.AgentCore`, ``step(event) -> effects``), its events
and effects (:mod:`~agent.runtime.core.events`), the state its parts share
(:mod:`~agent.runtime.core.shared`, :mod:`~agent.runtime.core.geometry`), the vehicle as it
sees it (:mod:`~agent.runtime.core.vehicle`), what it publishes
(:mod:`~agent.runtime.core.published`), the status snapshot
(:mod:`~agent.runtime.core.standing`) and leaving (:mod:`~agent.runtime.core.departing`).
No clock, lock, transport, journal or file."""
