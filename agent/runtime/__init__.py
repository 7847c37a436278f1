"""Processes. One agent: :mod:`~agent.runtime.agent` (the tick loop owning the parts:
:mod:`~agent.runtime.shared`, :mod:`~agent.runtime.trade_client`,
:mod:`~agent.runtime.trade_server`, :mod:`~agent.runtime.membership`,
:mod:`~agent.runtime.completion`), :mod:`~agent.runtime.pose` (the pose-source contract and
the kinematic vehicle of eq. 5.1), :mod:`~agent.runtime.process` (opening a session and a
journal, the loop, signals) and :mod:`~agent.runtime.flying` (the same agent flying a
quadcopter, phase by phase). Also :mod:`~agent.runtime.observer` (invariant checks of a
whole mission), :mod:`~agent.runtime.memsim` (a whole mission in memory, on virtual
time), :mod:`~agent.runtime.watch` (a mission's events and live view) with
:mod:`~agent.runtime.status` (its rendering), :mod:`~agent.runtime.recorder` (MCAP and
events.jsonl) with :mod:`~agent.runtime.scene` (Foxglove messages), and
:mod:`~agent.runtime.launcher` (``viscover launch``)."""
