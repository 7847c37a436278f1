"""The "potential" strategy's bounds and search sizes: one set of constants for the simulator
(:mod:`agent.sim.strategy`) and the agents (:mod:`agent.runtime.moves`,
:mod:`agent.runtime.planning`), so both make the same decisions.

The decisions themselves are pure functions of one agent's state and its peers' messages in
:mod:`agent.core.coverage_moves` (relocation, pair / group re-splits); what a transit does
each Δt is :func:`agent.world.environment.transit_displacement`, and when one is given up
:data:`agent.world.environment.STALL_TICKS`.
"""

from __future__ import annotations

from typing import Final

#: Flights to a better viewpoint per agent in the move stage.
MAX_RELOCATIONS: Final = 4
#: Whole-team re-split rounds after the pair and triple moves (teams of four or more).
TEAM_MOVES: Final = 2
#: Greedy starts of a whole-team re-split's search (pairs and triples use one).
TEAM_STARTS: Final = 8
#: Whether 3-member re-splits are tried when no pair re-split with a partner helps.
TRIPLES: Final = True
#: Termination bounds on re-splits, which differ in kind: the simulator sees the whole team
#: and counts the team's re-splits (at most ``TEAM_RESPLITS_PER_N2`` × n²); an agent sees only
#: its own and initiates at most ``REGROUPS_PER_MEMBER`` × n. They exist so that every run
#: terminates.
TEAM_RESPLITS_PER_N2: Final = 3
REGROUPS_PER_MEMBER: Final = 1
