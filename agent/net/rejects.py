"""Reject counting and rate-limited logging shared by transport threads: the locked,
wall-clock versions of :class:`agent.wire.codec.RejectCounter` and
:class:`agent.wire.codec.RateLimitedLogger` (those are for one owner, an agent core, which
reads no clock and takes no lock)."""

from __future__ import annotations

import logging
import threading
import time

from agent.wire.codec import RateLimitedLogger, RejectCounter

__all__ = ["LockedRejectCounter", "rate_limited_log"]


#: Distinct keys counted one by one; rejects on further keys are counted under
#: :data:`OTHER_KEYS` (anyone may send on keys of its choosing: the table stays bounded).
MAX_KEYS = 1024
OTHER_KEYS = "(other keys)"


class LockedRejectCounter(RejectCounter):
    """Thread-safe counts of rejected messages, per reason and per key (at most
    :data:`MAX_KEYS` keys; ``folded`` counts the rejects counted under :data:`OTHER_KEYS`)."""

    def __init__(self) -> None:
        super().__init__()
        self._lock = threading.Lock()
        self.folded = 0

    def add(self, reason: str, key: str = "") -> None:
        with self._lock:
            if key not in self.by_key and len(self.by_key) >= MAX_KEYS:
                key = OTHER_KEYS
                self.folded += 1
            super().add(reason, key)

    def snapshot(self) -> dict[str, dict[str, int]]:
        with self._lock:
            return super().snapshot()


class _LockedLogger(RateLimitedLogger):
    """A :class:`RateLimitedLogger` several threads log through."""

    def __init__(self, logger: logging.Logger | None, interval_s: float, level: int) -> None:
        super().__init__(logger, interval_s, level, clock=time.monotonic)
        self._lock = threading.Lock()

    def log(self, reason: str, message: str) -> bool:
        with self._lock:
            return super().log(reason, message)


def rate_limited_log(logger: logging.Logger | None = None, interval_s: float = 10.0,
                     level: int = logging.WARNING) -> RateLimitedLogger:
    """At most one line per reason every ``interval_s`` seconds of the monotonic clock,
    from any thread."""
    return _LockedLogger(logger, interval_s, level)
