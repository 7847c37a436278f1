"""The chapter-5 kinematic simulator in one process (:mod:`agent.sim.kinematic`), its result
(:mod:`agent.sim.result`) and report (:mod:`agent.sim.report`)."""
