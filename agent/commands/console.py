"""Standard output and error of a ``viscover`` command when their reader goes away.

``viscover launch ... | head -3``, ``... | tee log`` and then Ctrl-C (which ends ``tee``
too), a terminal closed under ``nohup``: the next write fails (EPIPE; Python ignores SIGPIPE,
so it is a :class:`BrokenPipeError`, not a signal). Python's own advice
(https://docs.python.org/3/library/signal.html#note-on-sigpipe) is to catch it, point the
descriptor at ``/dev/null`` so that nothing fails again at exit, and end; setting SIGPIPE back
to its default instead would also kill the process on a socket's broken connection (Zenoh).

:func:`guarded` wraps ``sys.stdout`` and ``sys.stderr`` of one command in a
:class:`PipeSafe` stream with one of two policies:

* ``"end"``: the command's output is its product (``scenario check``, ``status``,
  ``preflight``, ``--help``): the first write that fails in the main thread
  raises :class:`BrokenPipeError`, which :func:`agent.commands.kit.run_handler` turns into a
  quiet end with :data:`EXIT_BROKEN_PIPE` (128 + SIGPIPE, what a shell reports for a Unix
  tool that SIGPIPE ended). Other threads' writes are dropped, never raised: a thread dying
  on its console must not take down the work it does.
* ``"keep"``: the command flies, runs or watches a mission, or writes files (``launch``,
  ``agent``, ``groundstation``, ``observe``, ``report``, ...; ``agent.cli.KEEP_RUNNING``):
  its output is a view and the run's own logs are the record, so a failed write is dropped,
  and so is every later one; the command goes on and exits with its own status.

A descriptor 1 or 2 already closed at start (``viscover ... >&-``) is given ``/dev/null``, so
that no file, pipe or socket the command opens takes its number (a child process would write
its output into it).
"""

from __future__ import annotations

import contextlib
import errno
import os
import signal
import sys
import threading
from collections.abc import Iterable, Iterator
from typing import Any, Literal, TextIO

#: 128 + SIGPIPE: the status of a command that ended because its output's reader went away,
#: as a shell reports a Unix tool that SIGPIPE ended (``yes | head -1``: 141).
EXIT_BROKEN_PIPE = 128 + int(signal.SIGPIPE)

Policy = Literal["end", "keep"]

#: errno values of a console that is gone: the reader closed the pipe (EPIPE), the terminal
#: hung up (EIO), the descriptor was closed under us (EBADF).
_GONE = frozenset({errno.EPIPE, errno.EIO, errno.EBADF})


def _gone(e: BaseException) -> bool:
    """Whether ``e`` says the stream's reader (or the stream itself) is gone."""
    if isinstance(e, OSError):
        return e.errno in _GONE
    return isinstance(e, ValueError) and not isinstance(e, UnicodeError)  # closed file


class PipeSafe:
    """A text stream (``sys.stdout`` / ``sys.stderr``) that survives its reader going away
    (module docstring); everything but writing and flushing is the wrapped stream's."""

    def __init__(self, stream: TextIO, policy: Policy) -> None:
        self.wrapped = stream
        self.policy: Policy = policy
        self.gone = False  #: a write failed: every later one is dropped
        self.error: BaseException | None = None  #: the error of that write
        self._lock = threading.Lock()

    def _lost(self, e: BaseException) -> None:
        """The reader went away: further output goes nowhere (the descriptor too, so that
        the interpreter's last flush and any child that inherits it cannot fail); raise in
        the main thread of an ``end`` command."""
        with self._lock:
            first, self.gone = not self.gone, True
            if first:
                self.error = e
        if first:
            with contextlib.suppress(OSError, ValueError, AttributeError):
                fd = self.wrapped.fileno()
                null = os.open(os.devnull, os.O_WRONLY)
                os.dup2(null, fd)
                os.close(null)
        if self.policy == "end" and threading.current_thread() is threading.main_thread():
            raise BrokenPipeError(errno.EPIPE, "the output's reader went away") from e

    def write(self, text: str) -> int:
        if self.gone:
            return len(text)
        try:
            return self.wrapped.write(text)
        except (OSError, ValueError) as e:
            if not _gone(e):
                raise
            self._lost(e)
            return len(text)

    def writelines(self, lines: Iterable[str]) -> None:
        for line in lines:
            self.write(line)

    def flush(self) -> None:
        if self.gone:
            return
        try:
            self.wrapped.flush()
        except (OSError, ValueError) as e:
            if not _gone(e):
                raise
            self._lost(e)

    def __getattr__(self, name: str) -> Any:
        return getattr(self.wrapped, name)


def _reopen_closed_descriptors() -> None:
    """Give ``/dev/null`` to descriptors 1 and 2 when they are closed (module docstring)."""
    for fd in (1, 2):
        try:
            os.fstat(fd)
        except OSError:
            null = os.open(os.devnull, os.O_WRONLY)
            if null != fd:
                os.dup2(null, fd)
                os.close(null)


@contextlib.contextmanager
def guarded(policy: Policy = "end") -> Iterator[tuple[PipeSafe, PipeSafe]]:
    """``sys.stdout`` and ``sys.stderr`` as :class:`PipeSafe` streams of ``policy`` for the
    duration (restored after); a missing one (closed at start) writes to ``/dev/null``."""
    _reopen_closed_descriptors()
    saved = sys.stdout, sys.stderr
    streams = []
    opened: list[TextIO] = []
    for s in saved:
        if s is None:  # Python found the descriptor closed at start
            s = open(os.devnull, "w", encoding="utf-8")  # closed below
            opened.append(s)
        streams.append(s.wrapped if isinstance(s, PipeSafe) else s)
    out, err = PipeSafe(streams[0], policy), PipeSafe(streams[1], policy)
    sys.stdout, sys.stderr = out, err
    try:
        yield out, err
    finally:
        sys.stdout, sys.stderr = saved
        for s in opened:
            s.close()


def set_policy(policy: Policy) -> None:
    """Switch the guarded ``sys.stdout`` / ``sys.stderr`` (if they are) to ``policy``."""
    for s in (sys.stdout, sys.stderr):
        if isinstance(s, PipeSafe):
            s.policy = policy
