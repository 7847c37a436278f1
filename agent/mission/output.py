"""What ``viscover launch`` prints, and where it is kept: :class:`LaunchOutput` says each line
to the user and into ``logs/launch.log``, and copies each child's output into its own log,
the user's screen and the events.

The user's output is a view, the run folder the record: when its reader goes away (``|
head``, a ``| tee`` that Ctrl-C ended, a closed terminal) the lines go on into the logs, the
loss is said once (``logs/launch.log`` and the events: ``launch: the output's reader went
away (Broken pipe); the mission goes on, every line in RUN/logs``) and nothing else changes.
The copy of a child's output never stops before that output ends: a child whose output is
not read would block on its next line.
"""

from __future__ import annotations

import contextlib
import errno
import logging
import os
import threading
from collections.abc import Callable
from pathlib import Path
from typing import IO, TextIO

from agent.mission.child import Child
from agent.mission.recorder import line_event
from agent.storage.events import Event, LogLine

_log = logging.getLogger(f"viscover.{__name__}")


class LaunchOutput:
    """The launcher's lines to ``out`` and ``logs/launch.log`` (once :meth:`open_log` named
    it); ``note`` records an event (the launcher's recorder, when it runs)."""

    def __init__(self, out: TextIO, logs: Path, note: Callable[[Event], None]) -> None:
        self.out, self.logs, self.note = out, logs, note
        self.console = True  #: the user's output still has a reader (False: | head ended)
        self.lost: LogLine | None = None  #: the event saying it went away
        self._lock = threading.Lock()
        self._said: IO[str] | None = None  #: logs/launch.log: every line said
        self.pumps: list[threading.Thread] = []  #: the threads copying the children's output

    def open_log(self) -> None:
        """Keep every line from now on in ``logs/launch.log``."""
        self._said = (self.logs / "launch.log").open("a", encoding="utf-8")

    def close_log(self) -> None:
        with self._lock:
            if self._said is not None:
                self._said.close()
                self._said = None

    def _keep(self, text: str) -> None:
        """``text`` into launch.log (caller holds the lock); a full disk is not an error."""
        if self._said is not None:
            with contextlib.suppress(OSError, ValueError):
                self._said.write(text + "\n")
                self._said.flush()

    def say(self, text: str) -> None:
        """One line to the user, and into ``logs/launch.log`` (module docstring)."""
        lost: BaseException | None = None
        with self._lock:
            self._keep(text)
            if not self.console:
                return
            try:
                print(text, file=self.out, flush=True)
            except UnicodeError:  # a line this terminal cannot show: it is in the logs
                pass
            except (OSError, ValueError) as e:  # EPIPE, EIO, a closed stream
                self.console, lost = False, e
            else:  # a stream that survives it says so (agent.commands.console.PipeSafe)
                if getattr(self.out, "gone", False):
                    self.console = False
                    lost = getattr(self.out, "error", None) or BrokenPipeError(
                        errno.EPIPE, os.strerror(errno.EPIPE))
            if lost is not None:
                why = lost.strerror if isinstance(lost, OSError) and lost.strerror else lost
                line = (f"launch: the output's reader went away ({why}); the mission goes on, "
                        f"every line in {self.logs}")
                self._keep(line)
                self.lost = LogLine(source="launch", level="warning", text=line)
        if lost is not None and self.lost is not None:
            self.note(self.lost)

    def copy(self, child: Child, stream: IO[str], log: IO[str]) -> None:
        """Copy ``child``'s output (``stream``) on a thread of its own into ``log``, the
        user's output and the events, until it ends."""
        pump = threading.Thread(target=self._pump, args=(child, stream, log),
                                name=f"pump-{child.name}", daemon=True)
        self.pumps.append(pump)
        pump.start()

    def drain(self, timeout_s: float = 5.0) -> None:
        """Wait for the copies to reach the end of their (exited) children's output."""
        for pump in self.pumps:
            pump.join(timeout_s)

    def _pump(self, child: Child, stream: IO[str], log: IO[str]) -> None:
        for line in stream:
            with contextlib.suppress(OSError, ValueError):  # a full disk: the rest goes on
                log.write(line)
                log.flush()
            text = line.rstrip("\n")
            child.lines.append(text)
            child.first_line.set()
            try:
                self.say(f"[{child.name}] {text}")
                if (ev := line_event(child.name, text)) is not None:
                    self.note(ev)
            except Exception:  # never let the copy die (the child would block on its output)
                _log.exception("launch: copying %s's output", child.name)
        child.first_line.set()
        with contextlib.suppress(OSError, ValueError):
            log.close()
