"""The one user-error type and the exit statuses of every viscover process.

A :class:`UsageError` is a mistake the user can fix (a bad file, a bad option, a journal of
another mission): the CLI prints it as one line, ``viscover: error: <message>``, and exits with
:data:`EXIT_USAGE`; never a traceback. Raise it from any layer; subclasses say where it came
from (:class:`agent.config.scenario.ScenarioError`, :class:`agent.protocol.records.
JournalMismatch`). This module has no dependencies inside viscover.
"""

from __future__ import annotations

from typing import Final

#: Done: the mission completed, or the operator ended it (``viscover land`` / ``stop``), or
#: an agent was stopped by SIGTERM (a service manager's orderly stop).
EXIT_OK: Final = 0
#: The mission went wrong: an invariant violation seen by the observer, or a flight failure
#: (handshake refused, initial pose not reached, failsafe landing, landing not confirmed).
EXIT_FAILURE: Final = 1
EXIT_USAGE: Final = 2  #: a user mistake (argparse uses the same status)
#: The mission did not complete: within ``--timeout``, or it ended with landmarks given up (an
#: inspection with capturable landmarks not captured, agent.protocol.inspection_end).
EXIT_INCOMPLETE: Final = 3
EXIT_INTERRUPTED: Final = 130  #: SIGINT (128 + 2), as shells report it (Ctrl-C)


class UsageError(Exception):
    """A mistake the user can fix: printed as one line, exit status :data:`EXIT_USAGE`."""
