"""A daemon thread that runs submitted callables in order, each optionally after a delay: how
the Zenoh transport keeps user callbacks off Zenoh's own threads."""

from __future__ import annotations

import heapq
import itertools
import logging
import threading
import time
from collections.abc import Callable

_log = logging.getLogger(f"viscover.{__name__}")


class Worker:
    """A daemon thread running submitted callables in order, optionally after a delay.

    ``submit`` never blocks (safe from Zenoh callbacks). Items due at the same time run in
    submission order. Exceptions raised by items are logged, not propagated.
    """

    def __init__(self, name: str) -> None:
        self.name = name
        self._cond = threading.Condition()
        self._heap: list[tuple[float, int, Callable[[], None]]] = []
        self._seq = itertools.count()
        self._stopping = False
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def submit(self, fn: Callable[[], None], delay_s: float = 0.0) -> bool:
        """Run ``fn`` on the worker after ``delay_s`` seconds; False if the worker stopped."""
        due = time.monotonic() + max(0.0, delay_s)
        with self._cond:
            if self._stopping:
                return False
            heapq.heappush(self._heap, (due, next(self._seq), fn))
            self._cond.notify()
        return True

    def _run(self) -> None:
        while True:
            with self._cond:
                while True:
                    if self._stopping:
                        return
                    if self._heap:
                        wait = self._heap[0][0] - time.monotonic()
                        if wait <= 0.0:
                            _, _, fn = heapq.heappop(self._heap)
                            break
                        self._cond.wait(wait)
                    else:
                        self._cond.wait()
            try:
                fn()
            except Exception:
                _log.exception("%s: task failed", self.name)

    def stop(self, timeout_s: float = 5.0) -> list[Callable[[], None]]:
        """Stop after the running item; return items never run. Joins the thread."""
        with self._cond:
            self._stopping = True
            pending = [fn for _, _, fn in sorted(self._heap)]
            self._heap.clear()
            self._cond.notify_all()
        if threading.current_thread() is not self._thread:
            self._thread.join(timeout_s)
            if self._thread.is_alive():
                _log.warning("%s: thread still busy after %.1f s", self.name, timeout_s)
        return pending
