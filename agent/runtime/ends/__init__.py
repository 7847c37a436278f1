"""The protocol's ends in the agent core: the trade client
(:mod:`~agent.runtime.ends.trade_client`: our offers, retries, hedged copies) and server
(:mod:`~agent.runtime.ends.trade_server`: Algorithm 7's responder), membership
(:mod:`~agent.runtime.ends.membership`: peers' states, poses, liveliness), completion
(:mod:`~agent.runtime.ends.completion`), joining (:mod:`~agent.runtime.ends.joining`) and the
pose check of offers (:mod:`~agent.runtime.ends.pose_check`). Pure: the transport is the
shell's."""
