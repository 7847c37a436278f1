"""Bookkeeping of one hedged query (several copies of one request in flight, the first reply
wins; :meth:`agent.net.transport.ZenohTransport.request_hedged`): replies and ends of its
copies arrive on Zenoh threads and are queued for the requester."""

from __future__ import annotations

import queue
import threading

#: A reply of one copy: (copy index, monotonic time sent, time received, payload).
Got = tuple[int, float, float, bytes]


class Hedge:
    """One hedged request in flight: replies and ends of its copies (from Zenoh threads)
    queued for the requester, the queries still open, whether a copy was lost."""

    def __init__(self) -> None:
        #: replies (payload None: copy ended; the requester re-checks :meth:`over`)
        self.got: queue.SimpleQueue[tuple[int, float, float, bytes | None]] = \
            queue.SimpleQueue()
        self._lock = threading.Lock()
        self._open = 0
        self._any = False
        self.lost = False  #: a copy was lost on the way: wait for the timeout

    def opened(self) -> None:
        """One more query sent or scheduled."""
        with self._lock:
            self._open += 1
            self._any = True

    def ended(self, k: int) -> None:
        """A query of copy ``k`` ended (its replies were delivered before)."""
        with self._lock:
            self._open -= 1
        self.got.put((k, 0.0, 0.0, None))

    def over(self) -> bool:
        """Queries were sent, every one ended and no copy was lost: no reply can come."""
        with self._lock:
            return self._any and self._open <= 0 and not self.lost
