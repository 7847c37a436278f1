"""The agent's parts: one drone's decisions and protocol ends, run by a process runner
(:mod:`agent.runners`). :mod:`~agent.runtime.agent` (the tick loop owning the parts:
:mod:`~agent.runtime.shared`, :mod:`~agent.runtime.trade_client`,
:mod:`~agent.runtime.trade_server`, :mod:`~agent.runtime.membership`,
:mod:`~agent.runtime.completion`, :mod:`~agent.runtime.adoption`,
:mod:`~agent.runtime.joining`, :mod:`~agent.runtime.fence_claims`), the strategies' drivers
(:mod:`~agent.runtime.planning`, :mod:`~agent.runtime.moves`, :mod:`~agent.runtime.revert`,
:mod:`~agent.runtime.inspecting`) and :mod:`~agent.runtime.pose` (the pose-source contract
and the kinematic vehicle of eq. 5.1). No process, signal or file handling here; nothing
here imports the simulator (:mod:`agent.sim`)."""
