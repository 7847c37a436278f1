"""Stateful property test of the trade protocol (issue 19): three or four
:class:`~agent.protocol.machine.TradeMachine` s trading a dozen landmarks through the model
network of :mod:`agent.testing.protocol_net`.

Rules: agents converge and offer (Algorithm 7 at their viewpoints, or arbitrary valid terms: a
subset, a pair re-split, a revert pull; ``eager`` offers even with a trade in doubt); messages
are delivered in order or out of order (an Offer possibly meeting a responder that follows only
the machine's rules, or whose pose check answers first), lost, duplicated or replayed (any
message ever sent, or an old request handled at once); retry timers fire as the runtime's do
(an offer re-sent or given up, Commits until acknowledged, StatusQueries until decided);
agents crash and restart from their journals (killed at once, on a power loss that drops the
records not fsynced, or while handling a message, with none, some or all of that step's
records journaled and its answer never sent).

After every step the ownership invariants hold (:meth:`ProtocolNet.violations
<agent.testing.protocol_net.ProtocolNet.violations>`: no landmark owned twice or lost, the
owner at its highest version, versions monotone and each created once, every held landmark
held for a pending trade, both sides of every trade agreeing, every machine what its journal
rebuilds). At the end the network heals and the retries run their course: every trade
resolves and every landmark has exactly one owner, and the same one after every agent loses
power and recovers.

Deterministic for a given hypothesis seed (``--hypothesis-seed``): nothing else is random.
"""

from __future__ import annotations

import sys

from hypothesis import HealthCheck, event, settings
from hypothesis import strategies as st
from hypothesis.stateful import (
    RuleBasedStateMachine,
    initialize,
    invariant,
    rule,
)

from agent.testing.protocol_net import LANDMARK_IDS, VIEWPOINTS, ProtocolNet, Terms, Variant

AGENTS = ("A", "B", "C", "D")
#: an index into a list that changes size (taken modulo its length; shrinks to the first)
INDEX = st.integers(min_value=0, max_value=63)
AGENT = st.integers(min_value=0, max_value=len(AGENTS) - 1)
POSE = st.integers(min_value=0, max_value=len(VIEWPOINTS) - 1)
LANDMARKS = st.lists(st.sampled_from(LANDMARK_IDS), max_size=len(LANDMARK_IDS), unique=True)
TERMS = st.one_of(
    st.just(Terms("alg7")),
    st.builds(lambda ids: Terms("subset", tuple(sorted(ids))), LANDMARKS),
    st.builds(lambda ids: Terms("regroup", tuple(sorted(ids))), LANDMARKS),
    st.builds(lambda ids: Terms("pull", tuple(sorted(ids))), LANDMARKS),
)
VARIANT: st.SearchStrategy[Variant] = st.sampled_from(
    ["runtime", "runtime", "eager", "pose_unknown", "pose_refused"])
#: records a crashing agent journals of the step it was handling (0: none)
KEEP = st.integers(min_value=0, max_value=2)


class TradeProtocol(RuleBasedStateMachine):
    """Agents, network and faults as rules; ownership invariants as invariants."""

    net: ProtocolNet

    @initialize(n=st.integers(min_value=3, max_value=4),
                owners=st.lists(AGENT, min_size=len(LANDMARK_IDS), max_size=len(LANDMARK_IDS)),
                poses=st.lists(POSE, min_size=len(AGENTS), max_size=len(AGENTS)))
    def start(self, n: int, owners: list[int], poses: list[int]) -> None:
        """The mission: ``n`` agents, the owner of each landmark, each agent's viewpoint
        (shifted by its index: distinct ones by default)."""
        agents = AGENTS[:n]
        self.net = ProtocolNet(agents, {lid: agents[o % n] for lid, o in
                                        zip(LANDMARK_IDS, owners, strict=True)},
                               {a: (p + j) % len(VIEWPOINTS) for j, (a, p) in
                                enumerate(zip(agents, poses, strict=False))})

    def _agent(self, i: int) -> str:
        return self.net.agents[i % len(self.net.agents)]

    def _other(self, i: int, d: int) -> str:
        n = len(self.net.agents)
        return self.net.agents[(i + 1 + d % (n - 1)) % n]

    # -- agents ---------------------------------------------------------------------------
    @rule(i=AGENT, d=AGENT, pose=POSE)
    def converge(self, i: int, d: int, pose: int) -> None:
        """An agent (one still optimising first) converges at a viewpoint and, if it may
        (no trade pending), offers to another under Algorithm 7 (``maybe_offer``)."""
        opt = [a for a, n in self.net.nodes.items() if n.optimising] or list(self.net.agents)
        a = opt[i % len(opt)]
        self.net.converge(a, pose)
        if self.net.nodes[a].busy() is None:
            self.net.start_offer(a, self._other(self.net.agents.index(a), d), Terms("alg7"))

    @rule(i=AGENT, d=AGENT, terms=TERMS, pose=POSE, eager=st.booleans())
    def offer(self, i: int, d: int, terms: Terms, pose: int, eager: bool) -> None:
        """An agent offers to another, the responder to decide by ``terms`` (Algorithm 7 at
        both poses, or arbitrary valid terms: a subset, a re-split, a pull); one optimising
        converges at a viewpoint first. The runtime offers only without a trade pending,
        ``eager`` even with one in doubt (one offer at a time still)."""
        node = self.net.nodes[self._agent(i)]
        if node.optimising:
            self.net.converge(node.me, pose)
        if eager or node.busy() is None:
            self.net.start_offer(node.me, self._other(i, d), terms)

    @rule(i=AGENT, give_up=st.booleans())
    def timers(self, i: int, give_up: bool) -> None:
        """The retry timers of an agent with requests due fire: its offer, Commits not
        acknowledged and StatusQueries of trades in doubt go out again; or (``give_up``) an
        offer sent more than once without a reply is aborted, as after its last try (a reply
        may still be in flight)."""
        due = sorted({a for a, *_ in self.net.requests_due()})
        if not due:
            return
        a = due[i % len(due)]
        att = self.net.nodes[a].attempt
        if give_up and att is not None and att.tries > 1:
            self.net.give_up(a)
        else:
            self.net.timers(a)

    @rule(i=AGENT, k=INDEX, how=st.sampled_from(["kill", "power_loss", "handling"]),
          keep=KEEP)
    def crash(self, i: int, k: int, how: str, keep: int) -> None:
        """An agent is killed and restarts from its journal: at once (``kill``), losing its
        unsynced records too (``power_loss``), or while handling message ``k`` of those in
        flight (``handling``), after journaling only ``keep`` records of that step (its
        answer is never sent)."""
        if how == "handling" and self.net.pending:
            self.net.deliver(k, keep=keep)
        else:
            self.net.crash(self._agent(i), how == "power_loss")

    # -- network --------------------------------------------------------------------------
    @rule(count=st.integers(min_value=1, max_value=6))
    def deliver_in_order(self, count: int) -> None:
        """The oldest messages in flight arrive."""
        for _ in range(count):
            self.net.deliver(0)
            self._check()

    @rule(k=INDEX, variant=VARIANT)
    def deliver_any(self, k: int, variant: Variant) -> None:
        """Any message in flight arrives (the ``k``-th newest: reordering); an Offer may meet
        a responder that follows only the machine's rules, or whose pose check answers
        first."""
        self.net.deliver(-1 - k, variant)

    @rule(k=INDEX, fault=st.sampled_from(["lose", "duplicate", "replay"]))
    def network_fault(self, k: int, fault: str) -> None:
        """A message in flight is lost or duplicated, or one sent earlier arrives again."""
        if fault == "lose":
            self.net.lose(k)
        elif fault == "duplicate":
            self.net.duplicate(k)
        else:
            self.net.replay(k)

    @rule(k=INDEX, variant=VARIANT)
    def replay_request(self, k: int, variant: Variant) -> None:
        """A request sent earlier (the ``k``-th newest) arrives again, now: an Offer, Commit or
        StatusQuery its receiver may have finished with, or forgotten in a restart."""
        self.net.replay_request(k, variant)

    # -- invariants -----------------------------------------------------------------------
    def _check(self) -> None:
        found = self.net.violations()
        assert not found, "\n".join([*found, "-- last steps:", *self.net.log[-25:]])

    @invariant()
    def ownership(self) -> None:
        """No landmark owned twice or lost, versions monotone, holds pending, both sides of
        every trade agree, every machine what its journal rebuilds."""
        self._check()

    def teardown(self) -> None:
        """The network heals and the retries run: every trade resolves and every landmark has
        exactly one owner. That outcome is durable: after a power loss of every agent (and
        the retries that follow) each owns the same landmarks. Skipped when a step already
        failed."""
        if sys.exc_info()[0] is not None or not hasattr(self, "net"):
            return
        self._events("during")
        self._settle()
        owners = {a: n.machine.owned for a, n in self.net.nodes.items()}
        self._events("after drain")
        for a in self.net.agents:
            self.net.crash(a, power_loss=True)
        self._check()
        self._settle()
        after = {a: n.machine.owned for a, n in self.net.nodes.items()}
        assert after == owners, f"a power loss changed the final ledgers: {owners} -> {after}"

    def _settle(self) -> None:
        assert self.net.drain(), "pending trades did not resolve:\n" + "\n".join(
            self.net.log[-25:])
        found = self.net.final_violations()
        assert not found, "\n".join([*found, "-- last steps:", *self.net.log[-25:]])

    def _events(self, when: str) -> None:
        """What the run did (``--hypothesis-show-statistics``)."""
        ms = [n.machine for n in self.net.nodes.values()]
        ok = sum(m.ok for m in ms) // 2
        event(f"committed trades {when}", "0" if ok == 0 else "1-2" if ok <= 2 else "3+")
        event(f"responders restored {when}", str(min(2, sum(len(m.r_restored) for m in ms))))
        if when == "during":
            event("restarts", str(min(3, sum(n.starts - 1 for n in self.net.nodes.values()))))


TradeProtocol.TestCase.settings = settings(
    max_examples=300, stateful_step_count=50, deadline=None, report_multiple_bugs=False,
    suppress_health_check=[HealthCheck.too_slow],
)
test_trade_protocol = TradeProtocol.TestCase
