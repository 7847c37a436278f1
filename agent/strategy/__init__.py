"""Strategies: what each drone decides from its own state, its peers' messages and the
mission's environment, as pure functions (no I/O, no clocks, no threads).

The simulator drives these decisions in virtual time; the agent processes are to call the
same functions. Modules:

- :mod:`agent.strategy.inspection`: inspection missions (``[inspection]`` in a scenario):
  capture tours, re-splits judged by the longest tour, taking work, going home.

The thesis' decisions (Algorithm 7, :mod:`agent.core.trading`) and the "potential" coverage
moves (:mod:`agent.core.coverage_moves`) are still called from their drivers in
:mod:`agent.sim` and :mod:`agent.runtime`.
"""
