"""Strategies: what each drone decides from its own state, its peers' messages and the
mission's environment, as pure functions (no I/O, no clocks, no threads).

The simulator drives these decisions in virtual time; the agent processes are to call the
same functions. Modules:

- :mod:`agent.strategy.inspection`: inspection missions (``[inspection]`` in a scenario):
  capture tours, re-splits judged by the longest tour, taking work, going home.
- :mod:`agent.strategy.potential`: the bounds and search sizes of ``strategy = "potential"``,
  one set for the simulator and the agents.
- :mod:`agent.strategy.registry`: every strategy a scenario may name, registered once with
  the behaviours it turns on; the simulator and the agents read those flags, not the name.

The thesis' decisions (Algorithm 7, :mod:`agent.core.trading`) and the "potential" coverage
moves (:mod:`agent.core.coverage_moves`) are pure functions in :mod:`agent.core`; the order
in which a drone tries them is still written twice, in its drivers :mod:`agent.sim.strategy`
(sequential ticks) and :mod:`agent.runtime.moves` (asynchronous stages).
"""
