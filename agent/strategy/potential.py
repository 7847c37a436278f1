"""The "potential" strategy's bounds and search sizes, and the order in which a drone tries its
re-splits: read by the agents (:mod:`agent.runtime.moves.coverage`,
:mod:`agent.runtime.moves.planning`),
which ``viscover simulate`` runs too (:mod:`agent.testing.agent_engine`).

The decisions themselves are pure functions of one agent's state and its peers' messages in
:mod:`agent.core.coverage_moves` (relocation, pair / group re-splits); which re-split a drone
offers after Algorithm 7 moved nothing is :func:`resplit_after_no_trade`; what a transit
does each Δt is :func:`agent.world.environment.transit_displacement`, and when one is given
up :data:`agent.world.environment.STALL_TICKS`.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from typing import Final

import numpy as np
from numpy.typing import NDArray

from agent.core.coverage_moves import GroupProposal, OwnState, PeerMessage, group_proposal
from agent.core.viewpoints import Environment

#: Flights to a better viewpoint per agent in the move stage.
MAX_RELOCATIONS: Final = 4
#: Whole-team re-split rounds after the pair and triple moves (teams of four or more).
TEAM_MOVES: Final = 2
#: Greedy starts of a whole-team re-split's search (pairs and triples use one).
TEAM_STARTS: Final = 8
#: Whether 3-member re-splits are tried when no pair re-split with a partner helps.
TRIPLES: Final = True
#: A termination bound: an agent initiates at most ``REGROUPS_PER_MEMBER`` × n re-splits (it
#: sees only its own), so that every run terminates.
REGROUPS_PER_MEMBER: Final = 1


def resplit_after_no_trade(
    own: OwnState, partner: PeerMessage, thirds: Iterable[PeerMessage],
    others: Callable[[tuple[str, ...]], NDArray[np.float64]], env: Environment, d_opt: float,
    triples: bool = TRIPLES,
) -> GroupProposal | None:
    """The re-split a drone offers when Algorithm 7 moved nothing with ``partner`` (stage 2):
    one of both sets between two new poses, else (``triples``) one with ``partner`` and each
    of ``thirds`` (the other converged peers, in team order, taken lazily) in turn; the first
    that beats the members' current visions (eq. 3.10 on the group), or None.
    ``others(ids)``: positions (j, 3) [m; world ENU] of every agent but this one and ``ids``.
    """
    prop = group_proposal(own, (partner,), others((partner.id,)), env, d_opt)
    if prop is not None or not triples:
        return prop
    for third in thirds:  # a loop over the team (at most n - 2 triples), not landmarks
        prop = group_proposal(own, (partner, third), others((partner.id, third.id)), env,
                              d_opt)
        if prop is not None:
            return prop
    return None
