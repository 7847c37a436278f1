"""The strategy's moves in the agent core: the planner step (:mod:`~agent.runtime.moves.planning`,
eq. 3.8's gradient ascent), the driver that tries a strategy's registered moves in order
(:mod:`~agent.runtime.moves.drivers`) and the parts that carry the moves out: coverage
re-splits (:mod:`~agent.runtime.moves.coverage`), revert (:mod:`~agent.runtime.moves.revert`),
inspection tours (:mod:`~agent.runtime.moves.inspecting`) and their captures as evidence
(:mod:`~agent.runtime.moves.claims`), taking work
(:mod:`~agent.runtime.moves.work_taker`) and the battery hand-over
(:mod:`~agent.runtime.moves.handover`). Pure: decisions in :mod:`agent.strategy` and
:mod:`agent.core`."""
