"""The thesis in pure numpy (no I/O, no clocks, no threads): vision (ch. 3,
:mod:`~agent.core.vision`), collision avoidance (section 4.3, :mod:`~agent.core.avoidance`),
backtracking line search (section 4.4, :mod:`~agent.core.linesearch`), the planner step
(figure 4.1, :mod:`~agent.core.planner`), Algorithm 7 and partner lists (section 4.5,
:mod:`~agent.core.trading`), optimal orientation (Algorithm 1, :mod:`~agent.core.orientation`),
a gimbal's tilt limits as a constraint of the planner (:mod:`~agent.core.tilt`), landmark
generators (:mod:`~agent.core.landmarks`) and the way home
(:mod:`~agent.core.homing`)."""
