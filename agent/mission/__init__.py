"""Mission tooling: what watches, records and runs a whole mission from outside the drones.
:mod:`~agent.mission.observer` (invariant checks of a whole mission, with
:mod:`~agent.mission.invariants` and :mod:`~agent.mission.identity`),
:mod:`~agent.mission.watch` (a mission's events and live view, with
:mod:`~agent.mission.trade_events`) and :mod:`~agent.mission.status` (its rendering),
:mod:`~agent.mission.recorder` (MCAP and events.jsonl) with :mod:`~agent.mission.scene` and
:mod:`~agent.mission.capture_scene` (Foxglove messages), :mod:`~agent.mission.launcher`
(``viscover launch``) with :mod:`~agent.mission.runfolder`, and
:mod:`~agent.mission.operator` (``viscover land`` / ``stop``, who is live)."""
