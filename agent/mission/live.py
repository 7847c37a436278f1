"""The Foxglove live view of a recording (``viscover record|launch --live PORT``).

What foxglove-sdk gives and what is added here:

* **Both subprotocols.** The SDK's WebSocket server (foxglove-sdk 0.30) accepts a client only
  if it offers ``foxglove.sdk.v1`` (or ``foxglove.sdk.v1.1``) in ``Sec-WebSocket-Protocol``;
  one offering only ``foxglove.websocket.v1`` (Foxglove Studio before the rename, Lichtblick
  before 1.22) gets HTTP 400 "Missing expected sec-websocket-protocol header", and no option of
  ``foxglove.start_server`` changes that (its handshake compares with one constant). The two
  names stand for the same protocol (Foxglove's stated position when it renamed it; Lichtblick
  added the new name alongside the old one). So the SDK's server listens on a loopback port of
  its own, and :class:`FrontDoor` listens on ``host:port``: it reads each client's HTTP upgrade
  request, and when the client offers ``foxglove.websocket.v1`` but no ``foxglove.sdk.*`` it
  offers ``foxglove.sdk.v1`` to the SDK instead and names ``foxglove.websocket.v1`` in the
  101 answer back (``Sec-WebSocket-Accept`` depends on the key only, so the handshake stays
  valid); after the handshake it copies bytes both ways unchanged. A client offering an SDK
  name passes through untouched.
* **Latched topics.** The SDK has no latching (a channel re-sends nothing to a client that
  subscribes later). :class:`LiveView` keeps the last message of each latched channel and
  logs it again when a client subscribes to it (the server listener's ``on_subscribe``). The
  live channels live in a context of their own (the recording's are in another), so the
  re-sent copy reaches the live clients only, never the MCAP file. (Python's ``Client`` has
  no sink id, so the copy goes to every live subscriber of that channel: a repeat of a
  message that did not change.)
* **Log records.** The SDK logs through Python's ``logging`` (loggers ``foxglove.*``, and
  ``tungstenite.*`` for its WebSocket library); with nothing configured they reach
  ``logging.lastResort`` and land raw on stderr, in the middle of ``launch``'s output.
  :func:`route_sdk_logs` stops them there and re-logs them on ``viscover.mission.live.sdk``:
  the SDK's warnings and errors (a viewer that closed its tab, a failed handshake) at INFO,
  the rest at DEBUG, so they show with ``--log-level info`` / ``debug`` in our format.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import threading
import time
from collections.abc import Callable
from typing import Any

import foxglove
from foxglove.websocket import ChannelView, Client, ServerListener

_log = logging.getLogger(f"viscover.{__name__}")
_sdk_log = logging.getLogger(f"viscover.{__name__}.sdk")

#: The subprotocol the SDK's server speaks, and the older name of the same protocol.
SDK_PROTOCOL = b"foxglove.sdk.v1"
LEGACY_PROTOCOL = b"foxglove.websocket.v1"
#: The loggers the SDK's records come from.
SDK_LOGGERS = ("foxglove", "tungstenite")
#: Wall seconds a client has to send its upgrade request (and the SDK to answer it).
HANDSHAKE_S = 10.0
_HEADER = b"sec-websocket-protocol:"


class _SdkRecords(logging.Handler):
    """Re-logs an SDK record on :data:`_sdk_log`: WARNING and above at INFO, the rest DEBUG."""

    def emit(self, record: logging.LogRecord) -> None:
        level = logging.INFO if record.levelno >= logging.WARNING else logging.DEBUG
        if _sdk_log.isEnabledFor(level):
            _sdk_log.log(level, "foxglove-sdk (%s): %s", record.name, record.getMessage())


def route_sdk_logs() -> None:
    """Send the SDK's log records to our logger (module docstring); idempotent. Call it
    before the SDK logs anything: the SDK's bridge caches each logger's level at first use."""
    for name in SDK_LOGGERS:
        lg = logging.getLogger(name)
        if not any(isinstance(h, _SdkRecords) for h in lg.handlers):
            lg.addHandler(_SdkRecords())
        lg.propagate = False
        lg.setLevel(logging.INFO)


def _protocols(lines: list[bytes]) -> tuple[list[int], list[bytes]]:
    """Rows of the ``Sec-WebSocket-Protocol`` headers among HTTP head ``lines`` and the
    subprotocols they offer, in order."""
    rows = [i for i, ln in enumerate(lines) if i and ln.lower().startswith(_HEADER)]
    offered = [v.strip() for i in rows for v in lines[i][len(_HEADER):].split(b",")]
    return rows, offered


def offer_sdk_protocol(head: bytes) -> tuple[bytes, bool]:
    """A client's upgrade request ``head`` (up to and with the blank line) as the SDK's
    server must see it, and whether it was rewritten: a client offering
    ``foxglove.websocket.v1`` and no ``foxglove.sdk.*`` offers ``foxglove.sdk.v1`` instead."""
    lines = head.split(b"\r\n")
    rows, offered = _protocols(lines)
    if LEGACY_PROTOCOL not in offered or any(v.startswith(b"foxglove.sdk.") for v in offered):
        return head, False
    lines[rows[0]] = b"Sec-WebSocket-Protocol: " + SDK_PROTOCOL
    return b"\r\n".join(ln for i, ln in enumerate(lines) if i not in rows[1:]), True


def answer_legacy(head: bytes) -> bytes:
    """The SDK's answer ``head`` to a rewritten request with ``foxglove.sdk.v1`` named as
    ``foxglove.websocket.v1`` (an answer without it, e.g. a 400, unchanged)."""
    lines = head.split(b"\r\n")
    rows, offered = _protocols(lines)
    if offered != [SDK_PROTOCOL]:
        return head
    lines[rows[0]] = b"Sec-WebSocket-Protocol: " + LEGACY_PROTOCOL
    return b"\r\n".join(lines)


async def _pipe(src: asyncio.StreamReader, dst: asyncio.StreamWriter) -> None:
    """Copy ``src`` to ``dst`` until end of file or an error."""
    with contextlib.suppress(OSError, ConnectionError):
        while data := await src.read(1 << 16):
            dst.write(data)
            await dst.drain()


class FrontDoor:
    """A TCP front of the SDK's server on ``host:port`` (0: any free port) that admits both
    subprotocol names (module docstring); the SDK's server is on 127.0.0.1:``upstream``.
    Runs an asyncio loop on a daemon thread; :meth:`close` stops it. A port that cannot be
    bound raises RuntimeError (as ``foxglove.start_server`` does)."""

    def __init__(self, host: str, port: int, upstream: int) -> None:
        self.upstream = upstream
        self.legacy_clients = 0  #: clients admitted under ``foxglove.websocket.v1``
        self._writers: set[asyncio.StreamWriter] = set()
        self._loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self._loop.run_forever, name="live-front",
                                        daemon=True)
        self._thread.start()
        try:
            self._server = asyncio.run_coroutine_threadsafe(
                asyncio.start_server(self._serve, host, port), self._loop).result(10.0)
        except OSError as e:
            self._stop_loop()
            raise RuntimeError(f"cannot listen on {host}:{port}: {e.strerror or e}") from None
        self.port: int = self._server.sockets[0].getsockname()[1]

    async def _serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        """One client: its upgrade request to the SDK (rewritten if need be), the answer
        back, then bytes both ways."""
        up: asyncio.StreamWriter | None = None
        self._writers.add(writer)
        try:
            head = await asyncio.wait_for(reader.readuntil(b"\r\n\r\n"), HANDSHAKE_S)
            head, legacy = offer_sdk_protocol(head)
            up_reader, up = await asyncio.open_connection("127.0.0.1", self.upstream)
            up.write(head)
            await up.drain()
            answer = await asyncio.wait_for(up_reader.readuntil(b"\r\n\r\n"), HANDSHAKE_S)
            if legacy:
                answer = answer_legacy(answer)
                self.legacy_clients += b" 101 " in answer.split(b"\r\n", 1)[0]
            writer.write(answer)
            await writer.drain()
            both = [asyncio.ensure_future(_pipe(reader, up)),
                    asyncio.ensure_future(_pipe(up_reader, writer))]
            _done, pending = await asyncio.wait(both, return_when=asyncio.FIRST_COMPLETED)
            for task in pending:
                task.cancel()
        except (OSError, asyncio.IncompleteReadError, asyncio.LimitOverrunError,
                TimeoutError) as e:
            _log.debug("live view: a client went away during its handshake (%s)", e)
        except asyncio.CancelledError:  # closing: the connection ends here
            pass
        finally:
            self._writers.discard(writer)
            for w in (writer, up):
                if w is not None:
                    w.close()

    def _stop_loop(self) -> None:
        self._loop.call_soon_threadsafe(self._loop.stop)
        self._thread.join(5.0)
        if not self._thread.is_alive():
            self._loop.close()

    def close(self) -> None:
        """Stop listening, drop the clients and stop the loop; idempotent."""
        if self._loop.is_closed():
            return

        async def shut() -> None:
            self._server.close()
            for w in list(self._writers):
                w.close()
            for task in asyncio.all_tasks():
                if task is not asyncio.current_task():
                    task.cancel()
            await asyncio.sleep(0)  # let them end

        with contextlib.suppress(Exception):
            asyncio.run_coroutine_threadsafe(shut(), self._loop).result(5.0)
        self._stop_loop()


class Tee:
    """One topic logged on the recording's channel and, with a live view, on its live twin
    (``make(context)`` builds the channel in a context). A latched tee keeps its last
    message for the live view to re-send to a client that subscribes later."""

    def __init__(self, make: Callable[[foxglove.Context], Any], record: foxglove.Context,
                 live: LiveView | None, latched: bool = False) -> None:
        self.record = make(record)
        self.live: Any = None if live is None else make(live.context)
        self.latched = latched
        self.last: tuple[Any, int] | None = None
        if live is not None and latched:
            live.latch(self)

    def log(self, msg: Any, log_time: int) -> None:
        """Log ``msg`` at ``log_time`` [ns since the epoch] on both channels."""
        if self.latched:
            self.last = (msg, log_time)
        self.record.log(msg, log_time=log_time)
        if self.live is not None:
            self.live.log(msg, log_time=log_time)


class LiveView(ServerListener):
    """The SDK's server on a loopback port of its own, its :class:`FrontDoor` on
    ``host:port`` (:attr:`port` is the one to give a viewer), and the latched channels."""

    def __init__(self, name: str, host: str, port: int) -> None:
        route_sdk_logs()
        self.context = foxglove.Context()
        self._latched: dict[int, Tee] = {}
        self._lock = threading.Lock()
        self.server = foxglove.start_server(name=name, host="127.0.0.1", port=0,
                                            context=self.context, server_listener=self)
        try:
            self.front = FrontDoor(host, port, self.server.port)
        except RuntimeError:
            self.server.stop()
            raise
        self.port = self.front.port

    def latch(self, tee: Tee) -> None:
        """Re-send ``tee``'s last message to each client that subscribes to it."""
        with self._lock:
            self._latched[tee.live.id()] = tee

    def on_subscribe(self, client: Client, channel: ChannelView) -> None:
        """A client subscribed: the channel's last message if it is latched (errors logged
        here, never raised into the SDK)."""
        with self._lock:
            tee = self._latched.get(channel.id)
        last = None if tee is None else tee.last
        if tee is None or last is None:
            return
        try:
            tee.live.log(last[0], log_time=time.time_ns())
        except Exception as e:  # a callback must not raise into the SDK's thread
            _log.warning("live view: could not re-send %s to client %d: %s", channel.topic,
                         client.id, e)

    def close(self) -> None:
        """Stop the front door and the SDK's server."""
        self.front.close()
        self.server.stop()
