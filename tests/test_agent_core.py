"""The agent core on its own (:class:`~agent.runtime.core.agent_core.AgentCore`, issue 19): stepped
by
hand, no transport, no thread, no journal. A tick that needs a reply returns an ask and
waits; the core answers queries meanwhile; the records an offer depends on come out before
the offer; a failed journal stops every answer and the next tick raises it."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from agent.core.planner import PlanStep
from agent.runtime.core.agent_core import AgentCore
from agent.runtime.core.events import (
    Answer,
    Ask,
    Command,
    Compute,
    Liveliness,
    Persist,
    Publish,
    Query,
    Reply,
    Start,
    Tick,
)
from agent.runtime.core.shared import AgentConfig
from agent.runtime.shell.pose import carry_out, fix_of
from agent.storage.journal import JournalFailed
from agent.testing.core_net import LOSSLESS, CoreNet
from agent.wire import keys
from agent.wire.codec import Codec
from agent.wire.peer import (
    Accept,
    AdoptOrder,
    Busy,
    Commit,
    FenceProposal,
    FenceVote,
    Offer,
    Request,
    pack,
)
from agent.wire.peer import Reply as ReplyMsg
from tests.agent_helpers import fixed_motion, random_scene

REQUESTS: Codec[Request] = Codec(Request)
REPLIES: Codec[ReplyMsg] = Codec(ReplyMsg)


def converged_team() -> CoreNet:
    """Three cores of a random scene, converged at once (they offer at their first tick)."""
    return CoreNet(random_scene(3, 9, 1), AgentConfig(mission="m", seed=1),
                   motion=fixed_motion(1, max_ticks=0))


def first_ask(net: CoreNet, aid: str) -> tuple[AgentCore, list[object]]:
    """Tick ``aid`` until its tick waits for an answer; the effects of that step."""
    core = net.cores[aid]
    for _ in range(20):
        effects = core.step(Tick(net.clock.now(), fix_of(net.vehicles[aid])))
        if core.waiting:
            return core, list(effects)
        net.carry(aid, effects, LOSSLESS)
        net.clock.advance(0.1)
    raise AssertionError(f"{aid} never asked")


def test_a_tick_that_needs_a_reply_waits_and_the_core_answers_queries_meanwhile() -> None:
    net = converged_team()
    a, effects = first_ask(net, "N0")
    ask = effects[-1]
    assert isinstance(ask, Ask) and keys.kind_of(ask.key) == "trade"
    assert isinstance(REQUESTS.decode(ask.payload), Offer)
    partner = keys.try_agent_of(ask.key)
    assert partner is not None and partner != "N0"
    # The offer's own record (its trade id, journaled) is persisted before it leaves.
    assert any(isinstance(e, Persist) for e in effects[:-1])
    assert not any(isinstance(e, Persist) for e in effects[effects.index(ask):])
    with pytest.raises(RuntimeError, match="waits for an answer"):
        a.step(Tick(net.clock.now(), fix_of(net.vehicles["N0"])))
    # Meanwhile the partner's own offer to us is answered: Busy, we are trading.
    b, theirs = first_ask(net, partner)
    offer = theirs[-1]
    assert isinstance(offer, Ask) and keys.try_agent_of(offer.key) == "N0"
    got = a.step(Query(offer.payload, offer.key, 0.0))
    assert isinstance(got[-1], Reply) and got[-1].payload is not None
    busy = REPLIES.decode(got[-1].payload)
    assert isinstance(busy, Busy) and busy.reason == "trading"
    assert a.waiting  # still waiting for our own answer
    # The partner, waiting too, answers our offer (the larger id yields its own: Accept);
    # our tick runs on: the commit journaled, then its Commit asked.
    reply = net.step(partner, Query(ask.payload, ask.key, 0.0), LOSSLESS)
    assert reply is not None and isinstance(REPLIES.decode(reply), Accept)
    rest = a.step(Answer(reply, 0.0))
    assert a.shared.counters.outcomes == {"commit": 1} and a.waiting
    assert [type(e) for e in rest] == [Persist, Ask]
    commit = rest[-1]
    assert isinstance(commit, Ask) and isinstance(REQUESTS.decode(commit.payload), Commit)
    b.step(Answer(None, 0.0))  # its offer was given up (it yielded): a late answer is void
    assert b.shared.counters.outcomes.get("yield") == 1


def test_the_tick_publishes_after_the_records_it_made() -> None:
    net = converged_team()
    a = net.cores["N0"]
    effects = a.step(Start(0.0, fix_of(net.vehicles["N0"])))
    kinds = [type(e) for e in effects]
    assert Publish in kinds
    last_persist = max((i for i, k in enumerate(kinds) if k is Persist), default=-1)
    assert last_persist < kinds.index(Publish)


def test_a_failed_journal_answers_nothing_more_and_the_next_tick_raises() -> None:
    net = converged_team()
    a = net.cores["N0"]
    a.fail(JournalFailed("journal j: cannot write (No space left on device)"))
    commit = Commit(sender="N1", trade_id="N1:1:1")
    out = a.step(Query(REQUESTS.encode(commit), keys.trade_key("m", "N0"), 0.0))
    assert out == [Reply(None)]
    with pytest.raises(JournalFailed, match="No space left"):
        a.step(Tick(net.clock.now(), fix_of(net.vehicles["N0"])))


def test_the_planner_step_is_computed_outside_the_core_which_answers_meanwhile() -> None:
    """With the real planner the tick hands its planner step out as a Compute and waits; an
    offer arriving meanwhile is answered Busy("optimising"); the step's result moves the pose
    once it comes back."""
    net = CoreNet(random_scene(3, 9, 1), AgentConfig(mission="m", seed=1))
    a = net.cores["N0"]
    p0 = a.pose.current()[0].copy()
    effects = a.step(Tick(0.0, fix_of(net.vehicles["N0"])))
    wait = effects[-1]
    assert isinstance(wait, Compute) and a.waiting
    b = net.cores["N1"].state_message()  # as the initiator publishes it
    offer = Offer(sender="N1", trade_id="N1:1:1", p=b.p, v=b.v, owned=b.owned)
    got = a.step(Query(REQUESTS.encode(offer), keys.trade_key("m", "N0"), 0.0))
    assert isinstance(got[-1], Reply) and got[-1].payload is not None
    busy = REPLIES.decode(got[-1].payload)
    assert isinstance(busy, Busy) and busy.reason == "optimising"
    assert (a.pose.current()[0] == p0).all()  # not moved before the step's result is back
    move = a.step(Answer(wait.fn(), 0.0))[-1]  # the step's command leaves as an effect
    assert isinstance(move, Command) and a.waiting and np.any(move.p_dot)
    assert (a.pose.current()[0] == p0).all()  # the vehicle has not flown it yet
    a.step(Answer(carry_out(net.vehicles["N0"], move), 0.0))
    assert not a.waiting
    assert not (a.pose.current()[0] == p0).all()


def test_a_planner_step_computed_before_an_adoption_does_not_converge_the_new_set() -> None:
    """The planner step handed out as a Compute was computed for the set owned then; an
    adoption order answered while it computes changes the set, so the step's result (here a
    converged step) is stale: the agent keeps optimising its new set."""
    net = CoreNet(random_scene(3, 9, 1), AgentConfig(mission="m", seed=1))
    a = net.cores["N0"]
    gone = net.cores["N2"].shared.machine.owned  # N2's landmarks, adopted by N0 below
    del net.cores["N2"]
    a.step(Liveliness(keys.alive_key("m", "N2"), False, 0.0))
    effects = a.step(Tick(0.0, fix_of(net.vehicles["N0"])))
    wait = effects[-1]
    assert isinstance(wait, Compute) and a.phase == "optimising"
    selector = keys.trade_key("m", "N0")
    vote = a.step(Query(REQUESTS.encode(FenceProposal(sender="N1", epoch=1, fenced=["N2"])),
                        selector, 0.0))
    assert isinstance(vote[-1], Reply) and vote[-1].payload is not None
    assert isinstance(REPLIES.decode(vote[-1].payload), FenceVote)
    order = AdoptOrder(sender="N1", epoch=1, fenced=["N2"],
                       owned=pack({lid: ver + 1 for lid, ver in gone.items()}), drop=pack({}))
    a.step(Query(REQUESTS.encode(order), selector, 0.0))
    assert set(gone) <= set(a.shared.machine.owned)  # adopted while the step computed
    step = wait.fn()
    assert isinstance(step, PlanStep)
    still = dataclasses.replace(step, p_dot=np.zeros(3), omega=np.zeros(3))
    assert still.converged
    out = a.step(Answer(still, 0.0))
    while a.waiting:  # a search for a better viewpoint of the stale set: none found
        assert isinstance(out[-1], Compute)
        out = a.step(Answer(None, 0.0))
    assert a.phase == "optimising"
