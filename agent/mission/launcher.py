"""A whole mission on this machine from one command (``viscover launch``): start what it needs,
label and keep every process's output, supervise, show progress, and stop everything cleanly.

Processes, each in its own session (a terminal's Ctrl-C reaches only the launcher, which then
stops them in order): a Zenoh router on a free loopback port (unless one is given), the ground
station with simulated vehicles (``flight``; ``ground_args``), one agent per drone. The
launcher itself observes the mission (an in-process :class:`~.watch.MissionWatch`, the view
of ``viscover status``) and prints its status every 2 s: a line per drone and a summary; the
user's output is a view, kept going without a reader (``| head``; :mod:`~.output`).

Run folder: ``logs/<process>.log`` (every line each process printed; ``launch.log``: the
launcher's), ``state/<id>/`` (the agents' journals), ``observer.json`` (the final report) and
``launch.json`` (the scenario's digest, the router's endpoint and the ``viscover status /
land / stop`` commands that reach the mission, written at start; what was started and how it
ended, at the end). A fresh folder
per launch (:mod:`agent.mission.runfolder`); ``resume`` reuses one, journals included, once
found of the same scenario. A router elsewhere (``router``) is reached before anything is
written: with none there, the launch ends in one line and leaves no folder. With ``record``
(the run folder by default), ``events.jsonl`` and ``recording.mcap`` (:mod:`~.recorder`, plus
the processes' starts, exits, restarts, flight phases, failsafes), closed after every process.

Stopping: on SIGINT/SIGTERM (or ``timeout_s``) the agents get SIGTERM first (a flying agent
lands before it exits), then the ground station, then the router; anything still running after
its grace period is killed. Exit status: 0 the mission completed, or the operator ended it
(``viscover land`` / ``stop`` heard, :func:`~agent.mission.operator.ordered_end`), and every
agent exited 0; 1 an invariant violation or a process failure; 3 not complete within
``timeout_s``, or an inspection that ended with landmarks given up (said as every report of
its end says it, :mod:`agent.protocol.inspection_end`); 128 + signal number when interrupted
(130 for Ctrl-C), in ``launch.json`` too.

Not split further: starting, supervising and stopping share the children, their order and
the one recorder; the output is :mod:`~.output`'s, the run folder :mod:`~.runfolder`'s.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TextIO

from agent.config.digest import scenario_digest
from agent.config.scenario import Scenario
from agent.errors import EXIT_FAILURE, EXIT_INCOMPLETE, EXIT_OK, EXIT_USAGE, UsageError
from agent.mission.child import Child
from agent.mission.operator import order_listener, ordered_end
from agent.mission.output import LaunchOutput
from agent.mission.recorder import Recorder
from agent.mission.runfolder import mission_commands, write_captures, write_launch_json
from agent.mission.status import clocks_line, status_lines
from agent.mission.watch import MissionWatch
from agent.net.router import (
    client_config,
    free_tcp_port,
    start_router_process,
    stop_router_process,
)
from agent.net.security import launch_security
from agent.net.session import open_session
from agent.net.transport import ZenohTransport
from agent.storage.events import Crash, Event, Exited, LaunchEnd, Process

ROLES = ("router", "groundstation", "agents")
REPO = Path(__file__).resolve().parents[2]


@dataclass(frozen=True)
class LaunchPlan:
    """What to start and how (times in wall seconds unless stated)."""

    scenario_path: str
    scenario: Scenario
    mission: str
    run_dir: Path
    resume: bool = False
    flight: bool = False  #: fly simulated quadrotors (ground station + MAVLink)
    router: str | None = None  #: an existing router's endpoint (None: start one here)
    #: routers started here, each linked to every other (a mesh): agent k attaches to router
    #: k mod routers, the others its fallbacks (docs/running.md#more-than-one-router)
    routers: int = 1
    only: frozenset[str] = frozenset(ROLES)  #: the roles started on this machine
    ids: tuple[str, ...] = ()  #: the agents started here (default: every one)
    restart: bool = False  #: restart a crashed agent with its journal
    record: Path | None = None  #: record the mission into this folder (None: no recording)
    live: int | None = None  #: also serve the recording to Foxglove on this loopback port
    max_restarts: int = 5  #: per agent; then it is reported and left down
    rate_scale: float = 10.0  #: kinematic agents' mission seconds per wall second
    time_scale: float = 3.0  #: the simulated fleet's (flight)
    timeout_s: float | None = None
    agent_args: tuple[str, ...] = ()  #: extra ``viscover agent`` options (fault flags)
    ground_args: tuple[str, ...] = ()  #: extra ``viscover groundstation`` options (--gnss)
    #: extra options of one agent (its battery's capacity)
    own_args: Mapping[str, tuple[str, ...]] = field(default_factory=dict)
    status_period_s: float = 2.0
    out: TextIO = field(default=sys.stdout, compare=False)
    tls_dir: str | None = None  #: secured profile's team directory (None: $VISCOVER_TLS_DIR)
    connect_wait_s: float = 30.0  #: how long to wait for the router at ``router``


class Launcher:
    """Runs a :class:`LaunchPlan` (see the module docstring)."""

    def __init__(self, plan: LaunchPlan) -> None:
        self.plan = plan
        self.lock = threading.Lock()
        self.children: dict[str, Child] = {}
        self.router_proc: subprocess.Popen[bytes] | None = None
        self.endpoint = plan.router or ""
        self.router_pid: int | None = None
        self.mesh: list[tuple[subprocess.Popen[bytes], str]] = []  #: routers 2.. (``routers``)
        self.ports: dict[str, int] = {}
        self.recorder: Recorder | None = None
        self.security = launch_security(plan.tls_dir)  #: None: the open lab profile
        self.sec_args = self.security.child_args() if self.security else []
        self.orders: list[tuple[str, list[str]]] = []  #: (land/stop, targets) heard on the mesh
        self.child_env: dict[str, str] = {}  #: added to every child's environment
        self.output = LaunchOutput(plan.out, plan.run_dir / "logs", self._note)

    # -- output ----------------------------------------------------------------------------
    def say(self, text: str) -> None:
        """One line to the user, and into ``logs/launch.log`` (:mod:`~.output`)."""
        self.output.say(text)

    def _spawn(self, child: Child) -> None:
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(REPO), env.get("PYTHONPATH")]))
        env.update(self.child_env)
        log = child.log_path.open("a", encoding="utf-8")
        child.proc = subprocess.Popen(child.cmd, stdout=subprocess.PIPE,
                                      stderr=subprocess.STDOUT, text=True, env=env,
                                      start_new_session=True)
        child.pids.append(child.proc.pid)
        self._note(Process(source=child.name, level="info", text=f"{child.name}: started (pid "
                           f"{child.proc.pid})", pid=child.proc.pid))
        assert child.proc.stdout is not None
        self.output.copy(child, child.proc.stdout, log)

    # -- start -----------------------------------------------------------------------------
    def _viscover(self, *args: str) -> list[str]:
        return [sys.executable, "-m", "agent.cli", *args]

    def start_router(self) -> None:
        """A router on a free loopback port (unless the plan names one); with ``routers`` > 1
        that many, each dialling every other (a mesh; the first is the launcher's own)."""
        if self.plan.router is None and "router" in self.plan.only:
            team = self.security.team if self.security else None
            ports = [free_tcp_port() for _ in range(self.plan.routers)]
            eps = [f"{'tcp/127.0.0.1' if team is None else 'tls/localhost'}:{x}" for x in ports]
            for i, port in enumerate(ports):  # each keeps its fence record in the run
                proc, ep = start_router_process(
                    port, connect=eps[:i] + eps[i + 1:], new_session=True, team=team,
                    state_dir=self.plan.run_dir / ("router" if i == 0 else f"router{i + 1}"))
                if i == 0:
                    self.router_proc, self.endpoint, self.router_pid = proc, ep, proc.pid
                else:
                    self.mesh.append((proc, ep))
            for i, ep in enumerate(self.routers()):
                on = [a for k, a in enumerate(self.plan.ids) if k % len(eps) == i]
                self.say(f"router: {ep}" + (f" (agents {', '.join(on) or 'none'})"
                                            if self.mesh else ""))
        elif not self.endpoint:
            raise UsageError("--only without router: give the mission's router with --router")

    def routers(self) -> list[str]:
        """The endpoints of the mission's routers started here (the first: ``endpoint``)."""
        return [self.endpoint, *(ep for _p, ep in self.mesh)]

    def agent_connect(self, aid: str) -> list[str]:
        """``--connect`` options of drone ``aid``: its router of the mesh, then the others."""
        eps = self.routers()
        k = [a.id for a in self.plan.scenario.agents].index(aid) % len(eps)
        return [x for ep in eps[k:] + eps[:k] for x in ("--connect", ep)]

    def connect(self) -> ZenohTransport:
        """The launcher's own session on the router at ``endpoint``, waiting for it up to
        ``connect_wait_s`` (an external router) and saying so, else one line."""
        cfg = (self.security.client_config(self.endpoint) if self.security
               else client_config(self.routers()))
        return open_session(cfg, None, f"launch-{os.getpid()}", self.plan.connect_wait_s,
                            option="--router")

    def commands(self) -> dict[str, str]:
        """The ``viscover status / land / stop`` command lines that reach this mission."""
        p = self.plan
        return mission_commands(p.scenario_path, p.mission, self.endpoint, self.sec_args)

    def start_groundstation(self) -> None:
        """The ground station with one simulated vehicle per drone (``flight``); waits for
        its ready line to learn the vehicles' UDP ports."""
        p = self.plan
        ids = [a.id for a in p.scenario.agents]
        child = Child("groundstation", self._viscover(
            "groundstation", "--source", "sim", "--scenario", p.scenario_path, "--connect",
            self.endpoint, "--mission", p.mission, "--time-scale", str(p.time_scale),
            "--ports", ",".join(f"{d}=0" for d in ids), *self.sec_args, *p.ground_args),
            p.run_dir / "logs" / "groundstation.log")
        self.children[child.name] = child
        self._spawn(child)
        deadline = time.monotonic() + 30.0
        while time.monotonic() < deadline:
            ready = next((x for x in child.lines if x.startswith("viscover-groundstation ready")),
                         None)
            if ready is not None:
                self.ports = {w.split("=", 1)[0]: int(w.rsplit(":", 1)[1])
                              for w in ready.split() if "=udp:" in w}
                return
            assert child.proc is not None
            if child.proc.poll() is not None:
                break
            time.sleep(0.05)
        raise UsageError("the ground station did not start: see "
                         f"{child.log_path} ({(child.lines or ['no output'])[-1]})")

    def agent_command(self, aid: str) -> list[str]:
        """The ``viscover agent`` command of drone ``aid``."""
        p = self.plan
        cmd = self._viscover("agent", "--id", aid, "--scenario", p.scenario_path,
                             *self.agent_connect(aid), "--mission", p.mission, "--state-dir",
                             str(p.run_dir / "state" / aid), "--exit-on-complete",
                             "--log-level", "WARNING")
        if p.flight:
            cmd += ["--mavlink", f"udpout:127.0.0.1:{self.ports[aid]}"]
        else:
            cmd += ["--rate-scale", str(p.rate_scale)]
        return cmd + self.sec_args + list(p.agent_args) + list(p.own_args.get(aid, ()))

    def prepare(self) -> None:
        """An inspection's table built once for the team, named to every agent."""
        from agent.world.prepared import prepare_team

        self.child_env.update(prepare_team(self.plan.scenario, self.plan.run_dir, self.say))

    def start_agents(self, watch: MissionWatch | None = None) -> None:
        """One agent process per drone of the plan (each expected by ``watch`` from now; an
        inspection's table prepared first, once)."""
        self.prepare()
        for aid in self.plan.ids:
            child = Child(aid, self.agent_command(aid), self.plan.run_dir / "logs" / f"{aid}.log")
            self.children[aid] = child
            if watch is not None:
                watch.expect(aid)
            self._spawn(child)

    # -- supervise -------------------------------------------------------------------------
    def _check_children(self) -> list[str]:
        """Newly exited agents; a crashed one is reported in one line (and restarted)."""
        failures = []
        for aid in self.plan.ids:
            child = self.children.get(aid)
            if child is None or child.proc is None or child.exit_code is not None:
                continue
            code = child.proc.poll()
            if code is None:
                continue
            if code != 0 and self.plan.restart and child.restarts < self.plan.max_restarts:
                child.restarts += 1
                self.say(f"launch: agent {aid} exited with status {code}; restarting it with "
                         f"its journal ({child.restarts}/{self.plan.max_restarts})")
                self._note(Crash(source=aid, level="error", text=f"{aid}: exited with status "
                                 f"{code}; restarted", status=code))
                self._spawn(child)
                continue
            child.exit_code = code
            self._note(Exited(source=aid, level="info" if code == 0 else "error",
                              text=f"{aid}: exited with status {code}", status=code))
            if code != 0:
                failures.append(f"agent {aid} exited with status {code} (see {child.log_path})")
                self.say(f"launch: {failures[-1]}")
        return failures

    def supervise(self, watch: MissionWatch | None, stop: threading.Event,
                  received: list[int] | None = None) -> tuple[int, str]:
        """Until every local agent has exited (0 too on the operator's orders), ``stop`` is set
        (signals ``received``) or the timeout passes: (exit status, how the mission ended)."""
        obs = None if watch is None else watch.observer
        p = self.plan
        t0 = time.monotonic()
        next_status = t0 + p.status_period_s
        failures: list[str] = []
        while not stop.is_set():
            failures += self._check_children()
            if all(self.children[a].exit_code is not None for a in p.ids):
                break
            if p.timeout_s is not None and time.monotonic() - t0 > p.timeout_s:
                left = "" if obs is None else obs.unfinished()  # an inspection: what is left
                return EXIT_INCOMPLETE, f"not complete within {p.timeout_s:g} s{left}"
            if watch is not None and time.monotonic() >= next_status:
                if next_status == t0 + p.status_period_s:  # the first status: its clocks
                    self.say("launch: " + clocks_line(
                        p.time_scale if p.flight else p.rate_scale, p.flight))
                for line in status_lines(watch.view(), "launch: "):
                    self.say(line)
                next_status += p.status_period_s
            stop.wait(0.1)
        if stop.is_set():
            sig = signal.Signals(received[0] if received else signal.SIGINT)
            self.say(f"launch: {sig.name}: landing and stopping everything")
            return 128 + sig, f"interrupted by {sig.name}"
        if failures:
            return EXIT_FAILURE, "; ".join(failures)
        if obs is not None:
            obs.done.wait(0.5 if self.orders else 5.0)
            rep = obs.snapshot()
            if rep.violations:
                return EXIT_FAILURE, f"{len(rep.violations)} invariant violation(s)"
            if not rep.ended and self.orders:
                return EXIT_OK, f"ended by the operator ({ordered_end(self.orders, p.ids)})"
            if not rep.ended and "router" in p.only:
                return EXIT_INCOMPLETE, ("the agents exited but the observer saw no completion"
                                         + obs.unfinished())
            if rep.inspection is not None:  # complete only with every capturable captured
                return (EXIT_OK if rep.complete else EXIT_INCOMPLETE), rep.inspection["verdict"]
        return EXIT_OK, "complete"

    # -- stop ------------------------------------------------------------------------------
    def _terminate(self, names: list[str], grace_s: float) -> None:
        procs = [(n, self.children[n].proc) for n in names if n in self.children]
        for _n, proc in procs:
            if proc is not None and proc.poll() is None:
                with contextlib.suppress(ProcessLookupError):
                    proc.send_signal(signal.SIGTERM)
        deadline = time.monotonic() + grace_s
        for n, proc in procs:
            if proc is None:
                continue
            try:
                proc.wait(max(0.1, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                self.say(f"launch: {n} did not stop within {grace_s:g} s; killing it")
                proc.kill()
                proc.wait(5.0)

    def stop_all(self) -> None:
        """Agents first (flying ones land), then the ground station, then the router."""
        self._terminate(list(self.plan.ids), 90.0 if self.plan.flight else 15.0)
        self._terminate(["groundstation"], 15.0)
        for name, child in self.children.items():
            if child.exit_code is None and child.proc is not None:
                child.exit_code = code = child.proc.poll()
                if name in self.plan.ids and code is not None:  # stopped here: recorded too
                    self._note(Exited(source=name, level="info" if code == 0 else "error",
                                      text=f"{name}: exited with status {code}", status=code))
        self.output.drain()  # the children's last lines (a landing) reach logs and events
        if self.router_proc is not None:
            stop_router_process(self.router_proc)
            self.router_proc = None
        for proc, _ep in self.mesh:  # kept: launch.json names them at the end too
            stop_router_process(proc)

    def _note(self, ev: Event) -> None:
        """Record one event of the launcher (processes, flight lines) when recording."""
        if self.recorder is not None:
            self.recorder.event(ev)

    # -- all together ----------------------------------------------------------------------
    def run(self, stop: threading.Event, received: list[int] | None = None) -> int:
        """Start, supervise, stop; returns the exit status (``received``: the signals that
        set ``stop``)."""
        p = self.plan
        tp: ZenohTransport | None = None
        if self.endpoint:  # a router elsewhere: reach it before anything is written
            try:
                tp = self.connect()
            except BaseException:
                if not p.resume:
                    with contextlib.suppress(OSError):
                        p.run_dir.rmdir()  # the fresh, still empty run folder
                raise
        (p.run_dir / "logs").mkdir(parents=True, exist_ok=True)
        self.output.open_log()
        self.say(f"launch: {'resuming' if p.resume else 'run folder'} {p.run_dir}")
        obs = watch = None
        code, how = EXIT_FAILURE, "launcher error"  # until supervise says otherwise
        try:
            self.start_router()
            if tp is None:
                tp = self.connect()
            for name, line in self.commands().items():
                self.say(f"launch: {name}: {line}")
            self._write_summary(None, "running")
            watch = MissionWatch(tp, p.mission, p.scenario, tls_dir=p.tls_dir)
            watch.listeners.append(order_listener(self.orders))
            obs = watch.observer
            if p.record is not None:
                try:
                    self.recorder = Recorder(tp, p.scenario, p.mission, p.record, watch=watch,
                                             live=p.live)
                except RuntimeError as e:  # the live server's port is taken
                    raise UsageError(f"--live {p.live}: {e}") from None
                if self.output.lost is not None:  # before the recording started
                    self._note(self.output.lost)
                live = self.recorder.server
                self.say(f"launch: recording into {self.recorder.path}" + (
                    "" if live is None else f", live on ws://127.0.0.1:{live.port}"))
            if p.flight and "groundstation" in p.only:
                self.start_groundstation()
            if "agents" in p.only:
                self.start_agents(watch)
            code, how = self.supervise(watch, stop, received)
        except UsageError as e:
            code, how = EXIT_USAGE, f"not started: {e}"
            raise
        except BaseException as e:  # a bug: its name in launch.json, everything still stopped
            how = f"launcher error: {type(e).__name__}: {e}"
            raise
        finally:
            self.stop_all()
            write_captures(p.run_dir, p.scenario)  # the agents have left their journals
            if obs is not None:
                rep = obs.snapshot()
                (p.run_dir / "observer.json").write_text(json.dumps(rep.to_json(), indent=1))
            if self.recorder is not None:
                self._note(LaunchEnd(source="launch", level="info" if code == EXIT_OK else
                                     "warning", text=f"launch: {how} (exit status {code})",
                                     status=code))
                self.recorder.close()
            if watch is not None:
                watch.close()
            if tp is not None:
                tp.close()
            self._write_summary(code, how)
        self.say(f"launch: {how}; logs and journals in {p.run_dir}")
        self.output.close_log()
        return code

    def _write_summary(self, code: int | None, how: str) -> None:
        """``launch.json``: at start (``code`` None) and again at the end."""
        p = self.plan
        write_launch_json(p.run_dir, {
            "scenario": p.scenario_path, "scenario_name": p.scenario.name,
            "scenario_digest": scenario_digest(p.scenario), "mission": p.mission,
            "flight": p.flight, "router": self.endpoint, "mesh": [ep for _p, ep in self.mesh],
            "commands": self.commands() if self.endpoint else {}, "resumed": p.resume,
            "exit_status": code, "ended": how, "router_pid": self.router_pid,
        }, self.children)
