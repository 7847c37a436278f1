"""Test harnesses shipped with the package (as ``trio.testing``): :mod:`~agent.testing.memsim`
runs a whole mission of agent runtimes in memory, on virtual time, with seeded fault
injection; :mod:`~agent.testing.protocol_net` a model network of trade machines (loss,
duplicates, replays, crashes at any journal write) for state-machine tests;
:mod:`~agent.testing.agent_engine` the simulator driving the agents' own decision code
(``viscover simulate``), with :mod:`~agent.testing.rehearsal` its seeded faults (loss,
duplicates, jitter, drones lost for good) and the observer that checks its invariants;
:mod:`~agent.testing.core_net` agent cores stepped by hand over a model network (loss,
duplicates, replays, crashes; waits answered late and out of order,
:mod:`~agent.testing.core_waits`; agents gone for good) for state-machine tests of the core."""
