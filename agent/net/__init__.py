"""Adapters to the network: the :class:`~agent.net.transport.Transport` contract with its Zenoh
implementation (:mod:`agent.net.transport`) and an in-process double
(:mod:`agent.net.memory`), seeded fault injection (:mod:`agent.net.faults`), a Zenoh router
run from Python (:mod:`agent.net.router`) and the shared clock over Zenoh
(:mod:`agent.net.clocksync`). What travels is defined in :mod:`agent.wire`."""
