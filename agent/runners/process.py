"""One agent as a process: open what it needs (Zenoh session, journal, fault injector), run
the tick loop of :class:`~agent.runtime.shell.runtime.AgentRuntime` in mission time, stop cleanly on
SIGINT/SIGTERM, and say how it ended.

:func:`run_agent` runs a kinematic agent (the pose integrates its own commands, eq. 5.1);
the flying agent (:mod:`agent.runners.flying`) reuses every helper here and
:func:`agent_loop`. Options arrive as an :class:`AgentOptions` built by the command line
(:mod:`agent.commands.agent`); a user mistake raises :class:`~agent.errors.UsageError`.
"""

from __future__ import annotations

import contextlib
import json
import logging
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from types import FrameType
from typing import Any

from agent.clock import Clock, WallClock
from agent.config.digest import scenario_digest
from agent.config.scenario import AgentSpec, Scenario
from agent.errors import EXIT_FAILURE, EXIT_INCOMPLETE, EXIT_INTERRUPTED, EXIT_OK, UsageError
from agent.mission.operator import live_agents
from agent.net.faults import FaultConfig, FaultInjector
from agent.net.session import open_session
from agent.net.transport import Transport, ZenohTransport
from agent.runners.departure import announce_departure
from agent.runners.orders import Orders
from agent.runners.quality import inspection_end_line
from agent.runners.recovery import refuse_forgotten_id
from agent.runtime.core.standing import Seen
from agent.runtime.shell.runtime import AgentConfig, AgentRuntime
from agent.storage.journal import Journal, JournalFailed, JournalHeader, default_state_dir
from agent.wire.signed import SigningKeys

_log = logging.getLogger("viscover.agent")

#: Real seconds an agent waits for the team's final word (the router's fence record) once the
#: mission looks complete (agent.runtime.fencing.final_word).
FINAL_WORD_S = 30.0


@dataclass(frozen=True)
class AgentOptions:
    """What one agent process needs (times in wall seconds unless stated)."""

    agent_id: str
    scenario: Scenario
    mission: str
    zenoh: Any  #: a ``zenoh.Config`` for a client session
    state_dir: Path | None = None  #: journal directory (default per mission and id)
    rate_scale: float = 1.0  #: mission seconds per wall second (kinematic agents)
    exit_on_complete: bool = False
    timeout_s: float | None = None  #: give up (exit 3) after this long
    connect_wait_s: float = 30.0  #: keep trying to reach the router this long at start
    request_timeout_s: float = 0.3  #: a trade query waits this long for its reply
    faults: FaultConfig | None = None  #: injected faults (None: none)
    fault_seed: int = 0
    fault_log: str | None = None  #: JSONL log of every injected fault
    signing: SigningKeys | None = None  #: sign and check trade messages (secured profile)
    join: AgentSpec | None = None  #: a drone not in the scenario joining (start pose)

    def runtime_config(self, time_scale: float) -> AgentConfig:
        """The runtime's constants for a clock running ``time_scale`` times real time."""
        return AgentConfig(mission=self.mission, seed=self.fault_seed,
                           request_timeout_s=self.request_timeout_s, signing=self.signing,
                           final_word_s=FINAL_WORD_S).scaled(time_scale)


def make_fault_injector(opts: AgentOptions) -> FaultInjector | None:
    """The seeded fault injector of the options (None without faults)."""
    if opts.faults is None:
        return None
    try:
        return FaultInjector(opts.faults, seed=opts.fault_seed, log=opts.fault_log,
                             keep_records=False)
    except OSError as e:
        raise UsageError(f"--fault-log {opts.fault_log}: {e.strerror or e}") from None


def journal_binding(sc: Scenario) -> JournalHeader:
    """The header binding a journal to scenario ``sc`` (:mod:`agent.config.digest`)."""
    return JournalHeader(digest=scenario_digest(sc), scenario=sc.name, source=sc.source)


def open_journal(opts: AgentOptions) -> Journal:
    """The agent's journal (``state_dir``, default per mission and id), locked, checked
    against the scenario and replayed (:class:`~agent.storage.journal.JournalCorrupt` /
    ``JournalMismatch`` if it cannot be this agent's: of another scenario, or damaged);
    nothing is written to a journal that is refused."""
    state_dir = opts.state_dir or default_state_dir(opts.mission, opts.agent_id)
    try:
        journal = Journal(state_dir, bind=journal_binding(opts.scenario))
    except OSError as e:
        raise UsageError(f"--state-dir {state_dir}: {e.strerror or e}") from None
    try:
        journal.replay()  # a damaged journal is reported before anything else is opened
    except BaseException:
        journal.close()
        raise
    return journal


def open_transport(cfg: Any, faults: FaultInjector | None, node_id: str, wait_s: float = 0.0,
                   stop: threading.Event | None = None) -> ZenohTransport:
    """A :class:`ZenohTransport`, retrying for up to ``wait_s`` seconds while no router
    answers (a drone may boot before its ground station), saying so on stderr, then one line
    (:func:`agent.net.session.open_session`)."""
    return open_session(cfg, faults, node_id, wait_s, stop)


@contextlib.contextmanager
def stop_on_signals(stop: threading.Event,
                    received: list[int] | None = None) -> Iterator[threading.Event]:
    """Within the block SIGINT/SIGTERM set ``stop`` and are appended to ``received`` (main
    thread only; elsewhere nothing is installed); the previous handlers come back after."""
    if threading.current_thread() is not threading.main_thread():
        yield stop
        return

    def on_signal(signum: int, _frame: FrameType | None) -> None:
        if received is not None:
            received.append(signum)
        stop.set()

    previous = {sig: signal.signal(sig, on_signal) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield stop
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


def result_line(rt: AgentRuntime, clock: Clock, extra: dict[str, Any]) -> str:
    """The JSON line an agent prints when it leaves a complete mission, with what it does not
    see (``unseen``), what departed agents left behind (``orphaned``), the agents the team
    fenced out as lost, the landmarks it adopted from them and the fence rounds it led; an
    inspection's ``complete`` is its end's (every capturable landmark captured), with
    ``given_up`` ({id: reason})."""
    st = rt.standing(seen=True)
    seen = st.seen
    assert seen is not None
    return json.dumps({"agent": rt.id, "complete": True, "owned": st.owned,
                       "unseen": seen.unseen, "orphaned": seen.orphaned,
                       "fenced": st.fenced, "adopted": st.adopted,
                       "fence_rounds": st.fence_rounds, "vision": seen.vision, "ok": st.ok,
                       "failed": st.failed, "requests": st.requests,
                       "published": st.published, "bytes_out": st.bytes_out,
                       "timeouts": st.timeouts, "rejected": st.rejected,
                       "completed_at_s": st.completed_at, "exit_at_s": clock.now(),
                       **_inspection(seen), **extra})


def _inspection(st: Seen) -> dict[str, Any]:
    """An inspection mission's part of the result line: the landmarks captured in this
    agent's view, how many were capturable, those it captured itself, whether it is complete
    and what was given up."""
    ins = st.inspection
    if ins is None:
        return {}
    return {"captured": ins.captured, "capturable": ins.capturable,
            "captured_by_me": ins.captured_by_me, "complete": ins.end.complete,
            "given_up": {str(k): v for k, v in ins.end.given_up.items()},
            "refused_claims": ins.refused_claims}


def quality_warning(rt: AgentRuntime) -> str:
    """One line when the mission ended but not everything is inspected (a coverage mission's
    own landmarks unseen, landmarks orphaned by departed agents); empty otherwise. An
    inspection's landmarks not captured are in its end line
    (:func:`~agent.runners.quality.inspection_end_line`)."""
    parts = []
    st = rt.standing(seen=True).seen
    assert st is not None
    inspection = st.inspection is not None
    if not inspection and (unseen := st.unseen):
        parts.append(f"{len(unseen)} of its landmarks unseen ({_ids(unseen)})")
    for aid, ids in sorted(st.orphaned.items()):
        parts.append(f"{len(ids)} landmark(s) orphaned by {aid}, which left ({_ids(ids)})")
    if not parts:
        return ""
    return ("ended with " if inspection else "complete with ") + "; ".join(parts)


def _ids(ids: list[int], most: int = 10) -> str:
    """``ids`` as a short human list."""
    head = ", ".join(str(i) for i in ids[:most])
    return head + (f", ... {len(ids)} in all" if len(ids) > most else "")


def ensure_id_free(tp: Transport, mission: str, agent_id: str, wait_s: float = 0.5) -> None:
    """Refuse to start a second agent with the same id on the mission (another machine):
    a :class:`~agent.errors.UsageError` if its liveliness token is already present."""
    if agent_id in live_agents(tp, mission, wait_s):
        raise UsageError(f"agent {agent_id} is already running on mission {mission} (its "
                         "liveliness token is present): stop it first, or start this one "
                         "with another --id")


def agent_loop(rt: AgentRuntime, clock: Clock, stop: threading.Event, *,
               exit_on_complete: bool, timeout_s: float | None,
               each_tick: Callable[[], int | None] | None = None,
               report: Callable[[], dict[str, Any]] | None = None,
               orders: Orders | None = None) -> int:
    """The agent's main loop, kinematic or flying: one runtime tick per Δt of mission time.

    ``each_tick`` may end the loop with an exit status. Returns 0 once the mission has been
    complete long enough (``exit_on_complete``; prints :func:`result_line` with ``report()``),
    :data:`~agent.errors.EXIT_INCOMPLETE` after ``timeout_s`` wall seconds, 0 when ``stop``
    is set. A mission command (``orders``: land or stop) is obeyed before anything else:
    the loop ends at once with 0 and says why in one line. Whenever it ends before the
    mission is complete it announces the departure (:mod:`agent.runners.departure`); an
    ``each_tick`` that ends it announces its own.
    """
    dt = rt.sc.params.dt
    t_next = clock.now()
    deadline = None if timeout_s is None else time.monotonic() + timeout_s
    while not stop.is_set():
        if orders is not None and orders.received is not None:
            print(f"viscover: agent {rt.id}: leaving the mission: {orders.describe()}",
                  file=sys.stderr, flush=True)
            announce_departure(rt, "operator_stop" if orders.received.command == "stop"
                               else "operator_land", orders.describe())
            orders.reaffirm()
            return EXIT_OK
        try:
            rt.tick()
        except JournalFailed as e:  # nothing more can be made durable: leave the mission
            print(f"viscover: error: agent {rt.id}: {e}", file=sys.stderr)
            announce_departure(rt, "journal_failed", str(e))
            return EXIT_FAILURE
        st = rt.standing()
        if (out := st.fenced_out) is not None:
            why = (f"the team declared it lost (fence round {out.epoch}, told by {out.by}) "
                   "and adopted its landmarks; it holds nothing and leaves the mission")
            print(f"viscover: agent {rt.id}: {why}", file=sys.stderr, flush=True)
            announce_departure(rt, "fenced", why)
            return EXIT_OK
        if (unheard := st.final_word_gave_up) is not None:
            print(f"viscover: agent {rt.id}: {unheard}", file=sys.stderr, flush=True)
            announce_departure(rt, "timeout", unheard)
            return EXIT_INCOMPLETE
        if each_tick is not None and (code := each_tick()) is not None:
            return code
        if exit_on_complete and rt.exit_due(clock.now()):
            print(result_line(rt, clock, report() if report is not None else {}), flush=True)
            if (line := inspection_end_line(rt)) is not None:  # complete, or INCOMPLETE: ...
                print(f"viscover: agent {rt.id}: {line}", file=sys.stderr, flush=True)
            if warning := quality_warning(rt):
                print(f"viscover: agent {rt.id}: {warning}", file=sys.stderr, flush=True)
            return EXIT_OK
        if deadline is not None and time.monotonic() > deadline:
            why = f"not complete after {timeout_s} s ({rt.completion_blocker(clock.now())})"
            print(f"viscover: agent {rt.id}: {why}", file=sys.stderr)
            if (line := inspection_end_line(rt)) is not None:  # what the time left
                print(f"viscover: agent {rt.id}: {line}", file=sys.stderr)
            announce_departure(rt, "timeout", why)
            return EXIT_INCOMPLETE
        t_next += dt
        now = clock.now()
        if t_next < now - dt:
            t_next = now
        if t_next > now:
            stop.wait(clock.wall(t_next - now))
    if not rt.complete:
        announce_departure(rt, "signal", "stopped by SIGINT/SIGTERM")
    return EXIT_OK


def signal_status(code: int, received: list[int]) -> int:
    """The exit status of a process whose loop ended with ``code`` after the signals
    ``received``: :data:`~agent.errors.EXIT_INTERRUPTED` (130) after SIGINT (Ctrl-C), as
    shells report it; ``code`` (0 for a clean stop) after SIGTERM, the orderly stop of a
    service manager: the deploy units (``deploy/systemd``) count only 0 as a clean exit, so
    128 + 15 would leave ``systemctl stop``-ped agents failed, and ``viscover launch`` stops
    its agents with it."""
    if code == EXIT_OK and received and received[0] == signal.SIGINT:
        return EXIT_INTERRUPTED
    return code


def run_agent(opts: AgentOptions) -> int:
    """Run one kinematic agent until the mission is complete (with ``exit_on_complete``),
    ``timeout_s`` runs out, or SIGINT/SIGTERM; returns the exit status
    (:func:`signal_status`)."""
    faults = make_fault_injector(opts)
    journal = open_journal(opts)
    stop = threading.Event()
    clock = WallClock(opts.rate_scale, stop)
    tp = rt = orders = None
    got: list[int] = []  # SIGINT / SIGTERM received
    try:
        with stop_on_signals(stop, got):
            tp = open_transport(opts.zenoh, faults, opts.agent_id, opts.connect_wait_s, stop)
            ensure_id_free(tp, opts.mission, opts.agent_id)
            refuse_forgotten_id(tp, opts.mission, opts.agent_id, journal)
            orders = Orders(tp, opts.mission, opts.agent_id)
            rt = AgentRuntime(opts.agent_id, opts.scenario, tp, journal, clock,
                              config=opts.runtime_config(opts.rate_scale), join=opts.join)
            rt.start()
            _log.info("agent %s started (mission %s, incarnation %d)", opts.agent_id,
                      opts.mission, rt.standing().incarnation)
            code = agent_loop(rt, clock, stop, exit_on_complete=opts.exit_on_complete,
                              timeout_s=opts.timeout_s, orders=orders,
                              report=lambda: {"rate_scale": opts.rate_scale})
            return signal_status(code, got)
    finally:
        if orders is not None:
            orders.close()
        if rt is not None:
            rt.stop()
        if tp is not None:
            tp.close()
        journal.close()
        if faults is not None:
            faults.close()
