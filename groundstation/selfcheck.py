"""The ground station's check that the router passes what it publishes.

A session hears its own publications locally, whether or not the router accepted them, so a
ground station presenting a certificate the router's access control does not let publish
(``--identity drone-A`` on the secured profile) would print "ready" and publish into the void.
:func:`require_clock_passes` opens a second session with the same configuration (same
identity: reading is allowed to every team member) and waits for the ground station's own
clock to arrive through the router; if it does not, the station refuses to run in one line.
"""

from __future__ import annotations

import threading
from typing import Any

from agent.errors import UsageError
from agent.net.transport import ZenohTransport
from agent.wire import keys
from agent.wire.ground import CLOCK_CODEC


def clock_passes(cfg: Any, mission: str, wait_s: float = 3.0) -> bool:
    """Whether a clock message on ``mission``'s clock key reaches a second session opened
    with ``cfg`` within ``wait_s`` wall seconds (the caller publishes the clock, and checked
    that nobody else does)."""
    heard = threading.Event()

    def on_clock(key: str, payload: bytes) -> None:
        if CLOCK_CODEC.decode(payload, key) is not None:
            heard.set()

    probe = ZenohTransport(cfg, None, "groundstation-probe")
    try:
        probe.subscribe(keys.clock_key(mission), on_clock)
        return heard.wait(wait_s)
    finally:
        probe.close()


def require_clock_passes(cfg: Any, mission: str, identity: str | None,
                         wait_s: float = 3.0) -> None:
    """A :class:`UsageError` (one line naming ``identity``, the certificate presented on the
    secured profile, and the fix) if the router does not pass this ground station's clock."""
    if clock_passes(cfg, mission, wait_s):
        return
    if identity is not None:
        raise UsageError(f"the router refuses what this ground station publishes: it presents "
                         f"the certificate {identity!r}, which may not publish the mission's "
                         "clock, mocap and landmarks; run it with --identity ground (the "
                         "default)")
    raise UsageError(f"the router passes nothing this ground station publishes on "
                     f"{keys.clock_key(mission)} within {wait_s:g} s; check the router's "
                     "access_control")
