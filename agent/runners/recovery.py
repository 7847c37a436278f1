"""A drone whose journal is new must not start from the scenario's sets if its team already
heard it in the run under way: its ledger went with the old journal (moved away, a new SD
card, a fresh ``--state-dir``), and the scenario's sets would double what it gave away and
lose what it received.

:func:`refuse_forgotten_id` asks the router's fence record (:mod:`agent.net.keeper`), which
lists the incarnations heard of every agent of the mission; before anything is journaled, a
drone with no genesis record whose id the record lists, while the run it was in is under way,
stops with one line (exit 2). The run is under way when another agent of the mission is live
and its life overlapped the drone's old one (its liveliness token came up before the drone was
last heard, both on the router's clock) or it resumed a journal (incarnation above 1). A new
run of the mission on a long-running router is not refused: with nobody live, or with only
agents that started fresh after the drone left (the whole team started again together, in any
order). It then
stays out of the mission, so the team fences it after ``lost_after`` and adopts its landmarks
(from the survivors' ledgers: nothing lost or doubled); it rejoins under a new id with
``--join-at``. A record that does not come within the bound (a router that keeps none) is said
in one line and the drone starts as before.
"""

from __future__ import annotations

import logging
import time

from agent.errors import UsageError
from agent.mission.operator import live_agents
from agent.net.contract import Transport
from agent.protocol.records import GenesisRec
from agent.storage.journal import Journal
from agent.wire import keys
from agent.wire.record import RECORD_CODEC, FenceRecord

_log = logging.getLogger("viscover.agent")

#: A live agent whose token the router saw come up less than this long [s] after the drone
#: fell silent still counts as overlapping it: when a session closes the router announces
#: the remaining tokens again (measured: within 40 ms of the moment the drone's token went),
#: so a token's age alone can make a team under way look newly started; a new run's agents
#: start later than that (a process start).
OVERLAP_SLACK_S = 0.25
#: Seconds a drone with a new journal waits for the router's fence record.
RECORD_WAIT_S = 5.0


def fence_record(tp: Transport, mission: str, wait_s: float,
                 timeout_s: float = 0.5) -> FenceRecord | None:
    """The router's fence record of ``mission``, asked until one comes or ``wait_s`` [s] have
    passed (a router that just started may not answer at once); None if none came."""
    deadline = time.monotonic() + wait_s
    key = keys.fences_key(mission)
    while True:
        raw = tp.request(key, b"", timeout_s, kind="fences")
        rec = None if raw is None else RECORD_CODEC.decode(raw, key)
        if rec is not None and rec.mission == mission:
            return rec
        if time.monotonic() >= deadline:
            return None
        time.sleep(0.05)  # a session just opened may not know the router's queryable yet


def under_way(rec: FenceRecord, agent_id: str, live: set[str]) -> set[str]:
    """The agents of ``live`` whose run is the one ``agent_id`` was last heard in (module
    docstring); all of ``live`` from a keeper that keeps no lives (older builds)."""
    if not rec.alive_for and not rec.silent_for:
        return set(live)
    quiet = rec.silent_for.get(agent_id)  # None: the router still counts it live
    return {x for x in live if quiet is None or x in rec.resumed
            or rec.alive_for.get(x, 0.0) >= quiet - OVERLAP_SLACK_S}


def refuse_forgotten_id(tp: Transport, mission: str, agent_id: str, journal: Journal,
                        wait_s: float = RECORD_WAIT_S) -> None:
    """A :class:`UsageError` if ``journal`` is new (no genesis) but the team already heard
    ``agent_id`` (module docstring)."""
    if any(isinstance(r, GenesisRec) for r in journal.replay()):
        return
    rec = fence_record(tp, mission, wait_s)
    if rec is None:
        _log.warning("agent %s: no fence record from the router on %s within %g s: cannot "
                     "check that the team never heard %s before; starting from the "
                     "scenario's landmarks", agent_id, keys.fences_key(mission), wait_s,
                     agent_id)
        return
    if (inc := rec.seen.get(agent_id)) is None:
        return
    # Live: the router's own view of the tokens (in the record) and a liveliness query (a
    # slow answer on a loaded machine must not make a team under way look absent).
    live = (live_agents(tp, mission) | set(rec.alive_for)) - {agent_id}
    others = under_way(rec, agent_id, live)
    if others:
        raise UsageError(
            f"agent {agent_id}: its journal in {journal.dir} is new, but the team (live: "
            f"{', '.join(sorted(others))}) already heard {agent_id} (incarnation {inc}, the "
            "router's fence record): its landmarks "
            "went with its old journal, and starting from the scenario's sets would double "
            "what it gave away; it stays out, the team fences it after lost_after and adopts "
            "its landmarks: put the drone back to work under a new id with --join-at, or "
            "restore its journal")
