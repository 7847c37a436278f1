"""The lockstep simulator in one process, on virtual time: the chapter-5 kinematic simulator
(:mod:`agent.sim.kinematic`, the thesis strategy), the inspection run
(:mod:`agent.sim.inspection`); and every engine's result (:mod:`agent.sim.result`), report
(:mod:`agent.sim.report`) and recordings read back as results (:mod:`agent.sim.replay`). It
shares the scenario's world (:mod:`agent.world`) and the strategies (:mod:`agent.strategy`)
with the agent processes and imports nothing of theirs. A strategy with moves of its own
runs on the agents' code only (:mod:`agent.testing.agent_engine`)."""
