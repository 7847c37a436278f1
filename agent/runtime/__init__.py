"""One drone's agent: its core and the runtime that carries the core's effects out, run by a
process runner (:mod:`agent.runners`).

* The core, :mod:`~agent.runtime.core` (``AgentCore.step(event) -> effects``; the events and
  effects in :mod:`~agent.runtime.events`): pure, no lock, no transport, no journal. Its
  parts share :mod:`~agent.runtime.shared`: the protocol ends
  (:mod:`~agent.runtime.trade_client`, :mod:`~agent.runtime.trade_server`,
  :mod:`~agent.runtime.membership`, :mod:`~agent.runtime.completion`,
  :mod:`~agent.runtime.adoption`, :mod:`~agent.runtime.abandoned`,
  :mod:`~agent.runtime.final_word`,
  :mod:`~agent.runtime.joining`, :mod:`~agent.runtime.fence_claims`,
  :mod:`~agent.runtime.pose_check`) and the strategy's moves
  (:mod:`~agent.runtime.drivers`, :mod:`~agent.runtime.planning`,
  :mod:`~agent.runtime.moves`, :mod:`~agent.runtime.revert`,
  :mod:`~agent.runtime.inspecting`, :mod:`~agent.runtime.work_taker`,
  :mod:`~agent.runtime.handover`).
* The runtime, :mod:`~agent.runtime.agent` (``AgentRuntime``: raft's Ready loop over a
  transport and a journal), and :mod:`~agent.runtime.pose` (the pose-source contract and the
  kinematic vehicle of eq. 5.1).

No process, signal or file handling here; nothing here imports the simulator
(:mod:`agent.sim`); nothing in the core does I/O (``tests/test_layers.py``)."""
