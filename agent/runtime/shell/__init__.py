"""The agent runtime's shell: what carries the core's effects out. The runtime
(:mod:`~agent.runtime.shell.runtime`, ``AgentRuntime``: raft's Ready loop over a transport
and a journal, the one turn), the pose sources (:mod:`~agent.runtime.shell.pose`: the
kinematic vehicle of eq. 5.1, adapters of a flown one) and sealing of trade requests
(:mod:`~agent.runtime.shell.sealing`: the wall clock and randomness the core never reads)."""
