"""viscover trade protocol: wire messages (:mod:`agent.protocol.messages`) and the pure
ownership/trade state machine (:mod:`agent.protocol.trade`)."""
