"""Lost drones in the agent core: adoption of a lost drone's landmarks by fence rounds
(:mod:`~agent.runtime.fencing.adoption`), trades left with a fenced drone
(:mod:`~agent.runtime.fencing.abandoned`), the fences an agent claims and proves
(:mod:`~agent.runtime.fencing.fence_claims`) and the team's final word
(:mod:`~agent.runtime.fencing.final_word`). Pure."""
