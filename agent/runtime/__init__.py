"""One drone's agent: its core and the runtime that carries the core's effects out, run by a
process runner (:mod:`agent.runners`). Five sub-packages, by job; imports point down this
list's dependencies only (``tests/test_layers.py``):

* :mod:`agent.runtime.core`: the pure state machine, ``AgentCore.step(event) -> effects``
  (:mod:`~agent.runtime.core.agent_core`), its events and effects
  (:mod:`~agent.runtime.core.events`), the state its parts share
  (:mod:`~agent.runtime.core.shared`), the vehicle as the core sees it, the published state
  and the one status snapshot.
* :mod:`agent.runtime.ends`: the protocol's ends: the trade client and server (Algorithm 7
  over queries), membership, completion, joining, the pose check of offers.
* :mod:`agent.runtime.fencing`: lost drones: adoption by fence rounds, abandoned trades,
  fence claims and proofs, the team's final word.
* :mod:`agent.runtime.moves`: the strategy's moves: the planner step, the registered moves and
  the parts that carry them out (coverage re-splits, revert, inspection tours, taking work,
  hand-over).
* :mod:`agent.runtime.shell`: the runtime (``AgentRuntime``: raft's Ready loop over a
  transport and a journal), the pose sources (the kinematic vehicle of eq. 5.1) and sealing.

No process, signal or file handling here; nothing here imports the simulator
(:mod:`agent.sim`); nothing outside the shell does I/O or reads a clock
(``tests/test_layers.py``, ``tests/test_core_effects.py``)."""
