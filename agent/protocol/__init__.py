"""viscover trade protocol: wire messages (:mod:`agent.wire.peer`) and the pure
ownership/trade state machine (:mod:`agent.protocol.machine`)."""
