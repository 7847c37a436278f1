"""A small Python API over viscover's own machinery, for lab scripts (as Crazyswarm2's or
MAVSDK's): every call does what a ``viscover`` command does, with the same code.

* :meth:`Mission.launch` starts a whole mission on this machine (``viscover launch``: a Zenoh
  router on a free loopback port or the one given, the ground station for ``flight``, one
  agent process per drone, a run folder), as a child process; :meth:`Mission.attach`
  joins a mission already running on a mesh (``viscover status``).
* :meth:`Mission.states` iterates over the mission's state (:class:`~agent.mission.watch.
  MissionView`, the rows of ``viscover status``: per drone phase, landmarks, vision, trades,
  link; coverage, completion, violations, lost drones, an inspection's captures), one snapshot
  per ``period`` [s, wall], until the mission is over; :meth:`Mission.events` hands over the
  events the watch derives (trades, phases, joins, leaves, commands, violations: the typed
  Structs of :mod:`agent.storage.events`).
* :meth:`Mission.land` and :meth:`Mission.stop` are ``viscover land`` / ``viscover stop``;
  :meth:`Mission.wait` waits for the end and returns the exit status ``viscover launch``
  returns (0 complete or ended by the operator, 1 violation or failure, 3 not complete);
  :meth:`Mission.close` (or leaving the ``with`` block) lands and stops whatever this process
  launched, as Ctrl-C does.
* :class:`Run` reads a run folder: ``launch.json``, ``observer.json``, ``rehearsal.json`` and
  ``result.json`` (built from the recording, as ``viscover report --no-plots`` does, when the
  folder has none yet).
* :func:`simulate` runs a mission in memory on virtual time (``viscover simulate``), under
  seeded faults if asked (``--drop``, ``--dup``, ``--jitter``, ``--lose``): the result, and
  with faults the invariants and end an observer saw.

Errors a user can fix raise :class:`~agent.errors.UsageError` (one line, as the CLI prints
them). Times are wall seconds unless said; positions [m; world ENU].
"""

from __future__ import annotations

import contextlib
import os
import queue
import re
import signal
import subprocess
import sys
import threading
import time
from collections import deque
from collections.abc import Iterable, Iterator, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from agent.errors import EXIT_FAILURE, EXIT_INCOMPLETE, EXIT_OK, UsageError
from viscover.runs import Run, Simulation, scenario_of, simulate

if TYPE_CHECKING:
    from agent.config.scenario import Scenario
    from agent.mission.watch import MissionView, MissionWatch
    from agent.net.transport import ZenohTransport
    from agent.storage.events import Event
    from agent.wire.commands import CommandKind

__all__ = ["Mission", "Run", "Simulation", "UsageError", "simulate"]

#: Wall seconds a launched mission has to land and stop once closed, before it is killed.
GRACE_S = 120.0


def _endpoint(text: str, what: str) -> str:
    """A Zenoh endpoint (``tcp/HOST:PORT``), or a :class:`UsageError` naming ``what``."""
    import argparse

    from agent.commands import kit

    try:
        return kit.endpoint(text)
    except argparse.ArgumentTypeError as e:
        raise UsageError(f"{what}: {e}") from None


class _Launched:
    """``viscover launch`` running as a child process (in its own session, as the launcher
    runs its own children): its output kept (the last ``keep`` lines), the run folder and
    the router's endpoint read from it, its exit status once it ended."""

    def __init__(self, cmd: list[str], keep: int = 2000) -> None:
        from agent.mission.launcher import REPO

        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(REPO), env.get("PYTHONPATH")]))
        self.lines: deque[str] = deque(maxlen=keep)
        self.run_dir: Path | None = None
        self.endpoint = ""
        self.known = threading.Event()  #: run folder and endpoint read (or the launch ended)
        self.proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                     text=True, env=env, start_new_session=True)
        self._reader = threading.Thread(target=self._read, daemon=True,
                                        name=f"viscover-launch-{self.proc.pid}")
        self._reader.start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        with self.proc.stdout:
            for line in self.proc.stdout:  # until the launch exits
                text = line.rstrip("\n")
                self.lines.append(text)
                if m := re.match(r"launch: (?:run folder|resuming) (.+)$", text):
                    self.run_dir = Path(m.group(1))
                elif m := re.match(r"launch: status: .* --connect (\S+)", text):
                    self.endpoint = m.group(1)
                if self.run_dir is not None and self.endpoint:
                    self.known.set()
        self.known.set()

    @property
    def alive(self) -> bool:
        """The launch has not exited yet."""
        return self.proc.poll() is None

    def end(self, timeout: float | None) -> int | None:
        """Wait up to ``timeout`` [s] (None: for ever) for the exit status (128 + the signal
        of one that ended it, as a shell reports it); None if it is still running."""
        try:
            code = self.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            return None
        self._reader.join(5.0)
        return 128 - code if code < 0 else code

    def interrupt(self, grace: float) -> int | None:
        """End the launch as Ctrl-C does (SIGINT: every drone lands, then everything stops),
        killing it after ``grace`` [s]; its exit status."""
        if self.alive:
            with contextlib.suppress(ProcessLookupError):
                self.proc.send_signal(signal.SIGINT)
        code = self.end(grace)
        if code is None:
            self.proc.kill()
            code = self.end(10.0)
        return code


class Mission:
    """A mission on a Zenoh mesh, launched here (:meth:`launch`) or attached to
    (:meth:`attach`). Use it as a context manager, or call :meth:`close`."""

    def __init__(self, scenario: Scenario, mission: str, tp: ZenohTransport,
                 launched: _Launched | None = None) -> None:
        from agent.mission.watch import MissionWatch

        self.scenario, self.mission, self._tp = scenario, mission, tp
        self._launched = launched
        self._events: queue.Queue[Event] = queue.Queue()
        self.watch: MissionWatch = MissionWatch(tp, mission, scenario, start=False)
        self.watch.listeners.append(self._events.put)
        self.watch.start()
        self._closed = False

    # -- starting ---------------------------------------------------------------------------
    @classmethod
    def launch(cls, scenario: str | os.PathLike[str], *, runs: str | os.PathLike[str] = "runs",
               router: str | None = None, flight: bool = False, rate_scale: float = 10.0,
               time_scale: float = 3.0, timeout: float | None = None, record: bool = False,
               agent_args: Sequence[str] = (), mission: str | None = None,
               connect_wait: float = 30.0) -> Mission:
        """Start the mission of ``scenario`` (a .toml file) as ``viscover launch`` does, in a
        fresh run folder under ``runs``: a router on a free loopback port (or the running one
        at ``router``, e.g. ``tcp/127.0.0.1:7447``), the ground station and simulated
        quadrotors with ``flight``, one agent process per drone (kinematic ones ``rate_scale``
        times faster than real time; the fleet ``time_scale``), ``agent_args`` given to
        every agent (fault flags: ``["--drop=0.3"]``); ``record`` the mission
        (events.jsonl, recording.mcap; needs the ``ground`` extra); the mission is stopped
        after ``timeout`` [s] (exit status 3). Returns once this process's own session
        hears the mesh."""
        from agent.commands import kit

        sc = scenario_of(scenario)
        if router is not None:
            router = _endpoint(router, "router")
        name = kit.mission_name(mission, sc)
        cmd = [sys.executable, "-m", "agent.cli", "launch", str(scenario), "--runs", str(runs),
               "--mission", name, "--rate-scale", f"{rate_scale:g}", "--time-scale",
               f"{time_scale:g}", "--connect-wait", f"{connect_wait:g}",
               *(["--flight"] if flight else []), *(["--router", router] if router else []),
               *(["--timeout", f"{timeout:g}"] if timeout is not None else []),
               *([] if record else ["--no-record"]),
               *(f"--agent-arg={a}" for a in agent_args)]
        launched = _Launched(cmd)
        try:
            launched.known.wait(connect_wait + 60.0)
            if not launched.endpoint or launched.run_dir is None:
                code = launched.interrupt(30.0)
                said = next((x.removeprefix("viscover: error: ") for x in launched.lines
                             if x.startswith("viscover: error: ")), None)
                raise UsageError(said or f"viscover launch {scenario} did not start (exit "
                                 f"status {code}): {(list(launched.lines) or ['no output'])[-1]}")
            tp = _session(launched.endpoint, connect_wait)
            try:
                return cls(sc, name, tp, launched)
            except BaseException:
                tp.close()
                raise
        except BaseException:
            launched.interrupt(GRACE_S)
            raise

    @classmethod
    def attach(cls, scenario: str | os.PathLike[str], *, connect: str = "tcp/127.0.0.1:7447",
               mission: str | None = None, connect_wait: float = 10.0) -> Mission:
        """Join the running mission of ``scenario`` on the mesh at ``connect`` (a router's
        endpoint) as ``viscover status`` does: watch it, land or stop its drones; it is left
        running on :meth:`close`."""
        from agent.commands import kit

        sc = scenario_of(scenario)
        return cls(sc, kit.mission_name(mission, sc),
                   _session(_endpoint(connect, "connect"), connect_wait))

    # -- watching ---------------------------------------------------------------------------
    @property
    def run(self) -> Run | None:
        """The run folder of a launched mission (None: attached)."""
        if self._launched is None or self._launched.run_dir is None:
            return None
        return Run(self._launched.run_dir)

    @property
    def output(self) -> list[str]:
        """The launcher's last lines (every process's output, labelled; status lines)."""
        return [] if self._launched is None else list(self._launched.lines)

    @property
    def running(self) -> bool:
        """A launched mission whose launcher has not ended yet (attached: True)."""
        return self._launched is None or self._launched.alive

    def view(self) -> MissionView:
        """The mission now (the rows and summary of ``viscover status``)."""
        return self.watch.view()

    def states(self, period: float = 0.5, timeout: float | None = None
               ) -> Iterator[MissionView]:
        """A snapshot of the mission every ``period`` [s] until it is complete (the last one
        then says so), its launcher ended, or ``timeout`` [s] passed."""
        end = None if timeout is None else time.monotonic() + timeout
        while True:
            view = self.view()
            yield view
            if view.complete or not self.running or (end is not None and time.monotonic() >= end):
                return
            time.sleep(period)

    def events(self, timeout: float = 0.0) -> Iterator[Event]:
        """The events heard since the last call (waiting up to ``timeout`` [s] for the
        first one), in order."""
        try:
            yield self._events.get(timeout=timeout) if timeout > 0 else \
                self._events.get_nowait()
        except queue.Empty:
            return
        while True:
            try:
                yield self._events.get_nowait()
            except queue.Empty:
                return

    def live(self, wait: float = 0.5) -> set[str]:
        """The drones whose agent is live on the mesh now, asked for up to ``wait`` [s]: a
        session just opened may hear no token at its first liveliness query, so an empty
        answer is asked again until ``wait`` passed."""
        from agent.mission.operator import live_agents

        ids = {a.id for a in self.scenario.agents}
        end = time.monotonic() + wait
        while True:
            found = live_agents(self._tp, self.mission, max(0.05, end - time.monotonic()))
            if found & ids or time.monotonic() >= end:
                return found & ids
            time.sleep(0.05)

    # -- commanding -------------------------------------------------------------------------
    def land(self, ids: Iterable[str] | None = None, timeout: float = 10.0
             ) -> dict[str, float | None]:
        """``viscover land``: each drone of ``ids`` (default: every live one) leaves the
        mission, flies home and lands (a kinematic agent exits); repeated until each
        acknowledged or ``timeout`` [s]: {drone: seconds until it did, or None}."""
        return self._command("land", ids, timeout)

    def stop(self, ids: Iterable[str] | None = None, timeout: float = 10.0
             ) -> dict[str, float | None]:
        """``viscover stop``: emergency, each drone of ``ids`` (default: every live one)
        leaves at once and its flight controller lands where it is; as :meth:`land`."""
        return self._command("stop", ids, timeout)

    def _command(self, kind: CommandKind, ids: Iterable[str] | None, timeout: float
                 ) -> dict[str, float | None]:
        from agent.mission.operator import send_command

        known = [a.id for a in self.scenario.agents]
        targets = sorted(self.live(1.0)) if ids is None else sorted(set(ids))
        if unknown := [x for x in targets if x not in known]:
            raise UsageError(f"{', '.join(unknown)}: not drones of {self.scenario.name} "
                             f"(drones: {', '.join(known)})")
        if not targets:
            return {}
        return send_command(self._tp, self.mission, kind, targets,
                            sender=f"api-{os.getpid()}", timeout_s=timeout)

    # -- ending -----------------------------------------------------------------------------
    def wait(self, timeout: float | None = None) -> int | None:
        """Wait for the end: a launched mission's exit status (that of ``viscover launch``),
        an attached one's as ``viscover observe --until-complete`` says it (0 complete, 1 a
        violation, 3 ended incomplete); None if ``timeout`` [s] passed first."""
        if self._launched is not None:
            return self._launched.end(timeout)
        obs = self.watch.observer
        if not obs.done.wait(timeout):
            return None
        rep = obs.snapshot()
        return EXIT_FAILURE if rep.violations else EXIT_OK if rep.complete else EXIT_INCOMPLETE

    def close(self) -> int | None:
        """Stop watching; a launched mission still running is ended as Ctrl-C ends it (every
        drone lands, then everything stops). Returns a launched mission's exit status."""
        launched = self._launched
        if not self._closed:
            self._closed = True
            self.watch.close()
            self._tp.close()
        return None if launched is None else launched.interrupt(GRACE_S)

    def __enter__(self) -> Mission:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _session(endpoint: str, wait: float) -> ZenohTransport:
    from agent.net.router import client_config
    from agent.net.session import open_session

    return open_session(client_config([endpoint]), None, f"api-{os.getpid()}", wait,
                        say=lambda _line: None)
