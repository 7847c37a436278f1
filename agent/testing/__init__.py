"""Test harnesses shipped with the package (as ``trio.testing``): :mod:`~agent.testing.memsim`
runs a whole mission of agent runtimes in memory, on virtual time, with seeded fault
injection."""
