"""The simulator in one process, on virtual time: the chapter-5 kinematic simulator
(:mod:`agent.sim.kinematic`), the "potential" strategy's run (:mod:`agent.sim.strategy`), the
inspection run (:mod:`agent.sim.inspection`), their result (:mod:`agent.sim.result`), report
(:mod:`agent.sim.report`) and recordings read back as results (:mod:`agent.sim.replay`). It
shares the scenario's world (:mod:`agent.world`) and the strategies (:mod:`agent.strategy`)
with the agent processes and imports nothing of theirs."""
