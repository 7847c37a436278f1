"""Strategies: what each drone decides from its own state, its peers' messages and the
mission's environment, as pure functions (no I/O, no clocks, no threads), and the registry
that says which moves each strategy makes, in which order.

The agent core (:mod:`agent.runtime.core.agent_core`) carries a strategy's moves out, in the agent
processes (kinematic and flying) and in ``viscover simulate`` alike. Modules:

- :mod:`agent.strategy.registry`: every strategy a scenario may name, one registration line
  each: its moves (team re-split, revert, pair / triple re-split; an inspection's initial
  re-splits and taking work), in the order a drone tries them.
- :mod:`agent.strategy.inspection`: inspection missions (``[inspection]`` in a scenario):
  capture tours, re-splits judged by the longest tour, taking work, going home.
- :mod:`agent.strategy.potential`: the bounds and search sizes of ``strategy = "potential"``
  and the order of its re-splits after a NoTrade.

The thesis' decisions (Algorithm 7, :mod:`agent.core.trading`) and the "potential" coverage
moves (:mod:`agent.core.coverage_moves`) are pure functions in :mod:`agent.core`.
"""
