"""``viscover router``, ``viscover agent`` and ``viscover observe``.

:func:`register` adds the three subcommands to the ``viscover`` parser (see :mod:`agent.cli`);
``python -m agent.runtime.cli_commands ...`` runs them standalone.

Exit codes: 0 ok; 1 the observer saw an invariant violation; 2 a user mistake (one line on
stderr); 3 the observer timed out before the mission completed (with ``--until-complete``);
130 interrupted.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import signal
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from types import FrameType
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from agent.net.faults import FaultInjector
    from agent.runtime.agent import AgentRuntime
    from agent.storage.journal import Journal

EXIT_VIOLATION = 1
EXIT_USAGE = 2
EXIT_INCOMPLETE = 3

_log = logging.getLogger("viscover.agent")


class UsageError(Exception):
    """A mistake the user can fix (printed as one line, exit 2)."""


def fail(msg: str) -> int:
    print(f"viscover: error: {msg}", file=sys.stderr)
    return EXIT_USAGE


def _prob(text: str) -> float:
    try:
        p = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not 0.0 <= p <= 1.0:
        raise argparse.ArgumentTypeError(f"{text} is not a probability in [0, 1]")
    return p


def _nonneg(text: str) -> float:
    try:
        x = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not x >= 0.0:
        raise argparse.ArgumentTypeError(f"{text} must be >= 0")
    return x


def _positive(text: str) -> float:
    x = _nonneg(text)
    if x == 0.0:
        raise argparse.ArgumentTypeError("must be > 0")
    return x


def _kind_prob(text: str) -> tuple[str, float]:
    kind, sep, p = text.partition("=")
    if not sep or not kind:
        raise argparse.ArgumentTypeError(f"{text!r}: expected KIND=P, e.g. trade=0.5")
    return kind, _prob(p)


def _add_network(p: argparse.ArgumentParser) -> None:
    p.add_argument("--zenoh", metavar="FILE", help="Zenoh client config (json5), e.g. "
                   "broker_config/agent.json5")
    p.add_argument("--connect", metavar="ENDPOINT", action="append", default=[],
                   help="router endpoint, e.g. tcp/127.0.0.1:7447 (repeatable; overrides "
                   "--zenoh)")
    p.add_argument("--mission", help="mission name (key prefix); default: scenario name")


def register(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add the ``router``, ``agent`` and ``observe`` subcommands."""
    r = subparsers.add_parser("router", help="run a Zenoh router",
                              description="Run a Zenoh router (Ctrl-C to stop).")
    r.add_argument("--config", required=True, metavar="FILE",
                   help="router config (json5), e.g. broker_config/router.json5")
    r.set_defaults(func=cmd_router)

    a = subparsers.add_parser("agent", help="run one drone agent",
                              description="Run one agent: planner, landmark trading over "
                              "Zenoh, journal. Stops on SIGINT/SIGTERM.")
    a.add_argument("--id", required=True, help="agent id (as in the scenario)")
    a.add_argument("--scenario", required=True, metavar="FILE.toml")
    _add_network(a)
    a.add_argument("--state-dir", metavar="DIR", help="journal directory (default "
                   "~/.local/state/viscover/<mission>/<id>)")
    a.add_argument("--rate-scale", type=_positive, default=1.0, metavar="X",
                   help="run the mission clock X times faster than real time")
    a.add_argument("--exit-on-complete", action="store_true",
                   help="exit once the mission is complete")
    a.add_argument("--timeout", type=_positive, default=None, metavar="S",
                   help="give up after S real seconds (exit 3)")
    a.add_argument("--connect-wait", type=_nonneg, default=30.0, metavar="S",
                   help="keep trying to reach the router for S seconds at start (default 30)")
    a.add_argument("--request-timeout", type=_positive, default=0.3, metavar="S",
                   help="real seconds a trade query waits for its reply (default 0.3)")
    f = a.add_argument_group("fault injection (seeded, logged)")
    f.add_argument("--drop", type=_prob, default=0.0, metavar="P",
                   help="drop probability of every message, both directions")
    f.add_argument("--drop-kind", type=_kind_prob, action="append", default=[],
                   metavar="KIND=P", help="drop probability for one kind (pose, state, trade, "
                   "trade.reply, alive...), both directions; repeatable")
    f.add_argument("--delay", type=_nonneg, default=0.0, metavar="S", help="fixed delay [s]")
    f.add_argument("--jitter", type=_nonneg, default=0.0, metavar="S",
                   help="extra uniform delay in [0, S) [s]")
    f.add_argument("--dup", type=_prob, default=0.0, metavar="P", help="duplication probability")
    f.add_argument("--partition", default="", metavar="A,B",
                   help="agent ids this agent cannot reach")
    f.add_argument("--fault-seed", type=int, default=0, metavar="N")
    f.add_argument("--fault-log", metavar="PATH", help="JSONL log of injected faults")
    a.add_argument("--log-level", default="WARNING")
    from agent.runtime.flight_agent import add_flight_arguments

    add_flight_arguments(a)  # --flight, --mavlink, ...: fly a quadcopter (chapter 6)
    a.set_defaults(func=cmd_agent)

    o = subparsers.add_parser("observe", help="watch a mission and check its invariants",
                              description="Subscribe to every agent's state; report invariant "
                              "violations (exit 1), coverage and completion.")
    o.add_argument("--scenario", required=True, metavar="FILE.toml")
    _add_network(o)
    o.add_argument("--until-complete", action="store_true",
                   help="exit when the mission is complete (exit 3 on --timeout)")
    o.add_argument("--timeout", type=_positive, default=None, metavar="S",
                   help="stop after S seconds")
    o.add_argument("--json-out", metavar="PATH", help="write the report as JSON")
    o.add_argument("--log-level", default="WARNING")
    o.set_defaults(func=cmd_observe)


# -- helpers ---------------------------------------------------------------------------------


def load_scenario_arg(path: str) -> Any:
    from agent.config.scenario import ScenarioError, load_scenario

    try:
        return load_scenario(path)
    except ScenarioError as e:
        raise UsageError(str(e)) from None


def mission_name(args: argparse.Namespace, scenario: Any) -> str:
    from agent.wire import keys

    name = args.mission or "".join(c if c.isalnum() or c in "_-" else "_"
                                   for c in scenario.name)[:32]
    try:
        return keys.validate_id(name, "mission")
    except keys.KeyFormatError as e:
        raise UsageError(f"--mission: {e}") from None


def zenoh_config(args: argparse.Namespace) -> Any:
    from agent.net.router import client_config

    if args.connect:
        return client_config(args.connect)
    if args.zenoh:
        import zenoh

        if not Path(args.zenoh).is_file():
            raise UsageError(f"--zenoh {args.zenoh}: no such file")
        try:
            return zenoh.Config.from_file(args.zenoh)
        except Exception as e:  # zenoh reports config errors as ZError/ValueError
            raise UsageError(f"--zenoh {args.zenoh}: {e}") from None
    return client_config(["tcp/127.0.0.1:7447"])


def open_transport(cfg: Any, faults: Any, node_id: str, wait_s: float = 0.0,
                    stop: threading.Event | None = None) -> Any:
    """Open a :class:`ZenohTransport`, retrying for up to ``wait_s`` seconds while no router
    answers (a drone may boot before its ground station)."""
    from agent.net.transport import ZenohTransport

    deadline = time.monotonic() + wait_s
    while True:
        try:
            return ZenohTransport(cfg, faults, node_id)
        except Exception as e:
            if time.monotonic() >= deadline or (stop is not None and stop.is_set()):
                raise UsageError(
                    f"cannot open a Zenoh session (is the router running?): {e}") from None
            _log.info("no router yet (%s); retrying", e)
            if stop is not None:
                stop.wait(0.5)
            else:
                time.sleep(0.5)


def install_signals(stop: threading.Event) -> dict[int, Any]:
    """SIGINT/SIGTERM set ``stop`` (main thread only); returns the previous handlers."""
    if threading.current_thread() is not threading.main_thread():
        return {}

    def on_signal(_signum: int, _frame: FrameType | None) -> None:
        stop.set()

    return {sig: signal.signal(sig, on_signal) for sig in (signal.SIGINT, signal.SIGTERM)}


def restore_signals(previous: dict[int, Any]) -> None:
    for sig, handler in previous.items():
        signal.signal(sig, handler)


# -- commands --------------------------------------------------------------------------------


def cmd_router(args: argparse.Namespace) -> int:
    """``viscover router --config FILE``."""
    from agent.net.router import run_router

    if not Path(args.config).is_file():
        return fail(f"--config {args.config}: no such file")
    logging.basicConfig(level="INFO", format="%(asctime)s %(name)s %(message)s")
    try:
        run_router(args.config)
    except KeyboardInterrupt:
        return 130
    except Exception as e:
        return fail(f"router: {e}")
    return 0


def fault_injector(args: argparse.Namespace) -> FaultInjector | None:
    """The seeded fault injector of the agent's fault flags (None without faults)."""
    from agent.net.faults import FaultConfig, FaultInjector
    from agent.wire import keys

    kinds = dict(args.drop_kind)
    partition = [x for x in args.partition.split(",") if x]
    for x in partition:
        try:
            keys.validate_id(x)
        except keys.KeyFormatError as e:
            raise UsageError(f"--partition: {e}") from None
    if not (args.drop or kinds or args.delay or args.jitter or args.dup or partition):
        return None
    fc = FaultConfig(drop_out=kinds, drop_in=dict(kinds), drop_default=args.drop,
                     delay_s=args.delay, jitter_s=args.jitter, duplicate=args.dup,
                     partition=partition)
    try:
        return FaultInjector(fc, seed=args.fault_seed, log=args.fault_log, keep_records=False)
    except OSError as e:
        raise UsageError(f"--fault-log {args.fault_log}: {e.strerror or e}") from None


def open_journal(args: argparse.Namespace, mission: str) -> Journal:
    """The agent's journal in ``--state-dir`` (default per mission and id), locked."""
    from agent.storage.journal import Journal, JournalLocked, default_state_dir

    state_dir = Path(args.state_dir) if args.state_dir else default_state_dir(mission, args.id)
    try:
        return Journal(state_dir)
    except JournalLocked as e:
        raise UsageError(str(e)) from None
    except OSError as e:
        raise UsageError(f"--state-dir {state_dir}: {e.strerror or e}") from None


def new_runtime(*args: Any, **kwargs: Any) -> AgentRuntime:
    """``AgentRuntime(*args, **kwargs)`` (it replays the journal), a journal written by another
    build or for another scenario reported as a usage error."""
    from agent.protocol.machine import JournalMismatch
    from agent.runtime.agent import AgentRuntime

    try:
        return AgentRuntime(*args, **kwargs)
    except JournalMismatch as e:
        raise UsageError(str(e)) from None


def agent_loop(rt: AgentRuntime, args: argparse.Namespace, clock: Any, stop: threading.Event,
               *, each_tick: Callable[[], int | None] | None = None,
               report: Callable[[], dict[str, Any]] | None = None) -> int:
    """The agent's main loop (``viscover agent``, kinematic or flying): one runtime tick per
    Δt of mission time. ``each_tick`` may end the loop with an exit code. Returns 0 once the
    mission has been complete long enough (``--exit-on-complete``; prints one JSON line with
    the agent's result and ``report()``), EXIT_INCOMPLETE after ``--timeout`` wall seconds,
    0 when ``stop`` is set."""
    dt = rt.sc.params.dt
    t_next = clock.now()
    deadline = None if args.timeout is None else time.monotonic() + args.timeout
    while not stop.is_set():
        rt.tick()
        if each_tick is not None and (code := each_tick()) is not None:
            return code
        if args.exit_on_complete and rt.exit_due(clock.now()):
            c = rt.counters
            print(json.dumps({"agent": args.id, "complete": True,
                              "owned": rt.machine.owned_arrays()[0].tolist(),
                              "vision": rt.vision(), "ok": rt.machine.ok,
                              "failed": rt.machine.failed, "requests": c.requests,
                              "published": c.published, "bytes_out": c.bytes_out,
                              "timeouts": c.timeouts, "rejected": rt.rejects.total,
                              "completed_at_s": rt.completed_at, "exit_at_s": clock.now(),
                              **(report() if report is not None else {})}), flush=True)
            return 0
        if deadline is not None and time.monotonic() > deadline:
            print(f"viscover: agent {args.id}: not complete after {args.timeout} s "
                  f"({rt.completion_blocker(clock.now())})", file=sys.stderr)
            return EXIT_INCOMPLETE
        t_next += dt
        now = clock.now()
        if t_next < now - dt:
            t_next = now
        if t_next > now:
            stop.wait(clock.wall(t_next - now))
    return 0


def cmd_agent(args: argparse.Namespace) -> int:
    """``viscover agent --id A --scenario S.toml ...``."""
    try:
        return _run_agent(args)
    except UsageError as e:
        return fail(str(e))


def _run_agent(args: argparse.Namespace) -> int:
    if args.mavlink is not None or args.flight is not None:
        from agent.runtime.flight_agent import run_flight_agent

        return run_flight_agent(args)
    from agent.clock import WallClock
    from agent.runtime.agent import AgentConfig

    logging.basicConfig(level=args.log_level.upper(),
                        format=f"%(asctime)s {args.id} %(name)s %(levelname)s %(message)s")
    sc = load_scenario_arg(args.scenario)
    if args.id not in [a.id for a in sc.agents]:
        raise UsageError(f"--id {args.id}: not an agent of {args.scenario} "
                          f"(agents: {', '.join(a.id for a in sc.agents)})")
    mission = mission_name(args, sc)
    faults = fault_injector(args)
    journal = open_journal(args, mission)
    stop = threading.Event()
    previous = install_signals(stop)
    scale = float(args.rate_scale)
    clock = WallClock(scale, stop)
    cfg = AgentConfig(mission=mission, seed=args.fault_seed,
                      request_timeout_s=args.request_timeout)
    for name in ("backoff_s", "backoff_cap_s", "doubt_delay_s", "state_period_s",
                 "pose_journal_period_s"):
        setattr(cfg, name, getattr(cfg, name) * scale)  # real-time behaviour, mission units
    tp = None
    rt = None
    try:
        tp = open_transport(zenoh_config(args), faults, args.id, args.connect_wait, stop)
        rt = new_runtime(args.id, sc, tp, journal, clock, config=cfg)
        rt.start()
        _log.info("agent %s started (mission %s, incarnation %d)", args.id, mission,
                  rt.machine.incarnation)
        return agent_loop(rt, args, clock, stop, report=lambda: {"rate_scale": scale})
    finally:
        if rt is not None:
            rt.stop()
        if tp is not None:
            tp.close()
        journal.close()
        if faults is not None:
            faults.close()
        restore_signals(previous)


def cmd_observe(args: argparse.Namespace) -> int:
    """``viscover observe --scenario S.toml ...``."""
    try:
        return _run_observe(args)
    except UsageError as e:
        return fail(str(e))


def _run_observe(args: argparse.Namespace) -> int:
    from agent.runtime.observer import Observer, print_report

    logging.basicConfig(level=args.log_level.upper(),
                        format="%(asctime)s observer %(name)s %(levelname)s %(message)s")
    sc = load_scenario_arg(args.scenario)
    mission = mission_name(args, sc)
    if args.json_out:
        parent = Path(args.json_out).parent
        if not parent.is_dir():
            raise UsageError(f"--json-out {args.json_out}: directory {parent} does not exist")
    stop = threading.Event()
    previous = install_signals(stop)
    try:
        tp = open_transport(zenoh_config(args), None, f"observer-{os.getpid()}")
    except BaseException:
        restore_signals(previous)
        raise
    obs = None
    try:
        obs = Observer(tp, mission, [a.id for a in sc.agents], list(sc.landmark_ids))
        deadline = None if args.timeout is None else time.monotonic() + args.timeout
        while not stop.is_set():
            if args.until_complete and obs.done.is_set():
                break
            if deadline is not None and time.monotonic() >= deadline:
                break
            stop.wait(0.05)
        rep = obs.snapshot()
        print_report(rep)
        if args.json_out:
            Path(args.json_out).write_text(json.dumps(rep.to_json(), indent=1))
        if rep.violations:
            return EXIT_VIOLATION
        if args.until_complete and not rep.complete:
            return EXIT_INCOMPLETE
        return 0
    finally:
        if obs is not None:
            obs.close()
        tp.close()
        restore_signals(previous)


def main(argv: list[str] | None = None) -> int:
    """Standalone entry point: ``python -m agent.runtime.cli_commands agent ...``."""
    parser = argparse.ArgumentParser(prog="viscover")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    register(sub)
    try:
        args = parser.parse_args(argv)
    except SystemExit as e:
        return e.code if isinstance(e.code, int) else EXIT_USAGE
    try:
        return int(args.func(args))
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
