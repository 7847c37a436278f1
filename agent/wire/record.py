"""The team's final word: the record of fences a router keeps for drones that come back late.

A drone that returns after its team finished (everyone else exited) would otherwise hear of
nobody's fence: the fences live in the peers' states, and the peers are gone. The router
process (``viscover router``, :mod:`agent.net.keeper`) outlives the agents; it listens to every
state of every mission and answers queries on ``viscover/<m>/fences`` with a
:class:`FenceRecord`: the fence proofs the team's states carried (checked by the drone that
asks, as any proof: :mod:`agent.protocol.fence_proof`; the router is trusted with nothing),
the highest incarnation heard from each agent (a drone whose journal is new but whose id the
team already heard lost its ledger: it must not start from the scenario's sets), the
agents heard reporting the mission complete, and on the router's own clock how long each live
agent's liveliness token has been up and how long each other agent has been silent (a fresh
journal is refused only while a live agent's life overlapped the asker's old one: a new run of
the mission on a long-running router starts everyone fresh, together).

Bounded like every wire message: at most :data:`MAX_RECORD_PROOFS` proofs, :data:`MAX_IDS`
agents.
"""

from __future__ import annotations

from typing import Annotated, Final

import msgspec

from agent.wire.codec import Codec
from agent.wire.peer import MAX_IDS, AgentId, FenceProof, Incarnation

#: Proofs one record carries (a mission has few fence rounds; the newest are kept).
MAX_RECORD_PROOFS: Final = 64
#: Schema of :class:`FenceRecord` spoken by this build.
RECORD_SCHEMA: Final = 1
#: A duration on the router's clock [s] (finite, not negative).
Seconds = Annotated[float, msgspec.Meta(ge=0.0, le=1e9)]


class FenceRecord(msgspec.Struct, kw_only=True):
    """What the router heard of one mission (see the module docstring)."""

    mission: AgentId
    proofs: Annotated[list[FenceProof], msgspec.Meta(max_length=MAX_RECORD_PROOFS)] = \
        msgspec.field(default_factory=list)
    #: agent -> the highest incarnation its states carried
    seen: Annotated[dict[AgentId, Incarnation], msgspec.Meta(max_length=MAX_IDS)] = \
        msgspec.field(default_factory=dict)
    #: agents heard reporting the mission complete (ids ascending)
    complete: Annotated[list[AgentId], msgspec.Meta(max_length=MAX_IDS)] = \
        msgspec.field(default_factory=list)
    #: live agent -> seconds its liveliness token has been up [s, router clock]; empty from
    #: keepers before it
    alive_for: Annotated[dict[AgentId, Seconds], msgspec.Meta(max_length=MAX_IDS)] = \
        msgspec.field(default_factory=dict)
    #: agent heard but not live -> seconds since it was last heard [s, router clock]
    silent_for: Annotated[dict[AgentId, Seconds], msgspec.Meta(max_length=MAX_IDS)] = \
        msgspec.field(default_factory=dict)
    #: live agents whose states since their token came up carry an incarnation above 1 (they
    #: resumed a journal: the run they belong to may be an old one), ids ascending
    resumed: Annotated[list[AgentId], msgspec.Meta(max_length=MAX_IDS)] = \
        msgspec.field(default_factory=list)
    schema: int = RECORD_SCHEMA


RECORD_CODEC: Codec[FenceRecord] = Codec(FenceRecord)
