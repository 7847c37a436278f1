"""Opening a Zenoh session at start-up, for every process: wait for the router if it is not
there yet, say on stderr what is being waited for, and end in one line with the fix.

A drone may boot before its ground station, so a process keeps trying for ``wait_s`` seconds
(``--connect-wait``). When nothing answers it raises a :class:`~agent.errors.UsageError`
naming the endpoint, the wait and the option to fix (``--connect``, or ``--router`` for
``viscover launch``); Zenoh's own message is kept only when it says something else, and
without the Rust source location it ends with.
"""

from __future__ import annotations

import json
import logging
import re
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import zenoh

from agent.errors import UsageError
from agent.net.faults import FaultInjector
from agent.net.transport import ZenohTransport

_log = logging.getLogger(f"viscover.{__name__}")

#: The Rust source location zenoh appends to its errors ("... at /root/.cargo/....rs:447.").
_RUST_LOCATION = re.compile(r"\s+at \S+\.rs:\d+\.?\s*$")
_RETRY_S = 0.5


def to_stderr(line: str) -> None:
    """Print ``viscover: line`` on stderr."""
    print(f"viscover: {line}", file=sys.stderr, flush=True)


def endpoints_of(cfg: Any) -> list[str]:
    """The ``connect/endpoints`` of a client config (empty if it names none)."""
    try:
        eps = json.loads(cfg.get_json("connect/endpoints"))
    except Exception:  # zenoh raises its own error for a missing key
        return []
    return [str(e) for e in eps] if isinstance(eps, list) else []


def zenoh_reason(e: BaseException) -> str:
    """Zenoh's error message without the Rust source location."""
    return _RUST_LOCATION.sub("", str(e)).strip().rstrip("!")


def open_session(cfg: Any, faults: FaultInjector | None, node_id: str, wait_s: float = 0.0,
                 stop: threading.Event | None = None, *, option: str = "--connect",
                 say: Callable[[str], None] = to_stderr) -> ZenohTransport:
    """A :class:`ZenohTransport` on ``cfg`` (a ``zenoh.Config`` or a json5 file), retrying
    for up to ``wait_s`` seconds while no router answers; the first failure is announced with
    ``say`` ("waiting up to ... for the Zenoh router at ..."). Raises a UsageError when the
    time is up, KeyboardInterrupt when ``stop`` is set meanwhile."""
    if not isinstance(cfg, zenoh.Config):
        cfg = zenoh.Config.from_file(str(Path(cfg)))
    eps = endpoints_of(cfg)
    where = ", ".join(eps) or "the configured endpoints"
    deadline = time.monotonic() + wait_s
    waited = False
    while True:
        try:
            return ZenohTransport(cfg, faults, node_id)
        except Exception as e:  # zenoh.ZError: no router answered, or a bad config
            last = e
        if stop is not None and stop.is_set():
            raise KeyboardInterrupt
        if time.monotonic() >= deadline:
            break
        if not waited:
            say(f"waiting up to {wait_s:g} s for the Zenoh router at {where} ...")
            waited = True
        _log.info("no router yet (%s); retrying", zenoh_reason(last))
        (stop or threading.Event()).wait(min(_RETRY_S, max(0.0, deadline - time.monotonic())))
    reason = zenoh_reason(last)
    within = f" within {wait_s:g} s" if wait_s > 0 else ""
    if reason.startswith("Unable to connect"):
        proto = eps[0].split("/", 1)[0] if eps else "tcp"
        raise UsageError(f"no Zenoh router answered at {where}{within}: start one (viscover "
                         "router --config broker_config/router.json5) or give the right "
                         f"endpoint with {option} {proto}/HOST:PORT")
    raise UsageError(f"cannot open a Zenoh session to {where}{within}: {reason}")
