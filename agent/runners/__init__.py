"""Process runners: what ``viscover agent`` and ``viscover fly`` run.
:mod:`~agent.runners.process` (opening a session and a journal, the loop, signals, the end),
:mod:`~agent.runners.flying` (the same agent flying a quadcopter, phase by phase, with
:mod:`~agent.runners.settling`), :mod:`~agent.runners.orders` (the operator's commands
received), :mod:`~agent.runners.departure` (leaving the team on purpose) and
:mod:`~agent.runners.quality` (the end-of-run quality line)."""
