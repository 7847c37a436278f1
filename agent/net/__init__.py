"""viscover networking: key table, wire codec, fault injection and transports.

Modules: :mod:`agent.wire.keys` (key expressions), :mod:`agent.wire.codec` (msgspec msgpack
codec with rejection counting), :mod:`agent.net.faults` (seeded fault injection),
:mod:`agent.net.transport` (the :class:`Transport` interface and :class:`ZenohTransport`),
:mod:`agent.net.memory` (in-process :class:`MemoryNetwork`/:class:`MemoryTransport`) and
:mod:`agent.net.router` (a Zenoh router run from Python).
"""

from agent.net.faults import Decision, FaultConfig, FaultInjector, ReplayInjector
from agent.net.memory import MemoryNetwork, MemoryTransport
from agent.net.transport import Declared, Transport, ZenohTransport
from agent.wire.codec import Codec, RateLimitedLogger, RejectCounter

__all__ = [
    "Codec",
    "Decision",
    "Declared",
    "FaultConfig",
    "FaultInjector",
    "MemoryNetwork",
    "MemoryTransport",
    "RateLimitedLogger",
    "RejectCounter",
    "ReplayInjector",
    "Transport",
    "ZenohTransport",
]
